"""Soft shadows per light against a low-noise Cycles reference: the table every light's goal is
read from (mean absolute error and share of valid pixels off by more than 0.1).

The reference is Cycles' per-light soft visibility (``blender/cycles_reference.py``: lights as
they are, ``--cycles-samples`` at each pixel centre, its validity rule), rendered once per scene,
size and sample count and kept in ``--cache`` (2048 samples: about 2.5 min at 160x120, 10 min at
320x240, for ``soft_lights``' six lights). Ours: the final render's mask (``Settings.samples``
rays per pixel and light) for each of ``--samples``, and the viewport's mask on the first frame
after a change, the second and the eighth (``--viewport``; 4 samples per frame). Every valid
pixel counts (no subset).

    .venv/bin/python -m benchmarks.soft_per_light soft_lights --size 160x120 --samples 16 32 64 128 --viewport
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error

REPO = Path(__file__).resolve().parents[1]


def reference(spec: str, size, samples: int, cache: Path) -> dict:
    """{light name: visibility (H, W), NaN where invalid} from the cache, or rendered into it (the
    file name carries the reference recipe's version: a new recipe renders again)."""
    from hybrid_shadow_addon.blender.cycles_reference import RECIPE_VERSION
    path = cache / f"{spec.replace('/', '_').replace(':', '_')}_{size[0]}x{size[1]}_{samples}_r{RECIPE_VERSION}.npz"
    if path.exists():
        return dict(np.load(path))
    import bpy  # noqa: F401  (load_scene left the Blender scene open)

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    ref = render_reference(bpy.context.scene, None, resolution=size, samples=samples, hard=False)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **ref.visibility)
    tmp.replace(path)
    return dict(ref.visibility)


def row(label: str, frame, scene, ref: dict) -> str:
    cells = []
    for li in frame.lights:
        name = scene.lights[li].name
        if name not in ref:
            continue
        e = mask_error(ref[name], frame.mask_array(li))
        cells.append(f"{e.abs_error_sum / max(e.valid_pixels, 1):.4f} / "
                     f"{100 * e.off_pixels / max(e.valid_pixels, 1):.2f} %")
    return f"| {label} | " + " | ".join(cells) + " |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", default="soft_lights")
    ap.add_argument("--size", default="160x120", help="WxH")
    ap.add_argument("--samples", type=int, nargs="+", default=[32])
    ap.add_argument("--viewport", action="store_true", help="also the viewport's frames 1, 2 and 8")
    ap.add_argument("--cycles-samples", type=int, default=2048)
    ap.add_argument("--cache", default=str(REPO / "out" / "soft_references"))
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    from hybrid_shadow_addon.blender.load import load_scene
    scene = load_scene(args.scene)
    scene.resolution = size
    ref = reference(args.scene, size, args.cycles_samples, Path(args.cache))
    pipe = Pipeline()
    pipe.set_scene(scene, "bvh")
    names = [scene.lights[li].name for li in range(len(scene.lights)) if scene.lights[li].name in ref]
    print(f"{args.scene} {size[0]}x{size[1]}, against Cycles at {args.cycles_samples} samples: "
          "mean abs error / % of valid pixels off by more than 0.1")
    print("| ours | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for n in args.samples:
        print(row(f"{n} samples", pipe.render(scene, Settings(samples=n)), scene, ref), flush=True)
    if args.viewport:
        pipe.reset_history()
        s = Settings(accumulate=True, frame_samples=4)  # (to the default samples)
        for k in range(1, 9):
            f = pipe.render(scene, s)
            if k in (1, 2, 8):
                print(row(f"viewport, frame {k} ({f.stats['accumulated_samples']} samples)", f, scene, ref), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
