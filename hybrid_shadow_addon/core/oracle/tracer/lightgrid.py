"""A hard light's light-space grid walk (``core/bake/lightgrid.py``, ``scene_lightgrid.glsl``):
the ray's cell, its entries while their keys lie above the ray's, and the caster tests."""
from __future__ import annotations

import numpy as np

from ...bake.textures import SPHERE_FLAG, f32_up
from .primitives import F, prepare_rays, ragged_pairs, sphere_hit, transform_rays, woop_hit, woop_setup


def _dot32(a, b) -> np.ndarray:
    """Float32 dot product of rows ``a`` with vector ``b``, in the shader's order."""
    a = a.astype(F)
    b = np.asarray(b, F)
    return (a[:, 0] * b[0] + a[:, 1] * b[1]) + a[:, 2] * b[2]


def light_grid_place(grid, o, d):
    """``(g (N, 2) float32 grid position in cells, s (N,) float32 ray key, inside (N,))`` of
    bake-space rays ``o + t d`` through a light's grid, as ``hs_lg_place`` computes them."""
    u = grid.uniforms
    inv = F(u["hs_lg_inv_cell"])
    o = o.astype(F)
    d = d.astype(F)
    if "HS_LG_LOCAL" in grid.defines:
        w = -d
        a = np.abs(w)
        fx = (a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2])
        fy = ~fx & (a[:, 1] >= a[:, 2])
        z = np.where(fx, a[:, 0], np.where(fy, a[:, 1], a[:, 2]))
        uu = np.where(fx, w[:, 1], np.where(fy, w[:, 2], w[:, 0]))
        vv = np.where(fx, w[:, 2], np.where(fy, w[:, 0], w[:, 1]))
        face = np.where(fx, np.where(w[:, 0] > 0, 0, 1), np.where(fy, np.where(w[:, 1] > 0, 2, 3),
                                                                   np.where(w[:, 2] > 0, 4, 5))).astype(F)
        inside = z > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            uu = np.clip(uu / z, F(-1), F(1)) + F(1)
            vv = np.clip(vv / z, F(-1), F(1)) + F(1)
        r = F(int(u["hs_lg_dims"][0]))
        g = np.stack([np.minimum(uu * inv, r - F(1.0 / 256.0)),
                      np.minimum(vv * inv, r - F(1.0 / 256.0)) + face * r], axis=1)
        return np.where(inside[:, None], g, 0).astype(F), (-z).astype(F), inside
    gx = (_dot32(o, u["hs_lg_ux"]) - F(u["hs_lg_base"][0])) * inv
    gy = (_dot32(o, u["hs_lg_uy"]) - F(u["hs_lg_base"][1])) * inv
    nx, ny = (int(v) for v in u["hs_lg_dims"])
    inside = (gx >= 0) & (gy >= 0) & (gx < F(nx)) & (gy < F(ny))
    g = np.stack([np.where(inside, gx, 0), np.where(inside, gy, 0)], axis=1).astype(F)
    return g, _dot32(o, u["hs_lg_dz"]), inside


def instance_sphere_hit(scene, origin, inst, o, d, tmax) -> np.ndarray:
    """The analytic sphere instances ``inst`` (one per ray) against bake-space rays, in model
    space through each instance's bake-space inverse rows (float32), as its [leaf] record holds
    them and ``hs_lg_visibility`` reads them."""
    inv = scene.instances.inverse[inst, :3, :].copy()
    inv[:, :, 3] += inv[:, :, :3] @ np.asarray(origin, np.float64)
    om, dm = transform_rays(inv.astype(F).reshape(-1, 12), o, d)
    mid = scene.instances.model_ids[inst].tolist()
    cen = np.array([scene.models[m].sphere_center for m in mid], F).reshape(-1, 3)
    rad = f32_up(np.array([scene.models[m].sphere_radius for m in mid], np.float64)).astype(F)
    return sphere_hit(om, dm, cen, rad, tmax)


def trace_light_grid(grid, tris, scene, origin, origins, dirs, tmax=np.inf, stats: dict | None = None) -> np.ndarray:
    """Occlusion of bake-space rays ``origins + t dirs`` (the trace's rays towards the light:
    a sun's ``u_light_vec``, or ``light - origin`` with tmax 1) through a
    :class:`~..bake.lightgrid.LightGrid`, as ``hs_lg_visibility`` walks it: the ray's cell, its
    list while the keys lie above the ray's own and the entry's box holds the ray, the same
    float32 triangle test as the BVH (``floor``) and the sphere test in model space. ``tris``:
    the world casters' triangles (``WorldCasters.tris``); ``scene`` and ``origin`` give the sphere
    instances' records. ``stats``: ``entries`` (list entries walked, up to and including the first
    hit), ``tests`` (casters tested), ``rays``."""
    o, d, tm, valid = prepare_rays(origins, dirs, tmax)
    n = len(o)
    occ = np.zeros(n, bool)
    g, s, inside = light_grid_place(grid, o, d)
    live = np.nonzero(inside & valid)[0]
    c = g[live].astype(np.int64)
    tiles = int(grid.uniforms["hs_lg_tiles_x"])
    cell = (((c[:, 1] >> 3) * tiles + (c[:, 0] >> 3)) << 6) + ((c[:, 1] & 7) << 3) + (c[:, 0] & 7)
    cells = grid.textures["lg_cell"].linear()
    entries = grid.textures["lg_entry"].linear()
    st, cnt = cells[cell, 0].astype(np.int64), cells[cell, 1].astype(np.int64)
    own, ent = ragged_pairs(st, cnt)
    ray = live[own]
    key = entries[ent, 1].view(F)
    above = key > s[ray]
    # the walk stops at the first key at or below the ray's (keys descend): those above it form
    # a prefix, the entries it walks
    pos = np.arange(len(ent)) - np.repeat(np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt).astype(np.int64)
    first_below = np.full(len(live), np.iinfo(np.int64).max)
    np.minimum.at(first_below, own[~above], pos[~above])
    keep = pos < first_below[own]
    ray, own, pos, ent = ray[keep], own[keep], pos[keep], ent[keep]
    code = entries[ent, 0]
    # the entry's box within the cell: a ray outside it skips the caster
    f = ((g[ray] - np.floor(g[ray])) * F(255.0)).astype(F)
    sub = entries[ent, 2]
    b = [((sub >> np.uint32(8 * j)) & np.uint32(255)).astype(F) for j in range(4)]
    boxed = ~((f[:, 0] < b[0]) | (f[:, 0] > b[1]) | (f[:, 1] < b[2]) | (f[:, 1] > b[3]))
    hit = np.zeros(len(ray), bool)
    is_sph = (code & SPHERE_FLAG) != 0
    t_idx = np.nonzero(~is_sph & boxed)[0]
    if len(t_idx):
        k = code[t_idx].astype(np.int64)
        r = ray[t_idx]
        tv = np.asarray(tris, F)[k]
        hit[t_idx] = woop_hit(o[r], woop_setup(d[r]), tv[:, 0], tv[:, 1], tv[:, 2], tm[r], floor=True)
    s_idx = np.nonzero(is_sph & boxed)[0]
    if len(s_idx):
        r = ray[s_idx]
        hit[s_idx] = instance_sphere_hit(scene, origin, (code[s_idx] & ~SPHERE_FLAG).astype(np.int64),
                                         o[r], d[r], tm[r])
    occ[ray[hit]] = True
    if stats is not None:
        big = np.iinfo(np.int64).max
        first_hit = np.full(len(live), big)
        np.minimum.at(first_hit, own[hit], pos[hit])
        walked = np.where(first_hit < big, first_hit + 1, np.bincount(own, minlength=len(live)))
        tested = (boxed & (pos <= first_hit[own])).sum()
        stats["entries"] = stats.get("entries", 0) + int(walked.sum())
        stats["tests"] = stats.get("tests", 0) + int(tested)
        stats["rays"] = stats.get("rays", 0) + n
    return occ
