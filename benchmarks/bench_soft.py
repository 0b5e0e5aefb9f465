"""Soft shadows: error and cost per sample count, same run.

For each scene with soft lights: the ray-traced masks at ``samples`` = 1, 4, 16, 32, 64 (the final
render's probe pass + penumbra refinement), the viewport's accumulation (first frame after a
change: probes, 8 samples in the penumbrae, filtered; the 8th still frame: 32), and the same
scene rendered ``hard``.
Error: per light, against a reference share of each light, on a fixed random subset of the
covered pixels: the numpy soft oracle (``core/oracle/soft.py``, 256 stratified samples per
pixel, brute force), or with ``--cycles`` Cycles' per-light soft reference (lights as they
are, ``--cycles-samples`` at the pixel centre). Printed: mean absolute error, share of pixels
off by more than 0.1 (worst light), shadow ms (median of ``--repeats``), ÷ hard.

Scenes: ``soft`` (the test suite's hand-made scene: a 15° sun, a 0.4 m sphere light, square,
rectangle and disk area lights over a cube and a box, 160x120 by default) and any SCENE spec
``load_scene`` accepts (``soft_lights``, ``forest``...).

    .venv/bin/python -m benchmarks.bench_soft soft --size 320x240
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle.soft import soft_visibility
from hybrid_shadow_addon.core.settings import Settings

REPO = Path(__file__).resolve().parents[1]


def load(spec, size):
    if spec == "soft":
        from tests.helpers.scenes import soft_scene
        sc = soft_scene()
    else:
        from hybrid_shadow_addon.blender.load import load_scene
        sc = load_scene(spec)
    if size:
        sc.resolution = size
    return sc


def rays(frame, scene, li):
    pos = frame.gbuffer.read("position")
    nrm = frame.gbuffer.read("normal")
    ok = pos[..., 3] > 0
    p = pos[..., :3][ok].astype(np.float64)
    n = nrm[..., :3][ok].astype(np.float64)
    return ok, p + n * 2e-4, n


def references(pipe, scene, pixels, cycles: bool, cycles_samples: int):
    pipe.set_scene(scene, "bvh")
    f = pipe.render(scene, Settings(mode="raytrace", hard=True))
    rng = np.random.default_rng(11)
    out = {}
    for li in f.lights:
        ok, o, n = rays(f, scene, li)
        pick = np.sort(rng.choice(len(o), min(pixels, len(o)), replace=False))
        rows, cols = np.nonzero(ok)
        out[li] = [rows[pick], cols[pick], None]
        if not cycles:
            out[li][2] = soft_visibility(scene, li, o[pick], n[pick], samples=256)
    if cycles:
        import bpy  # noqa: F401  (load_scene left the Blender scene open)

        from hybrid_shadow_addon.blender.cycles_reference import render_reference
        ref = render_reference(bpy.context.scene, [scene.lights[li].name for li in out],
                               resolution=scene.resolution, samples=cycles_samples, hard=False)
        for li in out:
            vis = ref.visibility[scene.lights[li].name]
            out[li][2] = vis[out[li][0], out[li][1]]
    return out


def measure(pipe, scene, settings, refs, repeats, frames=1):
    """(mean abs error, share > 0.1 of the worst light, median shadow ms) of ``settings``."""
    pipe.set_scene(scene, "bvh")
    times = []
    for _ in range(repeats):
        pipe.reset_history()
        for _ in range(frames):
            f = pipe.render(scene, settings)
        times.append(f.timings["shadow_ms"] if frames == 1 else f.timings["shadow_ms"])
    maes, far = [], []
    for li, (r, c, ref) in refs.items():
        valid = np.isfinite(ref)
        e = np.abs(f.mask_array(li)[r, c][valid] - ref[valid])
        maes.append(float(e.mean()))
        far.append(float((e > 0.1).mean()))
    return float(np.mean(maes)), max(far), float(np.median(times))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["soft"])
    ap.add_argument("--size", default=None, help="WxH")
    ap.add_argument("--pixels", type=int, default=4000, help="reference pixels per light")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cycles", action="store_true", help="against Cycles' soft reference (bpy scenes only)")
    ap.add_argument("--cycles-samples", type=int, default=256)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x")) if args.size else None
    pipe = Pipeline()
    results = []
    for spec in args.scenes:
        scene = load(spec, size)
        refs = references(pipe, scene, args.pixels, args.cycles, args.cycles_samples)
        base = Settings(mode="raytrace", quality="high")
        rows = [("hard", base.replace(hard=True), 1)]
        rows += [(f"{n} samples" + (" (default)" if n == Settings.samples else ""), base.replace(samples=n), 1)
                 for n in (1, 4, 16, 32, 64)]
        acc = base.replace(accumulate=True, frame_samples=4, samples=64)
        rows += [("viewport, first frame", acc, 1), ("viewport, 8 still frames", acc, 8)]
        for _label, s, _frames in rows:  # (a warm-up render compiles each program first)
            pipe.set_scene(scene, "bvh")
            pipe.render(scene, s)
        hard_ms = None
        print(f"\n{spec} {scene.resolution[0]}x{scene.resolution[1]}, {len(refs)} shadowed lights, "
              f"reference: {'Cycles' if args.cycles else 'numpy oracle'}")
        print("| variant | mean abs error | > 0.1 (worst light) | shadow ms | ÷ hard |")
        print("|---|---:|---:|---:|---:|")
        for label, s, frames in rows:
            mae, far, ms = measure(pipe, scene, s, refs, args.repeats, frames)
            hard_ms = ms if hard_ms is None else hard_ms
            results.append({"scene": spec, "variant": label, "mae": mae, "far": far, "shadow_ms": ms,
                            "ratio": ms / hard_ms})
            print(f"| {label} | {mae:.4f} | {100 * far:.2f}% | {ms:.1f} | {ms / hard_ms:.1f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
