"""What a frame asks of the host along a camera orbit: its waits for the GPU and the bytes it
reads back beyond its RGBA32F image, per timing (``Pipeline.timing``: ``passes``, the CLI's and
benchmarks'; ``frame``, the viewport's), trace path and device model, with reuse and light grids
on (hard lights, high).

Device models: ``this`` (this context's defaults: on a software rasteriser light culling reads
back and the clock times choices with waits) and ``gpu`` (as a GPU's defaults: no host light
culling, the clock's timer queries read a frame later; on llvmpipe the queries' values are not
its work's time, so only the counts are a GPU's).

Per row: the most and the median waits of a frame, the most bytes read back beyond the image,
and the median ``total_ms`` (frames after the first two): with ``passes`` the sum of the passes'
times, each up to its wait; with ``frame`` the time up to the image read. Not a speed
comparison: the two measure different spans.

    .venv/bin/python -m benchmarks.bench_frame_waits [--scenes forest clusters city] [--size 640x360]
        [--frames 8] [--json OUT]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

from benchmarks.bench_reuse import orbit_cameras
from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import TIMINGS, Pipeline
from hybrid_shadow_addon.core.settings import Settings


def measure(scene, model: str, path: str, timing: str, w: int, h: int, frames: int) -> dict:
    pipe = Pipeline()
    try:
        pipe.set_scene(scene)
        pipe.timing, pipe.reuse = timing, True
        if model == "gpu":
            pipe.gpu.clock.queries = True
            rp = pipe.shadow_pass("raytrace")
            rp.options = dataclasses.replace(rp.options, cull_lights=False)
        settings = Settings(mode="raytrace", quality="high", hard=True, trace_path=path)
        got = []
        for cam in orbit_cameras(scene, frames, 0.005):
            f = pipe.render(dataclasses.replace(scene, camera=cam), settings, w, h)
            got.append((f.stats["waits"], f.stats["bytes_read_back"] - w * h * 16, f.timings["total_ms"]))
        got = got[2:]
        return {"max_waits": max(g[0] for g in got), "median_waits": statistics.median(g[0] for g in got),
                "max_extra_bytes": max(g[1] for g in got), "median_ms": round(statistics.median(g[2] for g in got), 1)}
    finally:
        pipe.release()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    print(f"{a.size}, {a.frames} frames (first 2 left out), hard lights at high, reuse and light grids on")
    print("| scene | device model | path | timing | most waits | median waits | most bytes beyond the image "
          "| median ms |\n|---|---|---|---|---:|---:|---:|---:|")
    rows = []
    for name in a.scenes:
        scene = load_scene(name)
        for model in ("this", "gpu"):
            for path in ("compute", "fragment"):
                for timing in TIMINGS:
                    r = dict(scene=name, model=model, path=path, timing=timing,
                             **measure(scene, model, path, timing, w, h, a.frames))
                    rows.append(r)
                    print(f"| {name} | {model} | {path} | {timing} | {r['max_waits']} | {r['median_waits']} | "
                          f"{r['max_extra_bytes']} | {r['median_ms']} |", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
