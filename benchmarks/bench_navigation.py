"""The rendered viewport after a change: how long until the first image and until the last,
with the navigation quality ``Low`` against ``Automatic`` (``blender/properties.py``), in the
same run.

Each change is one render request to the viewport's render worker (``core/runtime/worker.py``,
its own thread and context, as in Blender) with the settings the viewport builds: the fast pass
(the navigation quality; with soft lights only ``frame_samples`` rays a pixel and no probe pass)
then the full-quality frames (``high``; soft lights accumulate up to ``--samples``). ``Low``
always renders its fast pass at ``low``; ``Automatic`` keeps the viewport quality on a software
rasteriser (this machine's llvmpipe), where ``low`` costs more than ``high``. Timed from the
request: the first image, the first full-quality frame and the last frame (the worker idle);
medians over ``--repeats`` changes, the two choices alternating.

    .venv/bin/python -m benchmarks.bench_navigation [forest clusters city] [--size 640x360] [--repeats 3] [--soft]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.runtime.worker import RenderRequest, RenderWorker, snapshot
from hybrid_shadow_addon.core.settings import Settings


def change(worker, scene, fast, full, w, h, auto: bool, view: str) -> tuple:
    """(ms to the first image, to the first full-quality frame, to the last frame, frames)."""
    t0 = time.perf_counter()
    seq = worker.render(RenderRequest(view=view, scene=snapshot(scene), fast=fast, full=full, width=w, height=h,
                                      fast_auto=auto))
    first = full_at = None
    frames = 0
    while True:
        result, errors = worker.poll(view)
        if errors:
            raise RuntimeError(errors[0])
        now = (time.perf_counter() - t0) * 1e3
        if result is not None and result.seq == seq:
            frames = result.step + 1
            first = now if first is None else first
            if full_at is None and result.settings == full:
                full_at = now
            if result.refine_left == 0:
                return first, full_at, now, frames
        if not worker.busy(view) and result is None and first is not None:
            return first, full_at, now, frames
        time.sleep(0.001)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--soft", action="store_true", help="the lights' sizes (soft shadows, accumulating)")
    ap.add_argument("--samples", type=int, default=16, help="soft samples the viewport accumulates")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    hard = not args.soft
    full = Settings(mode="raytrace", quality="high", hard=hard, accumulate=True, samples=args.samples, frame_samples=4)
    fast = dataclasses.replace(full, quality="low", samples=4 if args.soft else args.samples)
    worker = RenderWorker()
    print(f"{'soft' if args.soft else 'hard'} lights, {w}x{h}, medians of {args.repeats} changes "
          "(ms from the request)\n")
    print("| scene | navigation | first image | first full-quality frame | last frame | frames |")
    print("|---|---|---:|---:|---:|---:|")
    try:
        for spec in args.scenes:
            scene = load_scene(spec)
            worker.set_scene(scene)
            change(worker, scene, full, full, w, h, False, spec)  # (compiles and bakes)
            change(worker, scene, fast, full, w, h, False, spec)
            got = {"Low": [], "Automatic": []}
            for _ in range(args.repeats):
                for name, auto in (("Low", False), ("Automatic", True)):
                    got[name].append(change(worker, scene, fast, full, w, h, auto, spec))
            for name, rows in got.items():
                a = np.array([[np.nan if v is None else v for v in r] for r in rows], np.float64)
                med = np.nanmedian(a, axis=0)
                print(f"| {spec} | {name} | {med[0]:.0f} | {med[1]:.0f} | {med[2]:.0f} | {int(med[3])} |", flush=True)
    finally:
        worker.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
