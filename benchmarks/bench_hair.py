"""Cost of a groom: the hair scene with a Curves object of ``--strands`` strands (6 points each),
exported as tubes. Prints export ms, bake ms, triangles, texture memory and the shadow pass ms
(ray traced, high quality, hard lights; and a 2048 shadow map) at ``--size``.

    .venv/bin/python -m benchmarks.bench_hair [--strands 100000] [--size 640x360] [--frames 5]
"""
import argparse
import statistics
import time

import bpy

from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.blender.load import open_scene
from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


def shadow_ms(scene, mode: str, width: int, height: int, frames: int) -> float:
    """Median shadow-pass ms over ``frames`` frames after two warm-up frames."""
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    pipe = Pipeline()
    pipe.set_scene(scene)
    settings = Settings(mode=mode, quality="high", hard=True)
    rows = [pipe.render(scene, settings, width, height).timings for _ in range(frames + 2)][2:]
    return statistics.median(r["shadow_ms"] for r in rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--strands", type=int, default=100_000, help="strands of the Curves object")
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=5)
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))

    open_scene(f"hair:strands={args.strands}")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    t0 = time.perf_counter()
    scene = export_depsgraph(depsgraph)
    export_ms = _ms(t0)
    t0 = time.perf_counter()
    scene = export_depsgraph(depsgraph)  # warm: the strands of an unchanged depsgraph read again
    export_again_ms = _ms(t0)
    t0 = time.perf_counter()
    baked = bake_scene(scene, BakeConfig())
    bake_ms = _ms(t0)
    print(f"strands              {args.strands} (Curves) + particle hair and points of the hair scene")
    print(f"triangles            {scene.triangle_count} ({scene.unique_triangle_count} unique, "
          f"{len(scene.instances)} instances)")
    print(f"export ms            {export_ms:.0f} (again: {export_again_ms:.0f})")
    print(f"bake ms              {bake_ms:.0f}")
    print(f"texture memory MB    {baked.stats['total_bytes'] / 2**20:.1f}")
    for mode in ("raytrace", "shadowmap"):
        print(f"shadow ms {mode:10s} {shadow_ms(scene, mode, width, height, args.frames):.1f} "
              f"at {width}x{height} (median of {args.frames})")
    for line in scene.report:
        print(f"report: {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
