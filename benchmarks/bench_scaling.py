"""Scaling benchmark over the ``scaling`` scene: shadow ms per mode, bake ms and texture MB as the
triangle count (1k -> 1M, at 100 instances) and the instance count (10 -> 100k, at 100k
triangles in all) grow. Prints a table; writes ``scaling.json`` and ``scaling.png``.

    .venv/bin/python -m benchmarks.bench_scaling [--resolution 320x180] [--repeats 3]
        [--triangles 1000 10000 100000 1000000] [--instances 10 100 1000 10000 100000]
        [--modes raytrace-high shadowmap-2048 none] [--output-dir out/bench_scaling]

Shadow ms: median of ``--repeats`` warm frames (``Frame.timings["shadow_ms"]``; the light grids
built up front, their build with the bake's, not timed); the frame's
total in ``scaling.json``. Export (Blender, not part of the comparison) and bake are timed once
per scene. One Pipeline for every scene and mode. The default run takes about 1-2 minutes on a
2-core machine with llvmpipe (timings are noisy there: other work shares the cores). The instance
sweep keeps the triangles in all, so its models shrink to a 6-triangle minimum at 100k instances.
"""
import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from hybrid_shadow_addon.__main__ import blender_output_to_stderr, parse_resolution
from hybrid_shadow_addon.tools.variants import resolve_variants


def measure(pipe, arg, variants, resolution, repeats, warmup):
    from hybrid_shadow_addon.blender.load import load_scene

    t0 = time.perf_counter()
    with blender_output_to_stderr():
        scene = load_scene(arg)
    export_ms = (time.perf_counter() - t0) * 1e3
    bake_ms = pipe.set_scene(scene)
    row = {"scene": arg, "triangles": int(scene.triangle_count), "unique_triangles": int(scene.unique_triangle_count),
           "instances": len(scene.instances), "export_ms": export_ms, "bake_ms": bake_ms,
           "texture_mb": pipe.scene_textures.nbytes / 1e6, "shadow_ms": {}, "total_ms": {}}
    w, h = resolution
    for v in variants:
        sh, tot = [], []
        for k in range(warmup + repeats):
            f = pipe.render(scene, v.settings, w, h, read_image=False)
            if k >= warmup:
                sh.append(f.timings["shadow_ms"])
                tot.append(f.timings["total_ms"])
        row["shadow_ms"][v.name] = float(np.median(sh))
        row["total_ms"][v.name] = float(np.median(tot))
    return row


def plot(rows, sweeps, variants, path):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 7), dpi=100)
    axes = fig.subplots(2, 2)
    for col, (sweep, key, xlabel) in enumerate((("triangles", "triangles", "triangles placed (instances x model)"),
                                               ("instances", "instances", "instances"))):
        rs = [r for r in rows if r["sweep"] == sweep]
        if not rs:
            continue
        x = [r[key] for r in rs]
        ax = axes[0][col]
        for v in variants:
            ax.plot(x, [max(r["shadow_ms"][v.name], 1e-3) for r in rs], marker="o", label=f"shadow ms: {v.label}")
        ax.plot(x, [r["bake_ms"] for r in rs], marker="s", ls="--", color="k", label="bake ms")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("ms")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        ax.set_title(f"vs {sweep} ({sweeps[sweep]})", fontsize=10)
        ax = axes[1][col]
        ax.plot(x, [r["texture_mb"] for r in rs], marker="o", color="tab:purple")
        ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("scene textures, MB")
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=parse_resolution, default=(320, 180))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--triangles", type=int, nargs="*", default=[1_000, 10_000, 100_000, 1_000_000])
    ap.add_argument("--triangles-instances", type=int, default=100, help="instances in the triangle sweep")
    ap.add_argument("--instances", type=int, nargs="*", default=[10, 100, 1_000, 10_000, 100_000])
    ap.add_argument("--instances-triangles", type=int, default=100_000, help="triangles in the instance sweep")
    ap.add_argument("--modes", nargs="+", default=["raytrace-high", "shadowmap-2048", "none"])
    ap.add_argument("--output-dir", default="out/bench_scaling")
    args = ap.parse_args()

    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    variants = resolve_variants(args.modes)
    w, h = args.resolution
    cases = [("triangles", f"scaling:triangles={t},instances={args.triangles_instances},width={w},height={h}")
             for t in args.triangles]
    cases += [("instances", f"scaling:triangles={args.instances_triangles},instances={i},width={w},height={h}")
              for i in args.instances]
    sweeps = {"triangles": f"{args.triangles_instances} instances",
              "instances": f"{args.instances_triangles} triangles"}
    pipe = Pipeline()
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=True)  # (hard lights' grids up front, not mid-run)
    rows = []
    names = [v.name for v in variants]
    head = f"{'sweep':<10}{'triangles':>11}{'unique':>9}{'instances':>10}{'export ms':>10}{'bake ms':>9}" \
        f"{'tex MB':>8}" + "".join(f"{n:>16}" for n in names)
    print(f"shadow ms per mode at {w}x{h}, median of {args.repeats}")
    print(head, flush=True)
    t_all = time.perf_counter()
    for sweep, arg in cases:
        r = measure(pipe, arg, variants, (w, h), args.repeats, args.warmup)
        r["sweep"] = sweep
        rows.append(r)
        print(f"{sweep:<10}{r['triangles']:>11}{r['unique_triangles']:>9}{r['instances']:>10}{r['export_ms']:>10.0f}{r['bake_ms']:>9.0f}"
              f"{r['texture_mb']:>8.1f}" + "".join(f"{r['shadow_ms'][n]:>16.1f}" for n in names), flush=True)
    pipe.release()
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling.json").write_text(json.dumps({"resolution": [w, h], "repeats": args.repeats, "sweeps": sweeps,
                                                   "rows": rows}, indent=2) + "\n")
    plot(rows, sweeps, variants, out / "scaling.png")
    print(f"{time.perf_counter() - t_all:.0f} s; wrote {out / 'scaling.json'} and {out / 'scaling.png'}")
    sys.stdout.flush()
    os._exit(0)  # bpy can take seconds tearing down


if __name__ == "__main__":
    main()
