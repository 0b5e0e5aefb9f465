"""Pipeline benchmark on llvmpipe (a script, not a test): ms per pass and per mode.

    .venv/bin/python -m benchmarks.bench_pipeline [--scenes forest,clusters,city] [--reps 3]
        [--size 640x360] [--scaling 1000,10000,100000,1000000] [--no-scaling] [--maps]

Tables (warm: the first frame of every configuration compiles shaders and is discarded; median
of ``--reps`` frames; the machine is shared, so compare ratios measured in the same run):
1. ms per pass and mode (raytrace high/medium/low, shadowmap, none) per scene; with ``--maps``
   raytrace also with the conservative occupancy maps (suns, all lights), and the maps' share;
2. ray-traced shadow pass / shadow-map pass on each scene at equal resolution;
3. shadow ms as triangles grow (``scaling:triangles=N,instances=M``), sun only.
"""
from __future__ import annotations

import argparse
import statistics

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings

SCENES = {"forest": "forest", "clusters": "clusters", "city": "city"}
PASSES = ("gbuffer_ms", "shadow_ms", "upsample_ms", "lighting_ms", "total_ms")


def _frame(pipe, scene, settings, w, h):
    fr = pipe.render(scene, settings, w, h, read_image=False)
    t = dict(fr.timings)
    maps = settings.mode == "raytrace" and settings.conservative != "off"
    t["map_ms"] = pipe.shadow_pass("raytrace").last_map_ms if maps else 0.0
    return t


def measure_all(pipe, scene, configs, w, h, reps):
    """{label: median timings}; configurations interleaved round-robin so that the load of a
    shared machine hits them alike (the first frame of each, compiling shaders, discarded)."""
    for _, s in configs:
        _frame(pipe, scene, s, w, h)
    rows = {c[0]: [] for c in configs}
    for _ in range(reps):
        for label, s in configs:
            rows[label].append(_frame(pipe, scene, s, w, h))
    return {label: {k: statistics.median(r[k] for r in rs) for k in PASSES + ("map_ms",)}
            for label, rs in rows.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="forest,clusters,city")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--scaling", default="1000,10000,100000,1000000")
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--maps", action="store_true", help="also raytrace with conservative occupancy maps")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    pipe = Pipeline()
    ratio_rows = []
    print(f"## ms per pass ({w}x{h}, llvmpipe, median of {a.reps} warm frames)\n")
    print("| scene | mode | shadow ms | (of which maps) | g-buffer | upsample | lighting | total |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.scenes.split(","):
        scene = load_scene(SCENES.get(name, name))
        pipe.set_scene(scene)
        high = Settings(mode="raytrace", quality="high", hard=True)  # (hard shadows, as the thesis)
        configs = [("raytrace high", high)]
        if a.maps:
            configs += [("raytrace high, maps for suns", high.replace(conservative="sun")),
                        ("raytrace high, maps for all lights", high.replace(conservative="all"))]
        configs += [("raytrace medium", Settings(mode="raytrace", quality="medium", hard=True)),
                    ("raytrace low", Settings(mode="raytrace", quality="low", hard=True)),
                    ("shadowmap", Settings(mode="shadowmap", hard=True)),
                    ("none", Settings(mode="none"))]
        res = measure_all(pipe, scene, configs, w, h, a.reps)
        for label, *_ in configs:
            t = res[label]
            print(f"| {name} | {label} | {t['shadow_ms']:.0f} | {t['map_ms']:.0f} | {t['gbuffer_ms']:.0f} | "
                  f"{t['upsample_ms']:.0f} | {t['lighting_ms']:.0f} | {t['total_ms']:.0f} |", flush=True)
        ratio_rows.append((name, res))
    print(f"\n## ray-traced shadow pass / shadow-map pass (equal resolution {w}x{h}; thesis: 14.7x)\n")
    print("| scene | raytrace ms | shadowmap ms | ratio |")
    print("|---|---|---|---|")
    for name, res in ratio_rows:
        rt, sm = res["raytrace high"]["shadow_ms"], res["shadowmap"]["shadow_ms"]
        print(f"| {name} | {rt:.0f} | {sm:.0f} | {rt / sm:.1f}x |")
    if a.no_scaling:
        return
    print(f"\n## shadow ms as triangles grow (scaling scene, {w}x{h}, ray traced high)\n")
    print("| triangles | instances | raytrace ms | shadowmap ms | rt step ratio |")
    print("|---|---|---|---|---|")
    prev = None
    for n in (int(v) for v in a.scaling.split(",")):
        inst = max(1, min(1000, n // 1000))
        scene = load_scene(f"scaling:triangles={n},instances={inst}")
        pipe.set_scene(scene)
        rt_s = Settings(mode="raytrace", hard=True)
        configs = [("rt", rt_s), ("shadowmap", Settings(mode="shadowmap", hard=True))]
        res = measure_all(pipe, scene, configs, w, h, a.reps)
        rt, sm = res["rt"]["shadow_ms"], res["shadowmap"]["shadow_ms"]
        step = "" if prev is None else f"{rt / prev:.2f}x"
        print(f"| {n} | {inst} | {rt:.0f} | {sm:.0f} | {step} |", flush=True)
        prev = rt
    pipe.release()


if __name__ == "__main__":
    main()
