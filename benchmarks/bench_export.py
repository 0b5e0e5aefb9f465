"""Time export_depsgraph: 100k instances (< 2 s) and 1M triangles (< 3 s), then every test scene.

Run from the repository root: ``.venv/bin/python -m benchmarks.bench_export``.
Each case: one warm-up export, then the median of 3.
"""
import os
import statistics
import sys
import tempfile
import time

for var in ("BLENDER_USER_RESOURCES", "XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
    os.environ.setdefault(var, tempfile.mkdtemp(prefix="hs-bench-"))

import bpy  # noqa: E402  (after the variables above: bpy reads them when it starts)

from hybrid_shadow_addon.blender.export import export_depsgraph  # noqa: E402
from hybrid_shadow_addon.blender.load import builtin_scenes, open_scene  # noqa: E402

TARGETS = [
    ("100k instances", "scaling:instances=100000,triangles=1000000", 2.0),
    ("1M triangles", "scaling:instances=100,triangles=1000000,models=100", 3.0),
]


def timed_export(arg):
    """(scene, median seconds of 3 exports after a warm-up, build seconds)."""
    t0 = time.perf_counter()
    open_scene(arg)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    build = time.perf_counter() - t0
    scene = export_depsgraph(depsgraph)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        scene = export_depsgraph(depsgraph)
        times.append(time.perf_counter() - t)
    return scene, statistics.median(times), build


def main():
    rows = []
    for label, arg, target in TARGETS:
        scene, seconds, _ = timed_export(arg)
        rows.append((label, len(scene.instances), len(scene.models), scene.triangle_count,
                     scene.unique_triangle_count, seconds, target))
    scenes = []
    for name in builtin_scenes():
        scene, seconds, build = timed_export(name)
        scenes.append((name, len(scene.instances), len(scene.models), scene.triangle_count, build, seconds))

    print()
    print(f"{'case':<16}{'instances':>10}{'models':>8}{'triangles':>11}{'unique':>10}{'export s':>10}{'target':>8}  ok")
    for label, n, m, t, u, s, target in rows:
        print(f"{label:<16}{n:>10}{m:>8}{t:>11}{u:>10}{s:>10.3f}{'<' + str(target):>8}  "
              f"{'yes' if s < target else 'NO'}")
    print()
    print(f"{'scene':<16}{'instances':>10}{'models':>8}{'triangles':>11}{'build ms':>10}{'export ms':>10}")
    for name, n, m, t, build, s in scenes:
        print(f"{name:<16}{n:>10}{m:>8}{t:>11}{build * 1e3:>10.0f}{s * 1e3:>10.1f}")
    return 0 if all(s < target for *_, s, target in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
