"""Alpha-cut shadows: what the alpha test costs, same run. ``alpha_cards`` (leaf cards, an
instanced leaf cluster, a chain-link fence, all cut by alpha textures; a textured ground; a sun
and a spot) against the same scene with ``opaque=1`` (the cards' and the fence's Alpha unlinked:
the same images for colour, no cut), against the alpha scene's geometry with every material
and image removed (``no images``: plain colours), ``closest=1`` (``binary``: the leaf's and
the fence's alpha strictly 0 or 1, Closest interpolation, so that no pixel blends two surfaces),
and ``one cut``: the alpha scene with only the card ``Card flat`` cut (every other instance on an
uncut copy of its material), which compiles the same alpha tracer as the alpha scene but has
almost no ray crossing a cut surface: what the alpha code costs by itself.

Per variant and structure: the shadow pass's ms (ray-traced high, every light hard; median of
``--repeats`` frames after ``--warmup``, the variants interleaved in each repeat, one pipeline
each on one context), the bake's ms (median of ``--bake-repeats`` ``bake_scene`` calls, the
material atlas included) with its ``atlas_ms``, the textures' MB (``BakedScene.texture_bytes``:
all of them, and the atlas + material records ``baked.materials.nbytes``), and the mismatch
against Cycles' per-light hard visibility (``tools/metrics.py``: |ours - Cycles| > 0.5, % of the
valid pixels of all lights together, worst light in brackets). For the alpha scene also the
mismatch over the pixels whose camera ray crosses no surface of fractional alpha (where Cycles
does not blend two surfaces into one pixel; tests/test_alpha_cycles.py explains why).

    .venv/bin/python -m benchmarks.bench_alpha [--size 640x360] [--repeats 5] [--warmup 2]
        [--structures bvh grid] [--json out.json]

Cycles references are cached on disk (``tools/reference.py``: ``$XDG_CACHE_HOME/hybrid_shadows``).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

VARIANTS = ("alpha", "binary", "one cut", "opaque", "no images")
LABELS = {"alpha": "alpha_cards", "binary": "alpha_cards:closest=1", "one cut": "alpha_cards, one card cut",
          "opaque": "alpha_cards:opaque=1", "no images": "alpha_cards, materials removed"}
ONE_CUT = "Card flat"


def strip_materials(scene):
    """``scene`` with no materials or images (every instance its plain base colour)."""
    inst = dataclasses.replace(scene.instances, material_ids=np.full(len(scene.instances), -1, np.int32))
    return dataclasses.replace(scene, instances=inst, materials=[], images=[]).validate()


def only_one_cut(scene, name: str):
    """``scene`` with only instance ``name`` cutting its shadow: every other instance gets a copy of
    its material without the alpha image."""
    k = len(scene.materials)
    mats = list(scene.materials) + [dataclasses.replace(m, alpha_image=-1) for m in scene.materials]
    mids = scene.instances.material_ids.copy()
    others = (mids >= 0) & (np.array(scene.instances.names) != name)
    mids[others] += k
    inst = dataclasses.replace(scene.instances, material_ids=mids)
    return dataclasses.replace(scene, instances=inst, materials=mats).validate()


def load(arg: str, size):
    import bpy

    from benchmarks.bench_quality import reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    bscene = open_scene(arg)
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=size).validate()
    t0 = time.perf_counter()
    ref, cached = reference(bscene, scene, size)  # hard lights
    print(f"{arg}: Cycles reference {'cached' if cached else f'{time.perf_counter() - t0:.1f} s'}",
          file=sys.stderr, flush=True)
    return scene, ref


def single_surface(scene, frame) -> np.ndarray:
    """(H, W) bool: covered pixels whose camera ray crosses no fractional alpha (numpy oracle)."""
    from hybrid_shadow_addon.core.oracle.tracer import visibility_brute

    pos = frame.gbuffer.read("position")
    cov = pos[..., 3] > 0.5
    p = pos[..., :3][cov].astype(np.float64)
    cam = np.broadcast_to(scene.camera.matrix[:3, 3].astype(np.float64), p.shape)
    front = visibility_brute(scene, cam, p - cam, 1.0 - 1e-4)
    through = visibility_brute(scene, cam, p - cam, 1.0 + 1e-4)
    own = np.where(front > 0, 1.0 - through / np.maximum(front, 1e-12), 1.0)
    out = np.zeros(cov.shape, bool)
    out[cov] = (front >= 0.999) & (own >= 0.999)
    return out


def bake_figures(scene, structure: str, repeats: int) -> dict:
    from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene

    ms, atlas_ms = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        b = bake_scene(scene, BakeConfig(structure=structure))
        ms.append((time.perf_counter() - t0) * 1e3)
        atlas_ms.append(b.materials.atlas_ms if b.materials is not None else 0.0)
    tex = b.texture_bytes
    return {"bake_ms": float(np.median(ms)), "bake_ms_all": ms, "atlas_ms": float(np.median(atlas_ms)),
            "texture_bytes": {k: int(v) for k, v in tex.items()}, "texture_mb": sum(tex.values()) / 2 ** 20,
            "material_mb": (b.materials.nbytes if b.materials is not None else 0) / 2 ** 20,
            "atlas": (f"{b.materials.atlas.layers} x {b.materials.atlas.width}x{b.materials.atlas.height}"
                      if b.materials is not None else None),
            "alpha_models": int(b.stats.get("alpha_models", 0))}


def run(size, structures, repeats: int, warmup: int, bake_repeats: int, ctx) -> dict:
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings
    from hybrid_shadow_addon.tools.metrics import combine, mask_error

    W, H = size
    alpha, ref_alpha = load(f"alpha_cards:width={W},height={H}", size)
    binary, ref_binary = load(f"alpha_cards:width={W},height={H},closest=1", size)
    opaque, ref_opaque = load(f"alpha_cards:width={W},height={H},opaque=1", size)
    scenes = {"alpha": (alpha, ref_alpha), "binary": (binary, ref_binary),
              "one cut": (only_one_cut(alpha, ONE_CUT), None),
              "opaque": (opaque, ref_opaque),
              "no images": (strip_materials(alpha), ref_opaque)}  # (the opaque scene's shadows)
    out = {"resolution": [W, H], "triangles": int(alpha.triangle_count), "instances": len(alpha.instances),
           "images": len(alpha.images), "materials": len(alpha.materials),
           "lights": [light.name for light in alpha.lights],
           "repeats": repeats, "warmup": warmup, "rows": {}}
    for s in structures:
        settings = Settings(mode="raytrace", quality="high", structure=s, hard=True)
        pipes = {v: Pipeline(ctx) for v in VARIANTS}
        try:
            for v in VARIANTS:
                pipes[v].set_scene(scenes[v][0], s)
            times = {v: [] for v in VARIANTS}
            last, now = {}, {}
            for k in range(warmup + repeats):
                for v in VARIANTS:
                    f = pipes[v].render(scenes[v][0], settings, W, H)
                    now[v] = f.timings["shadow_ms"]
                    if k >= warmup:
                        times[v].append(f.timings["shadow_ms"])
                    if k == warmup + repeats - 1:
                        sc, ref = scenes[v]
                        row = {"defines": f.stats["defines"], "rays_traced": f.stats["rays_traced"]}
                        if ref is not None:
                            masks = {sc.lights[li].name: f.mask_array(li) for li in f.lights}
                            per = {n: mask_error(ref[n], m) for n, m in masks.items() if n in ref}
                            tot = combine(per.values())
                            row.update(mismatch_pct=tot.mismatch_pct, mismatch=tot.mismatch_pixels,
                                       valid=tot.valid_pixels,
                                       worst_light_pct=max(e.mismatch_pct for e in per.values()),
                                       lights={n: e.to_dict() for n, e in per.items()})
                            if v in ("alpha", "binary"):
                                one = single_surface(sc, f)
                                per1 = {n: mask_error(np.where(one, ref[n], np.nan), m) for n, m in masks.items()}
                                t1 = combine(per1.values())
                                row.update(single_surface_mismatch_pct=t1.mismatch_pct,
                                           single_surface_mismatch=t1.mismatch_pixels,
                                           single_surface_valid=t1.valid_pixels,
                                           mixed_pixels=int((~one & np.isfinite(next(iter(masks.values())))).sum()))
                        last[v] = row
                print(f"  {s} repeat {k + 1}/{warmup + repeats}: " +
                      ", ".join(f"{v} {now[v]:.0f} ms" for v in VARIANTS),
                      file=sys.stderr, flush=True)
        finally:
            for p in pipes.values():
                p.release()
        for v in VARIANTS:
            r = dict(last[v], shadow_ms=float(np.median(times[v])), shadow_ms_all=[float(t) for t in times[v]])
            r.update(bake_figures(scenes[v][0], s, bake_repeats))
            out["rows"][f"{v}/{s}"] = r
    return out


def table(res: dict, structures) -> str:
    rows = res["rows"]
    lines = ["| scene | structure | alpha code | shadow ms | ÷ opaque | bake ms | atlas ms | textures MB | "
             "atlas + records MB | mismatch % (worst light) |", "|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for v in VARIANTS:
        for s in structures:
            r = rows[f"{v}/{s}"]
            base = rows[f"opaque/{s}"]["shadow_ms"]
            if "mismatch_pct" in r:
                mm = f"{r['mismatch_pct']:.3f} ({r['worst_light_pct']:.3f})"
                if "single_surface_mismatch_pct" in r:
                    mm += f"; {r['single_surface_mismatch_pct']:.3f} without the {r['mixed_pixels']} mixed pixels"
            else:
                mm = "–"
            alpha = "yes" if any(d.startswith("HS_HAS_ALPHA") for d in r["defines"]) else "no"
            lines.append(f"| {LABELS[v]} | {s} | {alpha} | {r['shadow_ms']:.0f} | {r['shadow_ms'] / base:.2f} | "
                         f"{r['bake_ms']:.1f} | "
                         f"{r['atlas_ms']:.1f} | {r['texture_mb']:.2f} | {r['material_mb']:.2f} | {mm} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", default="640x360")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--bake-repeats", type=int, default=5)
    p.add_argument("--structures", nargs="+", default=["bvh", "grid"])
    p.add_argument("--json")
    a = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", "/tmp/hs-bench-blender")
    from hybrid_shadow_addon.core.gpu.context import create_context

    size = tuple(int(v) for v in a.size.split("x"))
    res = run(size, a.structures, a.repeats, a.warmup, a.bake_repeats, create_context())
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    print(f"alpha_cards {size[0]}x{size[1]}: {res['triangles']} triangles, {res['instances']} instances, "
          f"{res['images']} images, {res['materials']} materials, lights {', '.join(res['lights'])}")
    print(table(res, a.structures))
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
