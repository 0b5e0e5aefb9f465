"""How often the long stages call their progress callback (and so how soon a cancel stops them):
the longest interval between two progress calls during a bake (each structure), the light
grids' builds (in the frame, ``eager_light_grids``) and a tiled final render, and the longest
tile of that render.

    .venv/bin/python -m benchmarks.bench_cancel_gaps [--scene forest] [--size 1280x720]
        [--max-draw-ms 100] [--json out.json]

Each case: its wall time, the number of progress calls, and the longest gap (ms) with the labels
on either side of it.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


class Gaps:
    """A progress callback that records when it was called."""

    def __init__(self):
        self.times = [time.perf_counter()]
        self.labels = ["(start)"]

    def __call__(self, done, total, label=""):
        self.times.append(time.perf_counter())
        self.labels.append(label)

    def result(self, name: str) -> dict:
        self.times.append(time.perf_counter())
        self.labels.append("(end)")
        gaps = [b - a for a, b in zip(self.times, self.times[1:])]
        i = max(range(len(gaps)), key=gaps.__getitem__)
        return {"name": name, "wall_ms": round((self.times[-1] - self.times[0]) * 1e3, 1),
                "calls": len(self.times) - 2, "max_gap_ms": round(gaps[i] * 1e3, 1),
                "between": [self.labels[i], self.labels[i + 1]]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="forest")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--max-draw-ms", type=float, default=100.0)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    from hybrid_shadow_addon.blender.load import load_scene
    from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
    from hybrid_shadow_addon.core.gpu.passes.trace import RaytraceOptions
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    w, h = (int(v) for v in a.size.lower().split("x"))
    scene = load_scene(a.scene)
    cases = []
    for structure in ("bvh", "grid"):
        g = Gaps()
        bake_scene(scene, BakeConfig(structure=structure), progress=g)
        cases.append(g.result(f"bake ({structure})"))
    pipe = Pipeline()
    try:
        rp = pipe.shadow_pass("raytrace")
        rp.options = RaytraceOptions(eager_light_grids=True)
        g = Gaps()  # (the frame's bake, then every hard light's grid, then its rays)
        pipe.render(scene, Settings(hard=True), 320, 180, progress=g)
        cases.append(g.result("bake + light grids (hard, eager, 320x180 frame)"))
        for label, settings in (("hard", Settings(hard=True)), ("soft", Settings())):
            pipe.gpu.budget.reset_stats()
            g = Gaps()
            pipe.render(scene, settings, w, h, progress=g, max_draw_ms=a.max_draw_ms)
            r = g.result(f"final render {w}x{h} {label}, max_draw_ms {a.max_draw_ms:g}")
            r.update(tiles=pipe.gpu.budget.tiles, longest_tile_ms=round(pipe.gpu.budget.longest_ms, 1))
            cases.append(r)
    finally:
        pipe.release()
    for c in cases:
        extra = f", {c['tiles']} tiles, longest {c['longest_tile_ms']} ms" if "tiles" in c else ""
        print(f"{c['name']}: {c['wall_ms']:.0f} ms, {c['calls']} calls, longest gap {c['max_gap_ms']} ms "
              f"({c['between'][0]!r} -> {c['between'][1]!r}){extra}")
    if a.json:
        a.json.write_text(json.dumps({"scene": a.scene, "cases": cases}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
