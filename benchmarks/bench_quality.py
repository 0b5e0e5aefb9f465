"""Shadow quality levels against each other and against Cycles: for each scene and quality, the
shadow pass's ms (median of warm frames, the qualities interleaved in each repeat), rays traced
per pixel (``Frame.stats``: ``rays_traced / pixels``) and the mismatch against the Cycles
per-light visibility (% of valid pixels, all lights together, and the worst light).

    .venv/bin/python -m benchmarks.bench_quality [--scenes forest,clusters,city,stiff/*] \
        [--size 320x180] [--repeats 3] [--variants high,medium,low] [--json out.json] [--plot out.png]

Scenes under ``stiff/`` render at their own size (200x150); the others at ``--size``. Cycles
references are cached on disk (``tools/reference.py``: ``$XDG_CACHE_HOME/hybrid_shadows``).
A variant is a quality, optionally with ``+key=value`` settings (``medium+conservative=all``);
``+method=depth`` (the default, and the only method) picks how the refinement traces its marked
pixels (``RaytraceOptions.refine_method``) and ``+view_cos=0.3`` (any key of ``Refiner.RULES``) sets a
refinement rule (``passes/refine.py``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

SCENES = ("forest", "clusters", "city")


def stiff_cases() -> list:
    return sorted(f"stiff/{p.stem}" for p in (REPO / "test_scenes" / "stiff").glob("*.py")
                  if not p.stem.startswith("_"))


def parse_variant(text: str) -> dict:
    parts = text.split("+")
    out = {"mode": "raytrace", "quality": parts[0], "hard": True}  # (the Cycles references are hard)
    for kv in parts[1:]:
        k, v = kv.split("=", 1)
        out[k] = {"true": True, "false": False}.get(v.lower(), int(v) if v.isdigit() else v)
    return out


def reference(bscene, scene, resolution):
    """Per-light Cycles visibility at ``resolution``, from the disk cache when there."""
    from hybrid_shadow_addon.blender.cycles_reference import CyclesReferenceProvider
    from hybrid_shadow_addon.tools.reference import default_cache_dir, load_cached, reference_key, save_cached

    prov = CyclesReferenceProvider(bscene)
    names = prov.light_names(scene)
    path = default_cache_dir(prov) / f"{reference_key(scene, resolution, 1, names, prov)}.npz"
    hit = load_cached(path)
    if hit is not None and set(hit[0]) == set(names):
        return hit[0], True
    vis, ms = {}, {}
    for n in names:
        vis[n], ms[n] = prov.visibility(scene, n, resolution, 1)
    save_cached(path, vis, ms)
    return vis, False


def run_scene(arg: str, size, variants, repeats: int, ctx, refs_only: bool = False) -> dict:
    import bpy

    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings
    from hybrid_shadow_addon.tools.metrics import combine, mask_error

    bscene = open_scene(arg)
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get()).validate()
    W, H = scene.resolution if arg.startswith("stiff/") else size
    t0 = time.perf_counter()
    ref, cached = reference(bscene, scene, (W, H))
    out = {"scene": arg, "resolution": [W, H], "reference_cached": cached, "reference_s": time.perf_counter() - t0,
           "variants": {}}
    if refs_only:
        return out
    pipe = Pipeline(ctx)
    try:
        pipe.set_scene(scene)
        rt = pipe.shadow_pass("raytrace")
        refiner = rt.refiner
        default_options, default_rules = rt.options, dict(refiner.rules)
        parsed = {v: parse_variant(v) for v in variants}
        methods = {v: parsed[v].pop("method", None) for v in variants}
        rules = {v: {k: float(parsed[v].pop(k)) for k in list(parsed[v]) if k in default_rules} for v in variants}
        settings = {v: Settings(**parsed[v]) for v in variants}

        def render(v):
            rt.options = replace(default_options, refine_method=methods[v] or default_options.refine_method)
            refiner.rules = {**default_rules, **rules[v]}
            return pipe.render(scene, settings[v], W, H)

        times = {v: [] for v in variants}
        for v in variants:  # warm-up (shader compilation)
            render(v)
        errors, stats = {}, {}
        for rep in range(repeats):
            for v in variants:
                f = render(v)
                times[v].append(f.timings["shadow_ms"])
                if rep == repeats - 1:  # (a frame's masks are valid until the next render)
                    errors[v] = {scene.lights[li].name: mask_error(ref[scene.lights[li].name], f.mask_array(li))
                                 for li in f.lights if scene.lights[li].name in ref}
                    stats[v] = f.stats
        for v in variants:
            per = errors[v]
            tot = combine(per.values())
            st = stats[v]
            out["variants"][v] = {
                "shadow_ms": float(np.median(times[v])), "shadow_ms_all": [float(t) for t in times[v]],
                "rays_traced": st["rays_traced"], "pixels": st["pixels"],
                "rays_per_pixel": st["rays_traced"] / st["pixels"] if st["pixels"] else 0.0,
                "mismatch_pct": tot.mismatch_pct, "mismatch": tot.mismatch_pixels, "valid": tot.valid_pixels,
                "worst_light_pct": max((e.mismatch_pct for e in per.values()), default=0.0),
                "lights": {n: e.mismatch_pct for n, e in per.items()}}
    finally:
        pipe.release()
    return out


def table(results: list, variants) -> str:
    head = "| scene | " + " | ".join(f"{v} ms | {v} rays/px | {v} mismatch % (worst light)" for v in variants) + " |"
    lines = [head, "|---|" + "---|---|---|" * len(variants)]
    sums = {v: 0.0 for v in variants}
    for r in results:
        cells = []
        for v in variants:
            x = r["variants"][v]
            sums[v] += x["shadow_ms"]
            cells += [f"{x['shadow_ms']:.0f}", f"{x['rays_per_pixel']:.3f}",
                      f"{x['mismatch_pct']:.3f} ({x['worst_light_pct']:.3f})"]
        lines.append(f"| {r['scene']} {r['resolution'][0]}x{r['resolution'][1]} | " + " | ".join(cells) + " |")
    base = sums[variants[0]] or 1.0
    lines.append("| **sum of shadow ms** | " + " | ".join(f"**{sums[v]:.0f}** ({sums[v] / base:.2f}x) | | "
                                                      for v in variants) + " |")
    return "\n".join(lines)


def plot(results: list, variants, path) -> None:
    """Mismatch against Cycles (log) against the summed shadow ms, one point per variant."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5), dpi=110)
    ax = fig.subplots()
    for v in variants:
        ms = sum(r["variants"][v]["shadow_ms"] for r in results)
        mm = sum(r["variants"][v]["mismatch"] for r in results)
        n = sum(r["variants"][v]["valid"] for r in results)
        e = max(100.0 * mm / n if n else 0.0, 1e-4)
        ax.scatter([ms], [e], s=46, zorder=3)
        ax.annotate(v, (ms, e), textcoords="offset points", xytext=(6, 4), fontsize=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("shadow ms, summed over the scenes (log)")
    ax.set_ylabel("mismatch against Cycles, % of valid pixels (log)")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"{len(results)} scenes: shadow error against shadow time")
    fig.tight_layout()
    fig.savefig(path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", default=",".join(SCENES) + ",stiff/*")
    p.add_argument("--size", default="320x180")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--variants", default="high,medium,low")
    p.add_argument("--json")
    p.add_argument("--plot")
    p.add_argument("--refs-only", action="store_true", help="only render (and cache) the Cycles references")
    a = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", "/tmp/hs-stiff-blender")
    from hybrid_shadow_addon.core.gpu.context import create_context

    size = tuple(int(v) for v in a.size.split("x"))
    scenes = []
    for s in (s for s in a.scenes.split(",") if s):
        scenes += stiff_cases() if s == "stiff/*" else [s]
    variants = [v for v in a.variants.split(",") if v]
    ctx = None if a.refs_only else create_context()
    results = []
    for s in scenes:
        t0 = time.perf_counter()
        r = run_scene(s, size, variants, a.repeats, ctx, a.refs_only)
        results.append(r)
        print(f"{s}: {time.perf_counter() - t0:.1f} s (reference {'cached' if r['reference_cached'] else 'rendered'})",
              file=sys.stderr, flush=True)
        if a.json:
            Path(a.json).write_text(json.dumps(results, indent=1))
    if not a.refs_only:
        print(table(results, variants))
        if a.plot:
            plot(results, variants, a.plot)
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
