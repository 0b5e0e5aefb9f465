"""Where `raytrace-high` and Cycles still differ on the stiff scenes, and whose float error it is.

For each case and light: our mask, Cycles' at 1 and 16 samples per pixel (all at the pixel
centre) and the *exact* answer: a float64 shadow ray from the float64 hit of the pixel-centre
camera ray, towards the light, with tmin 0 and the hit's own triangle skipped (Cycles' recipe
without its float32 arithmetic), on the scene's triangles in float64 ("exact") and on Cycles'
own, their world positions rounded to float32 ("exact f32"). One table of mismatch counts per
mask, then every pixel where we differ from Cycles (1 sample) with its class:

- ``coverage``: our G-buffer shows another surface than the exact camera ray (more than half a
  pixel from its hit): raster coverage of sub-pixel or edge-on triangles;
- ``ours``: we differ from the exact answer (origin offset, float32 trace);
- ``cycles other surface``: we equal the exact answer, Cycles' camera ray hit another surface
  (its Position pass more than half a pixel from the exact hit: a silhouette);
- ``cycles f32 vertices``: we equal the exact answer, Cycles equals the answer on its float32
  world vertices (far from the world origin they move by up to half a float32 ULP);
- ``cycles hit point``: we equal the exact answer, Cycles differs from it on its own vertices
  too: its hit point (the Position pass) is off the exact one, or its samples disagree.

    .venv/bin/python -m benchmarks.stiff_residuals [--cases far_away,stadium]

Small scenes only (every ray against every triangle); ``crowd`` takes minutes.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks import stiff_table

REPO = Path(__file__).resolve().parents[1]

CASES = ("far_away", "stadium", "axis_aligned", "grazing", "clip_range", "ortho", "cards", "instance_scales")


def world_triangles(scene, f32: bool) -> tuple:
    """Every shadow caster's triangles in the world (F, 3, 3) and the instance of each; ``f32``:
    the world positions rounded to float32, as Cycles stores them."""
    tris, inst = [], []
    for i in np.nonzero(scene.instances.casts_shadow)[0]:
        m = scene.models[int(scene.instances.model_ids[i])]
        M = scene.instances.matrices[i]
        v = m.vertices.astype(np.float64) @ M[:3, :3].T + M[:3, 3]
        if f32:
            v = v.astype(np.float32).astype(np.float64)
        tris.append(v[m.triangles.astype(np.int64)])
        inst.append(np.full(m.triangle_count, i))
    return np.concatenate(tris), np.concatenate(inst)


def nearest_hits(o, d, tris, tmin=0.0, tmax=np.inf, skip=None, chunk=1 << 20):
    """float64 Moller-Trumbore of every ray against every triangle: the nearest t in (tmin,
    tmax) (inf: none) and its triangle; ``skip``: a triangle per ray left out (-1: none)."""
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    tmax = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
    t_best = np.full(len(o), np.inf)
    tri_best = np.full(len(o), -1)
    per = max(1, chunk // len(tris))
    for a in range(0, len(o), per):
        oo, dd = o[a:a + per, None], d[a:a + per, None]
        with np.errstate(all="ignore"):
            p = np.cross(dd, e2)
            det = (e1 * p).sum(-1)
            s = oo - v0
            u = (s * p).sum(-1) / det
            q = np.cross(s, e1)
            v = (dd * q).sum(-1) / det
            t = (e2 * q).sum(-1) / det
            ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tmin) & (t < tmax[a:a + per, None])
        if skip is not None:
            rows = np.nonzero(skip[a:a + per] >= 0)[0]
            ok[rows, skip[a:a + per][rows]] = False
        t = np.where(ok, t, np.inf)
        tri_best[a:a + per] = np.argmin(t, axis=1)
        t_best[a:a + per] = t[np.arange(len(t)), tri_best[a:a + per]]
    return t_best, np.where(np.isfinite(t_best), tri_best, -1)


def exact_visibility(scene, light, P, own, tris) -> np.ndarray:
    """1 where the float64 ray from ``P`` to ``light`` (tmin 0, ``own`` skipped) is free."""
    if light.type == "SUN":
        d, tmax = np.broadcast_to(-light.direction, P.shape).astype(np.float64), np.inf
    else:
        d, tmax = light.position[None] - P, 1.0
    t, _ = nearest_hits(P, d, tris, tmin=1e-9, tmax=tmax, skip=own)
    return np.where(np.isfinite(t), 0.0, 1.0)


def analyse_case(name: str, ctx) -> tuple[list, list]:
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.core.oracle.rays import surface_points

    r = stiff_table.evaluate_case(name, ("raytrace-high",), ctx=ctx, repeats=1, keep_masks=True, eager_grids=True)
    scene, ref = r["_scene"], r["_ref"]
    W, H = scene.resolution
    ref16 = render_reference(bpy.context.scene, resolution=(W, H), samples=16)
    tris, tri_inst = world_triangles(scene, False)
    tris32, _ = world_triangles(scene, True)
    ro, rd = scene.camera.pixel_rays(W, H)
    cam, depth = r["_camera"], r["_depth"]
    vp = cam.viewplane
    summary, pixels = [], []
    for lname, m in r["raytrace-high"].items():
        light = next(li for li in scene.lights if li.name == lname)
        ours, c1, c16 = m["ours"], m["ref"], ref16.visibility[lname]
        ok = np.isfinite(ours) & np.isfinite(c1)
        rows, cols = np.nonzero(ok)
        t, own = nearest_hits(ro[rows, cols], rd[rows, cols], tris)
        P = ro[rows, cols] + t[:, None] * rd[rows, cols]
        exact, exact32 = np.full(ours.shape, np.nan), np.full(ours.shape, np.nan)
        exact[rows, cols] = exact_visibility(scene, light, P, own, tris)
        t32, own32 = nearest_hits(ro[rows, cols], rd[rows, cols], tris32)
        exact32[rows, cols] = exact_visibility(scene, light, ro[rows, cols] + t32[:, None] * rd[rows, cols], own32,
                                               tris32)
        ok16 = ok & np.isfinite(c16)

        def differ(a, b, mask):
            return int((mask & (np.abs(a - b) > 0.5)).sum())
        summary.append((name, lname, int(ok.sum()), differ(ours, c1, ok), differ(ours, c16, ok16),
                        differ(c1, c16, ok16), differ(exact, c1, ok), differ(exact32, c1, ok),
                        differ(ours, exact, ok)))
        bad = np.abs(ours[rows, cols] - c1[rows, cols]) > 0.5
        for k in np.nonzero(bad)[0]:
            R, C = rows[k], cols[k]
            foot = (abs(vp[1] - vp[0]) / W) * (1.0 if cam.ortho else depth[R, C] / cam.clip_start)
            pg = ((cam.cam_pos - r["_origin"]).astype(np.float32)
                  + surface_points(cam, np.array([R]), np.array([C]), depth[R, C:C + 1])[0]).astype(np.float64)
            ours_err = np.linalg.norm(pg + r["_origin"] - P[k]) / foot
            cyc_err = np.linalg.norm(ref.position[R, C].astype(np.float64) - P[k]) / foot
            kind = ("coverage" if ours_err > 0.5 else
                    "ours" if abs(ours[R, C] - exact[R, C]) > 0.5 else
                    "cycles other surface" if cyc_err > 0.5 else
                    "cycles f32 vertices" if abs(c1[R, C] - exact32[R, C]) <= 0.5 else "cycles hit point")
            inst = scene.instances.names[tri_inst[own[k]]] if own[k] >= 0 else "-"
            pixels.append((name, lname, (int(R), int(C)), inst, ours[R, C], c1[R, C], c16[R, C], exact[R, C],
                           exact32[R, C], ours_err, cyc_err, kind))
    return summary, pixels


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", default=",".join(CASES))
    a = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", "/tmp/hs-stiff-blender")
    from hybrid_shadow_addon.core.gpu.context import create_context

    ctx = create_context()
    summary, pixels = [], []
    for case in [c for c in a.cases.split(",") if c]:
        s, px = analyse_case(case, ctx)
        summary += s
        pixels += px
        print(f"{case}: done", file=sys.stderr, flush=True)
    print("| case | light | valid | ours vs Cycles 1 spp | ours vs Cycles 16 spp | Cycles 1 vs 16 spp | "
          "exact vs Cycles 1 spp | exact f32 vs Cycles 1 spp | ours vs exact |\n|---|---|---|---|---|---|---|---|---|")
    for row in summary:
        print("| " + " | ".join(str(x) for x in row) + " |")
    print("\n| case | light | pixel (row, col) | surface | ours | Cycles 1 spp | Cycles 16 spp | exact | exact f32 | "
          "ours - exact hit (px) | Cycles - exact hit (px) | class |\n|" + "---|" * 12)
    for c, lname, px, inst, o, c1, c16, ex, ex32, oe, ce, kind in pixels:
        print(f"| {c} | {lname} | {px} | {inst} | {o:.0f} | {c1:.2f} | {c16:.2f} | {ex:.0f} | {ex32:.0f} | {oe:.3f} "
              f"| {ce:.3f} | {kind} |")
    sys.stdout.flush()
    os._exit(0)  # bpy's teardown can take seconds


if __name__ == "__main__":
    sys.exit(main())
