"""Shadow visibility reused across camera moves (``core/gpu/passes/reproject.py``) against fresh
``high`` frames, same run: per frame of each camera path the rays traced, the shadow ms and the
share of valid pixels whose reused mask differs from the fresh one.

The paths are the thesis' (``tools/bench.py``): ``--frames`` frames evenly spaced over the
scene's animation (:func:`~hybrid_shadow_addon.tools.bench.path_frames` over
:class:`~hybrid_shadow_addon.blender.frames.BlenderFrames`' range, or over ``--range A-B``: a
viewport's camera moves a little between redraws), the cameras of those frames. A scene whose
path does not move the camera (``city``, ``clusters``) and the built-in ``smooth_shapes`` take an
orbit about the vertical through the scene's centre instead (``--orbit-step`` radians a frame).
Lights hard, mode ``raytrace``, quality ``high``; each frame is rendered by a pipeline that
always reuses, by a view of it that reuses where it pays (``reuse_choice="auto"``, the viewport's
way), by a view that always reuses and times its trace of the retraced pixels alone (the least a
reused frame costs: the rays it cannot do without, on a renderer that shades only the pixels that
pass the depth test) and by a view that never reuses (the first frame of each path is fresh for
all and left out of the ratios). The hard lights' grids are built at first sight (the steady state a viewport
reaches once they pay back); ``--no-grid`` traces the tree (lights that move, alpha-cut casters).
``--orbit`` orbits every scene; ``--no-group`` leaves the refinement's group rule (llvmpipe's
default) off in the reusing pipelines, as on a GPU.

    .venv/bin/python -m benchmarks.bench_reuse [forest city clusters smooth_shapes] [--size 640x360]
        [--frames 10] [--range A-B] [--orbit] [--orbit-step 0.02] [--no-grid] [--no-group]
        [--trace-path auto|compute|fragment] [--json OUT]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import frame_mismatch

HARD = Settings(mode="raytrace", quality="high", hard=True)


def orbit_cameras(scene, n: int, step: float = 0.02):
    """``n`` cameras turning about the vertical through the scene's bounds' centre."""
    lo, hi = scene.world_bounds()
    c = (np.asarray(lo) + np.asarray(hi)) * 0.5
    out = []
    for k in range(n):
        a = step * k
        rot = np.array([[np.cos(a), -np.sin(a), 0, 0], [np.sin(a), np.cos(a), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        t = np.eye(4)
        t[:3, 3] = c
        ti = np.eye(4)
        ti[:3, 3] = -c
        out.append(dataclasses.replace(scene.camera, matrix=t @ rot @ ti @ scene.camera.matrix))
    return out


def path_cameras(name: str, n: int, frame_range=None):
    """The scene, the cameras of ``n`` frames evenly spaced over its animation (or over
    ``frame_range``) and those frames, as the thesis' benchmark takes them."""
    import bpy

    from hybrid_shadow_addon.blender.frames import BlenderFrames
    from hybrid_shadow_addon.tools.bench import path_frames

    scene = load_scene(name)
    src = BlenderFrames(bpy.context.scene, name)
    frames = path_frames(*(frame_range or src.frame_range), n)
    cams = [src.scene_at(f).camera for f in frames]
    return scene, cams, frames


def still(cams) -> bool:
    """Whether every camera of a path is the first one."""
    return all(np.array_equal(c.matrix, cams[0].matrix) for c in cams)


def mismatch(a, b) -> float:
    """The share of valid pixels whose masks differ (:func:`frame_mismatch`)."""
    bad, valid = frame_mismatch(a, b)
    return bad / max(valid, 1)


def run_path(label, scene, cams, w, h, settings=HARD, group=None) -> dict:
    pipe = Pipeline()
    pipe.reuse, pipe.reuse_choice = True, "always"
    auto = pipe.view()
    auto.reuse = True
    bound = pipe.view()  # (always reusing, its trace of the retraced pixels timed alone)
    bound.reuse, bound.reuse_choice = True, "always"
    bound.shadow_pass("raytrace").reuse.time_retrace = True
    fresh = pipe.view()
    fresh.reuse = False
    for p in (pipe, auto, bound, fresh):  # (the grids from the first frame on: the steady state)
        rt = p.shadow_pass("raytrace")
        rt.options = dataclasses.replace(rt.options, eager_light_grids=True)
        if group is not None and p is not fresh:
            rt.refiner.rules["group"] = bool(group)
    pipe.set_scene(scene)
    rows = []
    try:
        for k, cam in enumerate(cams):
            s = dataclasses.replace(scene, camera=cam)
            a = pipe.render(s, settings, w, h)
            c = auto.render(s, settings, w, h)
            bound.render(s, settings, w, h)
            b = fresh.render(s, settings, w, h)
            rows.append(dict(frame=k, rays_traced=a.stats["rays_traced"], fresh_rays=b.stats["rays_traced"],
                             pixels_reused=a.stats["pixels_reused"], shadow_ms=round(a.timings["shadow_ms"], 2),
                             auto_shadow_ms=round(c.timings["shadow_ms"], 2), auto_ways=c.stats["reuse_ways"],
                             retrace_ms=round(bound.shadow_pass("raytrace").reuse.retrace_ms, 2),
                             fresh_shadow_ms=round(b.timings["shadow_ms"], 2), mismatch=mismatch(a, b),
                             auto_mismatch=mismatch(c, b)))
            r = rows[-1]
            print(f"{label} {k}: rays {r['rays_traced']} / {r['fresh_rays']}, shadow {r['shadow_ms']:.1f} "
                  f"(auto {r['auto_shadow_ms']:.1f}, {r['auto_ways']}; retraced pixels alone {r['retrace_ms']:.1f}) / "
                  f"{r['fresh_shadow_ms']:.1f} ms, "
                  f"mismatch {100 * r['mismatch']:.4f} % (auto {100 * r['auto_mismatch']:.4f} %)", flush=True)
    finally:
        fresh.release()
        bound.release()
        auto.release()
        pipe.release()
    later = rows[1:]

    def ratio(col):
        return float(np.median([r[col] / max(r["fresh_shadow_ms"], 1e-9) for r in later]))

    summary = dict(rays_ratio=sum(r["rays_traced"] for r in later) / max(1, sum(r["fresh_rays"] for r in later)),
                   ms_ratio=ratio("shadow_ms"), auto_ms_ratio=ratio("auto_shadow_ms"),
                   retrace_ratio=ratio("retrace_ms"),
                   worst_mismatch=max(r["mismatch"] for r in later),
                   auto_worst_mismatch=max(r["auto_mismatch"] for r in later))
    print(f"{label}: rays {summary['rays_ratio']:.3f} of fresh, shadow ms {summary['ms_ratio']:.2f}x always reusing, "
          f"{summary['auto_ms_ratio']:.2f}x where it pays, the retraced pixels' trace alone "
          f"{summary['retrace_ratio']:.2f}x (medians), worst mismatch "
          f"{100 * summary['worst_mismatch']:.4f} % ({100 * summary['auto_worst_mismatch']:.4f} %)", flush=True)
    return dict(frames=rows, **summary)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["forest", "city", "clusters", "smooth_shapes"])
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--range", default=None, help="A-B: the path's frames to sample (default: all)")
    ap.add_argument("--orbit-step", type=float, default=0.02, help="radians a frame of an orbit")
    ap.add_argument("--no-grid", action="store_true", help="hard lights trace the tree, no light grids")
    ap.add_argument("--orbit", action="store_true", help="orbit every scene, whatever its path")
    ap.add_argument("--no-group", action="store_true",
                    help="the reusing pipelines without the refinement's group rule (a GPU's default)")
    ap.add_argument("--trace-path", default="auto", choices=("auto", "compute", "fragment"),
                    help="Settings.trace_path of every pipeline")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    rng = tuple(int(v) for v in args.range.split("-")) if args.range else None
    out = {}
    for name in args.scenes:
        scene, cams, frames = path_cameras(name, args.frames, rng)
        path = f"frames {frames[0]}-{frames[-1]} ({len(frames)})"
        if still(cams) or args.orbit:
            cams, path = orbit_cameras(scene, args.frames, args.orbit_step), f"orbit {args.orbit_step} rad/frame"
        print(f"{name}: {path}", flush=True)
        settings = HARD.replace(light_grid=not args.no_grid, trace_path=args.trace_path)
        group = False if args.no_group else None  # (None: the renderer's default)
        out[name] = dict(path=path, grids=not args.no_grid, no_group=args.no_group,
                         **run_path(name, scene, cams, w, h, settings, group=group))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
