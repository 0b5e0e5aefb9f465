"""The stiff scenes (``test_scenes/stiff/``) against Cycles: one markdown table of every case x
mode with the mismatch (% of valid pixels where |ours - Cycles| > 0.5), the MAE and the shadow
time, worst light per case first. The lead pastes the output into BENCHMARKS.md.

    .venv/bin/python -m benchmarks.stiff_table [--cases grazing,far_away] [--modes raytrace-high,shadowmap]

Metrics come from ``hybrid_shadow_addon.tools.metrics`` (the ``compare`` tool's) when present.
``evaluate_case`` is also what ``tests/test_stiff.py`` runs.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

CASES = ("grazing", "axis_aligned", "far_away", "stadium", "cards", "degenerate", "crowd", "instance_scales",
         "point_in_box", "spot_touching", "ortho", "clip_range")
MODES = {  # name -> Settings kwargs
    "raytrace-high": dict(mode="raytrace", quality="high", hard=True),  # (hard Cycles references)
    "raytrace-medium": dict(mode="raytrace", quality="medium", hard=True),
    "shadowmap": dict(mode="shadowmap", hard=True),
}


def mask_metrics(reference: np.ndarray, ours: np.ndarray) -> dict:
    """valid, mismatch (pixels), missed, false, mismatch_pct, mae over pixels valid in both."""
    try:
        from hybrid_shadow_addon.tools.metrics import mask_error
    except ImportError:  # pragma: no cover - before the compare module existed
        mask_error = None
    if mask_error is not None:
        e = mask_error(reference, ours)
        return dict(valid=e.valid_pixels, mismatch=e.mismatch_pixels, missed=e.missed_pixels, false=e.false_pixels,
                    mismatch_pct=e.mismatch_pct, mae=e.mae)
    valid = np.isfinite(reference) & np.isfinite(ours)
    d = ours[valid].astype(np.float64) - reference[valid]
    n = int(valid.sum())
    mm = int((np.abs(d) > 0.5).sum())
    return dict(valid=n, mismatch=mm, missed=int((d > 0.5).sum()), false=int((d < -0.5).sum()),
                mismatch_pct=100.0 * mm / n if n else 0.0, mae=float(np.abs(d).mean()) if n else 0.0)


def evaluate_case(name: str, modes=("raytrace-high",), *, ctx=None, params: str = "", repeats: int = 3,
                  keep_masks: bool = False, eager_grids: bool = False) -> dict:
    """Load ``stiff/<name>``, render the Cycles reference at the scene's resolution and each mode
    with one pipeline; ``{mode: {light: metrics + shadow_ms}}`` plus ``'_scene'`` and ``'_ref'``.
    ``eager_grids``: the hard lights' grids from the first frame on (``passes/light_grid.py``),
    not only once they pay back. ``keep_masks`` also keeps the last frame's G-buffer depth and
    camera (``'_depth'``, ``'_camera'``) and the bake's origin (``'_origin'``)."""
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    arg = f"stiff/{name}" + (f":{params}" if params else "")
    bscene = open_scene(arg)
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get()).validate()
    W, H = scene.resolution
    t0 = time.perf_counter()
    ref = render_reference(bscene, resolution=(W, H))
    out = {"_scene": scene, "_ref": ref, "_cycles_s": time.perf_counter() - t0}
    pipe = Pipeline(ctx)
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=eager_grids)
    try:
        bake_ms = pipe.set_scene(scene)
        out["_bake_ms"] = bake_ms
        out["_baked_stats"] = dict(pipe.baked.stats)
        for mode in modes:
            settings = Settings(**MODES[mode])
            frame = pipe.render(scene, settings, W, H)  # warm-up: shader compilation
            times = []
            for _ in range(repeats):
                frame = pipe.render(scene, settings, W, H)
                times.append(frame.timings["shadow_ms"])
            res = {}
            for li in frame.lights:
                lname = scene.lights[li].name
                ours = frame.mask_array(li)
                m = mask_metrics(ref.visibility[lname], ours)
                m["shadow_ms"] = float(np.median(times))
                if keep_masks:
                    m["ours"] = ours
                    m["ref"] = ref.visibility[lname]
                res[lname] = m
            out[mode] = res
        if keep_masks:  # instance index per pixel (G-buffer), -1 on background
            gb = frame.gbuffer
            inst = gb.read("material")[..., 2]
            out["_instance"] = np.where(gb.read("position")[..., 3] > 0.5, np.rint(inst), -1).astype(np.int64)
            out["_depth"], out["_camera"], out["_origin"] = gb.read("depth"), gb.camera, np.array(pipe.baked.origin)
    finally:
        pipe.release()
    return out


def table(results: dict, modes) -> str:
    lines = ["| case | light | " + " | ".join(f"{m} mismatch % | {m} MAE | {m} ms" for m in modes) + " |",
             "|---|---|" + "---|---|---|" * len(modes)]
    for case, r in results.items():
        lights = list(r[modes[0]].keys())
        for lname in lights:
            cells = []
            for m in modes:
                x = r[m][lname]
                cells += [f"{x['mismatch_pct']:.3f} ({x['mismatch']}/{x['valid']})", f"{x['mae']:.4f}",
                          f"{x['shadow_ms']:.1f}"]
            lines.append(f"| {case} | {lname} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--modes", default=",".join(MODES))
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", "/tmp/hs-stiff-blender")
    from hybrid_shadow_addon.core.gpu.context import create_context

    ctx = create_context()
    modes = [m for m in a.modes.split(",") if m]
    results = {}
    for case in [c for c in a.cases.split(",") if c]:
        t0 = time.perf_counter()
        r = evaluate_case(case, modes, ctx=ctx, repeats=a.repeats)
        results[case] = r
        print(f"{case}: {time.perf_counter() - t0:.1f} s (Cycles {r['_cycles_s']:.1f} s)", file=sys.stderr, flush=True)
    print(table(results, modes))
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
