"""Digests of every mask and image the pipeline makes for the built-in scenes, in every mode.

A refactor that must not change behaviour is checked by running this before and after and
comparing the two files: every mask and image must be bit-identical.

    .venv/bin/python -m tools.mask_digest --output before.json
    .venv/bin/python -m tools.mask_digest --output after.json --against before.json

Each scene is rendered at a small size under a list of settings variants (every shadow mode and
quality, both acceleration structures, light grids on and off, hard and soft lights, interlacing
and accumulation over several frames); the SHA-256 of each mask (``Frame.mask_array``) and of the
lit image is recorded per frame. ``--tree DIR`` renders with another checkout's code (a peer commit)
and a scene may be a pickled core scene (``tools/pickle_scenes.py``), for a machine without Blender.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.machinery
import importlib.util
import json
import sys
import time
from pathlib import Path

from tools.pickle_scenes import load_pickled

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "hybrid_shadow_addon"

SCENES = [
    "cube_on_plane", "forest", "clusters", "city:blocks=4", "scaling:triangles=20000,instances=200",
    "animated", "alpha_cards", "soft_lights", "smooth_shapes",
    "stiff/axis_aligned", "stiff/cards", "stiff/clip_range", "stiff/crowd", "stiff/degenerate",
    "stiff/far_away", "stiff/grazing", "stiff/instance_scales", "stiff/ortho", "stiff/point_in_box",
    "stiff/spot_touching", "stiff/stadium", "stiff/thin",
]

#: name -> (Settings changes, frames rendered in a row after a reset)
VARIANTS = {
    "rt-high": ({}, 1),
    "rt-high-hard": ({"hard": True}, 1),
    "rt-high-hard-nogrids": ({"hard": True, "light_grid": False}, 1),
    "rt-medium-hard": ({"quality": "medium", "hard": True}, 1),
    "rt-low-hard": ({"quality": "low", "hard": True}, 1),
    "rt-medium": ({"quality": "medium"}, 1),
    "rt-medium-nearest": ({"quality": "medium", "upsample": "nearest", "hard": True}, 1),
    "rt-high-grid": ({"structure": "grid"}, 1),
    "rt-high-grid-hard": ({"structure": "grid", "hard": True}, 1),
    "rt-medium-grid-hard": ({"structure": "grid", "quality": "medium", "hard": True}, 1),
    "rt-interlace-hard": ({"interlace": True, "hard": True}, 5),
    "rt-accumulate": ({"accumulate": True}, 3),
    "rt-maxdist": ({"max_distance": 20.0, "max_shadowed_lights": 2, "hard": True}, 1),
    "shadowmap-512": ({"mode": "shadowmap", "shadowmap_size": 512}, 1),
    "shadowmap-512-hard": ({"mode": "shadowmap", "shadowmap_size": 512, "hard": True}, 1),
    "none": ({"mode": "none"}, 1),
}


def use_tree(tree: Path) -> None:
    """Import the add-on package of checkout ``tree`` (its ``shaders/`` and ``test_scenes/`` beside
    it) for the rest of this process, in place of the installed one: ``tree``'s folder becomes
    ``hybrid_shadow_addon``'s, so its submodules and pickled scenes load from there too."""
    if PACKAGE in sys.modules:
        raise RuntimeError(f"{PACKAGE} is imported already")
    spec = importlib.machinery.PathFinder.find_spec(PACKAGE, [str(tree.resolve())])
    if spec is None:
        raise SystemExit(f"--tree {tree}: not a checkout of this project (no {PACKAGE}/)")
    module = importlib.util.module_from_spec(spec)
    sys.modules[PACKAGE] = module
    spec.loader.exec_module(module)


def _sha(a) -> str:
    import numpy as np

    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _eager_light_grids(pipe) -> None:
    """Light grids built at a light's first sight, so that one frame traces them."""
    from dataclasses import replace

    rt = pipe.shadow_pass("raytrace")
    if hasattr(rt, "options"):
        rt.options = replace(rt.options, eager_light_grids=True)
    else:  # (a tree before RaytraceOptions: the baseline digests)
        rt.light_grids.eager = True


def digest_scene(pipe, scene, size, variants) -> dict:
    from hybrid_shadow_addon.core.settings import Settings

    out = {}
    for name, (changes, frames) in variants.items():
        s = Settings(**changes)
        pipe.reset_history()
        per_frame = []
        for _ in range(frames):
            frame = pipe.render(scene, s, *size)
            d = {"image": _sha(frame.image)}
            for i in frame.lights:
                d[scene.lights[i].name] = _sha(frame.mask_array(i))
            per_frame.append(d)
        out[name] = per_frame
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--output", required=True, help="JSON file of digests to write")
    ap.add_argument("--against", help="an earlier output: report every digest that differs")
    ap.add_argument("--scenes", help="comma-separated scene arguments (default: every built-in scene)")
    ap.add_argument("--variants", help="comma-separated variant names (default: all)")
    ap.add_argument("--resolution", default="96x64")
    ap.add_argument("--tree", type=Path, default=REPO, help="the checkout whose code renders (default: this one)")
    a = ap.parse_args(argv)
    use_tree(a.tree)
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    def load_scene(spec):
        if spec.endswith(".pkl.gz"):
            return load_pickled(spec)
        from hybrid_shadow_addon.blender.load import load_scene as load_blender

        return load_blender(spec)

    size = tuple(int(v) for v in a.resolution.split("x"))
    scenes = a.scenes.split(";") if a.scenes else SCENES
    variants = {k: VARIANTS[k] for k in a.variants.split(",")} if a.variants else VARIANTS
    result = {}
    for spec in scenes:
        t0 = time.perf_counter()
        scene = load_scene(spec)
        pipe = Pipeline()
        _eager_light_grids(pipe)
        pipe.set_scene(scene)
        result[spec] = digest_scene(pipe, scene, size, variants)
        pipe.release()
        print(f"{spec}: {time.perf_counter() - t0:.1f} s", flush=True)
    Path(a.output).write_text(json.dumps(result, indent=1, sort_keys=True))
    if not a.against:
        return 0
    before = json.loads(Path(a.against).read_text())
    diffs = 0
    for spec, vs in result.items():
        for v, frames in vs.items():
            old = before.get(spec, {}).get(v)
            if old is None:
                print(f"{spec} {v}: not in {a.against}")
                continue
            if old != frames:
                diffs += 1
                print(f"{spec} {v}: DIFFERS")
    print(f"{diffs} variant(s) differ")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
