"""Brute-force oracles over a :class:`Scene`: every shadow caster, no acceleration structure.

The same ray preparation, float32 transform, watertight triangle and sphere tests as the walks,
so they are the ground truth the structured tracers are compared with (small scenes only).
"""
from __future__ import annotations

import numpy as np

from ...bake.textures import f32_up
from ..alpha import is_opaque, transmittance
from .primitives import F, prepare_rays, sphere_hit, transform_rays, woop_hit, woop_hit_bary, woop_setup


def _casters(scene, o, d, tm, live, blockers=None):
    """Each shadow caster of ``scene`` (of those ``blockers`` marks, when given: a linked light's,
    :func:`core.scene.linking.blockers`) with the rays still to test (``live()``: their mask, read
    anew per caster) in its model space: ``(instance, model, rays, om, dm, sphere)``, ``sphere``
    the hits of an analytic sphere primitive, else None."""
    inst = scene.instances
    if not len(inst):
        return
    casting = inst.casts_shadow if blockers is None else inst.casts_shadow & np.asarray(blockers, bool)
    for i in np.nonzero(casting)[0].tolist():
        rays = np.nonzero(live())[0]
        if not rays.size:
            return
        model = scene.models[int(inst.model_ids[i])]
        rows = np.broadcast_to(inst.inverse[i, :3, :].astype(F).reshape(1, 12), (rays.size, 12))
        om, dm = transform_rays(rows, o[rays], d[rays])
        sphere = None
        if inst.sphere[i]:
            c = np.broadcast_to(model.sphere_center.astype(F), om.shape)
            r = np.broadcast_to(f32_up(model.sphere_radius), (rays.size,))
            sphere = sphere_hit(om, dm, c, r, tm[rays])
        yield i, model, rays, om, dm, sphere


def _pairs(n_rays: int, n_tri: int, chunk: int):
    """Every (ray, triangle) pair in chunks of about ``chunk``: ``(first ray, rays, ray of each
    pair, triangle of each pair)``."""
    per = max(1, chunk // n_tri)
    for a in range(0, n_rays, per):
        n = min(per, n_rays - a)
        yield a, n, np.repeat(np.arange(a, a + n), n_tri), np.tile(np.arange(n_tri), n)


def trace_brute(scene, origins, dirs, tmax=np.inf, chunk: int = 1 << 21, blockers=None) -> np.ndarray:
    """Occlusion of each ray against every shadow caster of ``scene`` (small scenes only); a
    linked light's rays: only the casters ``blockers`` (N,) marks."""
    o, d, tm, valid = prepare_rays(origins, dirs, tmax)
    occ = np.zeros(len(o), bool)
    for _i, model, rays, om, dm, sphere in _casters(scene, o, d, tm, lambda: valid & ~occ, blockers):
        if sphere is not None:
            occ[rays[sphere]] = True
            continue
        T = model.triangle_count
        if T == 0:
            continue
        v = model.vertices[model.triangles]  # (T, 3, 3)
        setup = woop_setup(dm)
        for a, n, rr, tt in _pairs(rays.size, T, chunk):
            s = tuple(x[rr] for x in setup)
            h = woop_hit(om[rr], s, v[tt, 0], v[tt, 1], v[tt, 2], tm[rays[rr]])
            occ[rays[a:a + n]] |= h.reshape(n, T).any(axis=1)
    return occ


def visibility_brute(scene, origins, dirs, tmax=np.inf, chunk: int = 1 << 21, blockers=None) -> np.ndarray:
    """(N,) float64 visibility in [0, 1] of each ray against every shadow caster of ``scene``
    (small scenes only): the product, over every caster surface the ray crosses at t in
    (0, tmax), of that surface's transmittance (:func:`core.oracle.alpha.transmittance`:
    0 for opaque surfaces and analytic spheres; BLEND 1 - alpha(uv); CLIP alpha < threshold).

    Same ray preparation, float32 transform and watertight test (``floor=False``) as
    :func:`trace_brute`, so ``visibility == 0`` exactly where ``trace_brute`` reports occluded
    on a scene without alpha. A triangle's UV is the barycentric blend of its corners' UVs
    (``Model.uvs``). Invalid rays (zero direction, tmax <= 0, NaN) get 1. ``blockers``: as
    :func:`trace_brute`'s."""
    o, d, tm, valid = prepare_rays(origins, dirs, tmax)
    vis = np.ones(len(o), np.float64)
    for i, model, rays, om, dm, sphere in _casters(scene, o, d, tm, lambda: valid & (vis > 0), blockers):
        if sphere is not None:
            vis[rays[sphere]] = 0.0
            continue
        T = model.triangle_count
        if T == 0:
            continue
        mid = int(scene.instances.material_ids[i])
        opaque = is_opaque(scene, mid)
        v = model.vertices[model.triangles]  # (T, 3, 3)
        uvs = (model.uvs.astype(np.float64) if model.uvs is not None
               else np.zeros((T, 3, 2), np.float64))
        setup = woop_setup(dm)
        for a, n, rr, tt in _pairs(rays.size, T, chunk):
            s = tuple(x[rr] for x in setup)
            if opaque:
                h = woop_hit(om[rr], s, v[tt, 0], v[tt, 1], v[tt, 2], tm[rays[rr]])
                vis[rays[a:a + n][h.reshape(n, T).any(axis=1)]] = 0.0
                continue
            h, bary, _ = woop_hit_bary(om[rr], s, v[tt, 0], v[tt, 1], v[tt, 2], tm[rays[rr]])
            k = np.nonzero(h)[0]
            if not k.size:
                continue
            uv = np.einsum("pc,pcj->pj", bary[k], uvs[tt[k]])
            np.multiply.at(vis, rays[rr[k]], transmittance(scene, mid, uv))
    return vis
