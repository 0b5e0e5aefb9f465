"""Shadow-ray throughput of our ray-traced pass against Mitsuba 3 on the very same rays and
triangles, same machine, same run (a script, not a test).

    .venv/bin/python -m pip install -r requirements-bench.txt
    .venv/bin/python -m benchmarks.bench_mitsuba [--scenes forest,scaling:triangles=1000,...]
        [--size 640x360] [--reps 3] [--variant llvm_ad_rgb]

Ours: the default settings, hard: the sun's light grid (built up front, its build not timed: once
per scene and sun). Rays: the sun's shadow rays of the G-buffer (origins after our offset, ``shadow_rays``), only
the texels our pass traces (facing the light). Our time: the ray-traced shadow pass for that
one light (median of warm frames), with and without the conservative maps; rays/s counts every
facing texel either way (the maps decide many without traversal: that is the point). Mitsuba:
one mesh of all world-space caster triangles (analytic sphere primitives as Mitsuba spheres),
``scene.ray_test`` on the same rays (Mitsuba has no tnear: our origins are already offset off
the surface), timed after a warm-up call (JIT compile). Agreement is reported too.
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings

DEFAULT = "scaling:triangles=1000,instances=1;scaling:triangles=10000,instances=10;" \
          "scaling:triangles=100000,instances=100;forest"


def world_triangles(scene):
    """(T, 3, 3) float32 world triangles of the mesh casters; (centres, radii) of sphere casters."""
    inst = scene.instances
    tris, sph_c, sph_r = [], [], []
    for i in np.nonzero(inst.casts_shadow)[0]:
        model = scene.models[inst.model_ids[i]]
        m = inst.matrices[i]
        if inst.sphere[i]:
            c = m[:3, :3] @ np.asarray(model.sphere_center, np.float64) + m[:3, 3]
            sph_c.append(c)
            sph_r.append(float(model.sphere_radius) * float(np.linalg.norm(m[:3, :3], axis=0).max()))
            continue
        if not model.triangle_count:
            continue
        v = model.vertices.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        tris.append(v[model.triangles.astype(np.int64)])
    t = np.concatenate(tris).astype(np.float32) if tris else np.zeros((0, 3, 3), np.float32)
    return t, np.array(sph_c).reshape(-1, 3), np.array(sph_r)


def mitsuba_scene(mi, tris, sph_c, sph_r):
    objs = {"type": "scene"}
    if len(tris):
        mesh = mi.Mesh("casters", vertex_count=3 * len(tris), face_count=len(tris))
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(tris.reshape(-1).astype(np.float32))
        params["faces"] = mi.UInt32(np.arange(3 * len(tris), dtype=np.uint32))
        params.update()
        objs["casters"] = mesh
    for k, (c, r) in enumerate(zip(sph_c, sph_r)):
        objs[f"s{k}"] = {"type": "sphere", "center": [float(x) for x in c], "radius": float(r)}
    return mi.load_dict(objs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=DEFAULT, help="';'-separated scene specs")
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--cold", action="store_true",
                    help="a cold frame: no light grids, the tree alone (the first frames after a change)")
    a = ap.parse_args(argv)
    import mitsuba as mi

    mi.set_variant(a.variant)
    w, h = (int(v) for v in a.size.split("x"))
    pipe = Pipeline()
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=not a.cold)  # (the sun's grid from the first frame on)
    print(f"## shadow-ray throughput, sun rays at {w}x{h}{', cold (no light grids)' if a.cold else ''} "
          f"(Mitsuba {mi.__version__} {a.variant}, 2 cores)\n")
    print("| scene | triangles | rays | ours ms | ours Mrays/s | ours with maps Mrays/s | Mitsuba ms | Mitsuba Mrays/s "
          "| ours / Mitsuba | agree |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for spec in a.scenes.split(";"):
        scene = load_scene(spec)
        suns = [i for i, light in enumerate(scene.lights) if light.type == "SUN"]
        li = suns[0] if suns else 0
        for i, light in enumerate(scene.lights):
            light.use_shadow = i == li
        pipe.set_scene(scene)
        timings = {}
        for cons in (False, True):  # (the mask compared below is the last: with maps)
            settings = Settings(mode="raytrace", conservative="sun" if cons else "off", hard=True,  # (Mitsuba's rays)
                                light_grid=not a.cold)
            pipe.render(scene, settings, w, h, read_image=False)
            ts = []
            for _ in range(a.reps):
                fr = pipe.render(scene, settings, w, h, read_image=False)
                ts.append(fr.timings["shadow_ms"])
            timings[cons] = statistics.median(ts)
        ours = fr.mask_array(li)
        gb = fr.gbuffer
        cov = ~np.isnan(ours)
        o, d, tmax, facing = shadow_rays(gb, np.nonzero(cov), scene.lights[li], pipe.baked.origin)
        o, d = o[facing], d[facing]
        n = len(o)
        tris, sc, sr = world_triangles(scene)
        msc = mitsuba_scene(mi, tris, sc, sr)
        ray = mi.Ray3f(o=mi.Point3f(*[mi.Float(o[:, k]) for k in range(3)]),
                       d=mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)]))
        occ = msc.ray_test(ray)
        mi_occ = np.array(occ, bool)  # warm-up: JIT compile + evaluation
        mts = []
        for _ in range(a.reps):
            t0 = time.perf_counter()
            r = msc.ray_test(ray)
            import drjit as dr
            dr.eval(r)
            dr.sync_thread()
            mts.append((time.perf_counter() - t0) * 1e3)
        mt = statistics.median(mts)
        agree = float((np.where(mi_occ, 0.0, 1.0) == ours[cov][facing]).mean())
        ours_rate = n / timings[False] / 1e3
        maps_rate = n / timings[True] / 1e3
        mi_rate = n / mt / 1e3
        print(f"| {spec} | {len(tris)} | {n} | {timings[False]:.0f} | {ours_rate:.2f} | {maps_rate:.2f} | {mt:.0f} | "
              f"{mi_rate:.1f} | {ours_rate / mi_rate:.3f}x | {agree:.4f} |", flush=True)
    pipe.release()


if __name__ == "__main__":
    main()
