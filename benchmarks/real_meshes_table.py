"""Hard shadows on smooth, custom-normal and flipped-face meshes and on third-party models against
Cycles: one markdown table of every scene x light with the mismatch (% of valid pixels where
|ours - Cycles| > 0.5), how many of those we shadow where Cycles lights ("false") and the reverse
("missed"), and the set's total, as BENCHMARKS.md records it.

    .venv/bin/python -m benchmarks.real_meshes_table [--scenes normals/custom_split,models/avocado]
        [--mode raytrace-high]

The scenes are ``test_scenes/normals/*.py`` and ``test_scenes/models/*.py``; the references are
Cycles' per-light hard visibility at the scene's resolution, cached as ``compare`` caches them.
``evaluate_scene`` is also what ``tests/test_real_meshes.py`` runs.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

SCENES = ("normals/smooth_primitives", "normals/weighted_normals", "normals/custom_split", "normals/flipped_faces",
          "normals/gltf_roundtrip", "normals/obj_roundtrip", "models/avocado", "models/lantern", "models/waterbottle")
MODES = {  # name -> Settings kwargs (hard lights: the Cycles references are hard)
    "raytrace-high": dict(mode="raytrace", quality="high", hard=True),
    "raytrace-medium": dict(mode="raytrace", quality="medium", hard=True),
    "raytrace-low": dict(mode="raytrace", quality="low", hard=True),
    "raytrace-interlace": dict(mode="raytrace", quality="high", hard=True, interlace=True),
    "shadowmap": dict(mode="shadowmap", hard=True),
}


def reference(bscene, scene) -> dict:
    """Per-light Cycles visibility at the scene's resolution (1 sample at the pixel centre, hard
    lights), from ``compare``'s disk cache when there."""
    from hybrid_shadow_addon.blender.cycles_reference import CyclesReferenceProvider
    from hybrid_shadow_addon.tools.reference import default_cache_dir, load_cached, reference_key, save_cached

    prov = CyclesReferenceProvider(bscene)
    names = prov.light_names(scene)
    path = default_cache_dir(prov) / f"{reference_key(scene, scene.resolution, 1, names, prov)}.npz"
    hit = load_cached(path)
    if hit is not None and set(hit[0]) == set(names):
        return hit[0]
    vis, ms = {}, {}
    for n in names:
        vis[n], ms[n] = prov.visibility(scene, n, scene.resolution, 1)
    save_cached(path, vis, ms)
    return vis


def evaluate_scene(arg: str, mode: str = "raytrace-high", *, ctx=None, keep_masks: bool = False) -> dict:
    """Load the scene ``arg``, render it in ``mode`` (hard lights, their grids built at once) and
    measure each light's mask against Cycles: ``{light: MaskError.to_dict()}`` (plus ``ours``
    and ``ref`` arrays with ``keep_masks``), ``'_scene'``, the exported core scene, and with
    ``keep_masks`` ``'_instance'``, the G-buffer's instance index per pixel (-1: background)."""
    import bpy

    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings
    from hybrid_shadow_addon.tools.metrics import mask_error

    bscene = open_scene(arg)
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get()).validate()
    W, H = scene.resolution
    ref = reference(bscene, scene)
    out = {"_scene": scene}
    pipe = Pipeline(ctx)
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=True)
    try:
        pipe.set_scene(scene)
        settings = Settings(**MODES[mode])
        pipe.render(scene, settings, W, H)  # warm-up: shader compilation
        for _ in range(4 if settings.interlace else 0):  # a still view: every phase traced
            pipe.render(scene, settings, W, H)
        frame = pipe.render(scene, settings, W, H)
        for li in frame.lights:
            name = scene.lights[li].name
            if name not in ref:
                continue
            ours = frame.mask_array(li)
            m = mask_error(ref[name], ours).to_dict()
            if keep_masks:
                m["ours"], m["ref"] = ours, ref[name]
            out[name] = m
        if keep_masks:
            gb = frame.gbuffer
            inst = gb.read("material")[..., 2]
            out["_instance"] = np.where(gb.read("position")[..., 3] > 0.5, np.rint(inst), -1).astype(np.int64)
    finally:
        pipe.release()
    return out


def lights_of(result: dict) -> dict:
    """The per-light entries of an :func:`evaluate_scene` result."""
    return {k: v for k, v in result.items() if not k.startswith("_")}


def table(results: dict) -> str:
    """Markdown: one row per scene and light, then the set's total (pixels summed over masks)."""
    lines = ["| scene | light | valid px | mismatch % | mismatched | false (we shadowed, Cycles lit) | "
             "missed (we lit, Cycles shadowed) |", "|---|---|---|---|---|---|---|"]
    valid = mism = false = missed = 0
    for scene, r in results.items():
        for light, m in lights_of(r).items():
            lines.append(f"| {scene} | {light} | {m['valid_pixels']} | {m['mismatch_pct']:.3f} | "
                         f"{m['mismatch_pixels']} | {m['false_pixels']} | {m['missed_pixels']} |")
            valid += m["valid_pixels"]
            mism += m["mismatch_pixels"]
            false += m["false_pixels"]
            missed += m["missed_pixels"]
    pct = 100.0 * mism / valid if valid else 0.0
    lines.append(f"| **all** | | {valid} | {pct:.3f} | {mism} | {false} | {missed} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--mode", default="raytrace-high", choices=sorted(MODES))
    a = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", "/tmp/hs-real-meshes-blender")
    from hybrid_shadow_addon.core.gpu.context import create_context

    ctx = create_context()
    results = {}
    for arg in [s for s in a.scenes.split(",") if s]:
        t0 = time.perf_counter()
        results[arg] = evaluate_scene(arg, a.mode, ctx=ctx)
        print(f"{arg}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    print(table(results))
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
