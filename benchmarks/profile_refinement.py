"""Where the refinement's rays go (``quality`` medium/low): which pixels it marks for their own ray
and why, and what the marked rays cost in llvmpipe's lock-step groups.

For each scene and quality (hard lights, ``--structure bvh``) one frame is rendered with the
refinement rule ``group`` off and one with it on (``passes/refine.py``); each light's marks are
read from the depth buffer. Printed per scene and quality:

- marked: the pixel-lights marked for their own ray, over the valid pixel-lights (rule off);
- why (rule off): the pixel's surrounding samples cannot stand for it (``refine_geometry.glsl``:
  another surface, a crease, a grazing view) or its cell's samples disagree
  (``refine_cells.glsl``); the rest are pixels that graze the light;
- the lock-step cost of the full-resolution rays, from the numpy mirror of the walk
  (``core/oracle/tracer/twolevel.py``: node steps per ray) over 4x2 blocks (each fragment-shader
  invocation runs 8 pixels until its slowest lane is done): ``high`` traces every block; the
  trace under the depth test runs each block that holds a mark for its slowest marked lane
  (rule off, and on: the whole block's unknown pixels); a perfectly compacted list would run the
  marked rays 8 at a time in the order llvmpipe shades them (64-pixel tiles, 4x4 blocks). The
  ratios to ``high`` bound what the refinement can save on this machine before its coarse trace
  and its classification passes are paid.

Deterministic (no timing).

    .venv/bin/python -m benchmarks.profile_refinement [forest clusters city] [--size 320x180]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.gpu.targets import read_texture
from hybrid_shadow_addon.core.oracle import tracer
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings

BW, BH = 4, 2  # llvmpipe's lock-step block (columns, rows from the bottom of the image)


def _gl_blocks(a: np.ndarray) -> np.ndarray:
    """(H, W) image, row 0 the top row -> (rows/BH, BH, cols/BW, BW) blocks of GL rows."""
    h, w = a.shape
    out = np.zeros((-(-h // BH) * BH, -(-w // BW) * BW), a.dtype)
    out[:h, :w] = a[::-1]
    return out.reshape(out.shape[0] // BH, BH, out.shape[1] // BW, BW)


def block_cost(steps: np.ndarray, lanes: np.ndarray) -> int:
    """Sum over the 4x2 blocks of the largest step count among ``lanes``."""
    return int(_gl_blocks(np.where(lanes, steps, 0)).max(axis=(1, 3)).sum())


def list_cost(steps: np.ndarray, lanes: np.ndarray) -> int:
    """The ``lanes`` rays 8 at a time, in llvmpipe's shading order, each group its slowest."""
    h = steps.shape[0]
    rows, cols = np.nonzero(lanes)
    gy = h - 1 - rows
    order = np.lexsort(((gy % 4) * 4 + cols % 4, ((gy % 64) // 4) * 16 + (cols % 64) // 4,
                        (gy // 64) * 100000 + cols // 64))
    s = steps[rows, cols][order]
    s = np.pad(s, (0, -len(s) % 8))
    return int(s.reshape(-1, 8).max(axis=1).sum()) if len(s) else 0


def capture(pipe, scene, quality, w, h, group):
    """Render; each refined light's marks (H, W bool), cells and the frame's geometry bits."""
    rp = pipe.shadow_pass("raytrace")
    ref = rp.refiner
    kept_rule, orig = ref.rules["group"], rp.hard._trace
    got = {}

    def trace(job, ray):
        out = orig(job, ray)
        if rp.hard.plan == "refine":
            g = ref._grid
            got[ray.index] = (ref.marked(), read_texture(ref._work.get("cells", *g["cells"]).texture), dict(g))
        return out

    rp.hard._trace = trace
    ref.rules["group"] = group
    try:
        frame = pipe.render(scene, Settings(mode="raytrace", quality=quality, hard=True, structure="bvh"), w, h)
        geo = read_texture(ref._work.get("geometry", w, h).texture)
    finally:
        rp.hard._trace = orig
        ref.rules["group"] = kept_rule
    return frame, got, geo


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--qualities", default="medium,low")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    pipe = Pipeline()
    print("| scene | quality | marked | why: samples cannot stand / cell disagrees / grazes the light "
          "| lock-step cost / high: depth test | with group | perfect list |")
    print("|---|---|---:|---|---:|---:|---:|")
    try:
        for spec in args.scenes:
            scene = load_scene(spec)
            pipe.set_scene(scene, "bvh")
            w, h = tuple(scene.resolution) if spec.startswith("stiff/") else size
            steps_of = {}
            for quality in args.qualities.split(","):
                frame, off, geo = capture(pipe, scene, quality, w, h, False)
                _, on, _ = capture(pipe, scene, quality, w, h, True)
                tot = dict(valid=0, marked=0, geometry=0, cells=0, high=0, depth=0, group=0, list=0)
                for k, li in enumerate(frame.lights):
                    if li not in off:
                        continue
                    valid = ~np.isnan(frame.mask_array(k))
                    if li not in steps_of:  # (the rays are high's: the same for every quality)
                        rows, cols = np.nonzero(valid)
                        o, d, tmax, facing = shadow_rays(frame.gbuffer, (rows, cols), scene.lights[li],
                                                         pipe.baked.origin)
                        st = {"per_ray": True}
                        tracer.trace_structured(pipe.baked, o[facing], d[facing], tmax[facing], st)
                        steps = np.zeros((h, w), np.int64)
                        steps[rows[facing], cols[facing]] = st["ray_iterations"]
                        steps_of[li] = steps
                    steps = steps_of[li]
                    mk, cells, g = off[li]
                    mk = mk & valid
                    ys, xs = np.nonzero(mk)
                    gy = h - 1 - ys
                    s, (ox, oy) = g["scale"], g["offset"]
                    cx, cy = np.floor((xs - ox) / s).astype(int), np.floor((gy - oy) / s).astype(int)
                    inside = (cx >= 0) & (cy >= 0) & (cx < cells.shape[1]) & (cy < cells.shape[0])
                    cell = np.full(len(xs), -1.0)
                    cell[inside] = cells[::-1][cy[inside], cx[inside]]
                    stands = geo[ys, xs] == 15.0
                    tot["valid"] += int(valid.sum())
                    tot["marked"] += int(mk.sum())
                    tot["geometry"] += int((~stands).sum())
                    tot["cells"] += int((stands & (cell < 0)).sum())
                    tot["high"] += block_cost(steps, valid)
                    tot["depth"] += block_cost(steps, mk)
                    tot["group"] += block_cost(steps, on[li][0] & valid)
                    tot["list"] += list_cost(steps, mk)
                m = max(tot["marked"], 1)
                hi = max(tot["high"], 1)
                rest = tot["marked"] - tot["geometry"] - tot["cells"]
                print(f"| {spec} {w}x{h} | {quality} | {tot['marked'] / max(tot['valid'], 1):.3f} | "
                      f"{tot['geometry'] / m:.2f} / {tot['cells'] / m:.2f} / {rest / m:.2f} | "
                      f"{tot['depth'] / hi:.3f} | {tot['group'] / hi:.3f} | {tot['list'] / hi:.3f} |", flush=True)
    finally:
        pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
