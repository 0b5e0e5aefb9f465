"""The G-buffer's cost of smooth shading (the ``TERMINATOR`` geometry stage): a scene as it is
against the same scene with every flat model given corner normals (its face normals: the stage
runs, the lift is zero), alternated in one process; median G-buffer ms of each.

    .venv/bin/python -m benchmarks.bench_smooth_gbuffer forest --size 640x360 --repeats 6
"""
from __future__ import annotations

import argparse
import copy
import os
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def smooth_copy(scene):
    """``scene`` with every flat model given its face normals as corner normals."""
    from hybrid_shadow_addon.core.gpu.geometry import face_normals

    out = copy.deepcopy(scene)
    for m in out.models:
        if m.normals is None and m.triangle_count:
            m.normals = np.repeat(face_normals(m)[:, None, :], 3, axis=1).astype(np.float32)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--repeats", type=int, default=6)
    a = ap.parse_args(argv)
    from hybrid_shadow_addon.blender.load import load_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    w, h = (int(x) for x in a.size.split("x"))
    flat = load_scene(a.scene)
    runs = {"flat": (Pipeline(), flat), "smooth": (Pipeline(), smooth_copy(flat))}
    settings = Settings(mode="none")
    for pipe, scene in runs.values():
        pipe.set_scene(scene)
        for _ in range(2):  # shaders, buffers
            pipe.render(scene, settings, w, h)
    times = {k: [] for k in runs}
    for _ in range(a.repeats):
        for k, (pipe, scene) in runs.items():
            times[k].append(pipe.render(scene, settings, w, h).timings["gbuffer_ms"])
    f, s = (float(np.median(times[k])) for k in ("flat", "smooth"))
    print(f"{a.scene} {w}x{h}: G-buffer flat {f:.1f} ms, smooth {s:.1f} ms, smooth / flat {s / f:.2f}x")
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
