"""The hierarchical grid walk of ``shaders/common/scene_grid.glsl``, reading only the baked textures.

It tests the outside node, then walks each non-empty grid level with the DDA (node max-height
culling, the object BVH of crowded nodes, else the flat node list), and for each object the
world-sphere pre-test, the ray transform, the analytic sphere test or the stackless model-BVH
walk with the watertight triangle test. It follows the GLSL operation by operation in float32,
but runs all rays in lock step (one numpy pass per DDA or BVH step).
"""
from __future__ import annotations

import numpy as np

from ...bake.textures import BVH_TEXELS, MODEL_TEXELS, OBJECT_TEXELS, SPHERE_FLAG, TRI_TEXELS
from .primitives import (
    F,
    bake_space,
    prepare_rays,
    ragged_pairs,
    slab_hit,
    slab_inv,
    sphere_hit,
    sphere_pretest,
    transform_rays,
    woop_hit,
    woop_setup,
)

BIG = F(3.4e38)  # "no boundary" t of the DDA; > FLT_BIG
EPS16 = F(2.0 ** -16)
OBVH_EPS = F(2.0 ** -16)  # object-BVH box widening (HS_OBVH_EPS)


class _Tex:
    """The baked textures the walk reads, as flat record arrays."""

    def __init__(self, baked):
        t = baked.textures
        self.grid = t["grid"].linear()
        self.index = t["grid_index"].linear()
        self.obj = t["object"].records(OBJECT_TEXELS)
        self.model = t["model"].records(MODEL_TEXELS)
        self.bvh = t["bvh"].records(BVH_TEXELS)
        self.tri = t["tri"].records(TRI_TEXELS)


def _bvh_occluded(tex: _Tex, om, dm, root, count, tmax, stats) -> np.ndarray:
    """Stackless walk of each pair's model BVH (escape indices); any-hit."""
    P = len(om)
    hit = np.zeros(P, bool)
    i = root.astype(np.int64).copy()
    end = i + count
    setup = woop_setup(dm)
    inv = slab_inv(dm)
    act = np.nonzero(i < end)[0]
    while act.size:
        node = tex.bvh[i[act]]
        bmin = node[:, 0:3].view(F)
        bmax = node[:, 4:7].view(F)
        esc = node[:, 3].astype(np.int64)
        leaf = node[:, 7].astype(np.int64)
        bh = slab_hit(om[act], inv[act], bmin, bmax, tmax[act])
        if stats is not None:
            stats["bvh_nodes"] += act.size
        is_leaf = leaf != 0
        lt = np.nonzero(bh & is_leaf)[0]
        if lt.size:
            owner, tri = ragged_pairs(leaf[lt] >> 3, leaf[lt] & 7)
            p = act[lt[owner]]
            v = tex.tri[tri].reshape(-1, 3, 3)
            s = tuple(x[p] for x in setup)
            h = woop_hit(om[p], s, v[:, 0], v[:, 1], v[:, 2], tmax[p])
            if stats is not None:
                stats["triangles"] += tri.size
            hit[p[h]] = True
        nxt = np.where(bh & ~is_leaf, i[act] + 1, esc)
        i[act] = nxt
        keep = (nxt < end[act]) & ~hit[act]
        act = act[keep]
    return hit


def _test_pairs(tex: _Tex, o, d, tmax, ray, entry, stats) -> np.ndarray:
    """Occlusion of (ray, grid-index entry) pairs: pre-test, transform, sphere or BVH."""
    e = tex.index[entry]
    obj = e[:, 0].astype(np.int64)
    code = e[:, 1]
    rec = tex.obj[obj]
    if stats is not None:
        stats["objects"] += len(obj)
    ok = sphere_pretest(o[ray], d[ray], rec[:, 12:15], rec[:, 15], tmax[ray])
    out = np.zeros(len(obj), bool)
    sel = np.nonzero(ok)[0]
    if not sel.size:
        return out
    r = ray[sel]
    om, dm = transform_rays(rec[sel, 0:12], o[r], d[r])
    is_sph = (code[sel] & SPHERE_FLAG) != 0
    mid = (code[sel] & np.uint32(0x7FFFFFFF)).astype(np.int64)
    m = tex.model[mid]
    if is_sph.any():
        s = np.nonzero(is_sph)[0]
        sph = m[s, 0:4].view(F)
        out[sel[s]] = sphere_hit(om[s], dm[s], sph[:, 0:3], sph[:, 3], tmax[r[s]])
    mesh = np.nonzero(~is_sph & (m[:, 5] > 0))[0]
    if mesh.size:
        out[sel[mesh]] = _bvh_occluded(tex, om[mesh], dm[mesh], m[mesh, 4], m[mesh, 5], tmax[r[mesh]], stats)
    return out


def trace_grid(baked, origins, dirs, tmax=np.inf, stats: dict | None = None) -> np.ndarray:
    """Occlusion of each world-space ray through a grid bake's textures; ``stats`` (when given)
    gets the DDA steps, nodes, objects, BVH nodes and triangles tested."""
    o, d, tm, valid = prepare_rays(bake_space(baked, origins), dirs, tmax)
    N = len(o)
    occ = np.zeros(N, bool)
    if stats is not None:
        stats.update({"dda_steps": 0, "nodes_tested": 0, "objects": 0, "bvh_nodes": 0, "triangles": 0,
                      "obvh_walks": 0, "obvh_nodes": 0})
    tex = _Tex(baked)
    u = baked.uniforms
    H = F(u["hs_scene_max_height"])
    oz, dz = o[:, 2], d[:, 2]
    # scene max height: above it and going up (or flat) -> lit
    with np.errstate(invalid="ignore", over="ignore"):
        above = oz - H > EPS16 * (np.abs(oz) + np.abs(H))
    active = valid & ~(above & (dz >= 0))
    # DDA end: where an upward ray passes the scene max height (conservatively later)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_top = ((H - oz) + EPS16 * (np.abs(H) + np.abs(oz))) / np.where(dz > 0, dz, F(1)) * F(1.0 + 2.0 ** -16)
    t_dda = np.where(dz > 0, np.minimum(tm, np.maximum(t_top, F(0))), tm).astype(F)

    # outside node: every active ray
    out_node = int(u["hs_outside_node"])
    _visit(tex, o, d, tm, occ, np.nonzero(active)[0], np.full(int(active.sum()), out_node), stats)

    gx, gy = F(u["hs_grid_origin"][0]), F(u["hs_grid_origin"][1])
    for lvl in range(len(u["hs_node_size"])):
        if u["hs_level_count"][lvl] == 0:
            continue
        s = F(u["hs_node_size"][lvl])
        nx, ny = (int(x) for x in u["hs_level_dims"][lvl])
        off = int(u["hs_level_offset"][lvl])
        rays = np.nonzero(active & ~occ)[0]
        if not rays.size:
            break
        _walk_level(tex, o, d, tm, t_dda, occ, rays, gx, gy, s, nx, ny, off, stats)
    return occ


def _visit(tex, o, d, tm, occ, ray, node, stats, zmin=None):
    """Test the objects of grid ``node`` for each ``ray`` (skipping culled / occluded ones)."""
    g = tex.grid[node]
    cnt = g[:, 1].astype(np.int64)
    keep = (cnt > 0) & ~occ[ray]
    if zmin is not None:
        maxh = g[:, 2].view(F)
        with np.errstate(invalid="ignore", over="ignore"):
            culled = zmin - maxh > EPS16 * (np.abs(zmin) + np.abs(maxh))
        keep &= ~culled
    if stats is not None:
        stats["nodes_tested"] += int(keep.sum())
    ray, g, cnt = ray[keep], g[keep], cnt[keep]
    if not ray.size:
        return
    tree = g[:, 3] != 0  # crowded node: walk its object BVH (hs_node_bvh_occludes)
    if tree.any():
        _node_bvh(tex, o, d, tm, occ, ray[tree], g[tree, 3].astype(np.int64) - 1, stats)
        ray, g, cnt = ray[~tree], g[~tree], cnt[~tree]
        if stats is not None:
            stats["obvh_walks"] += int(tree.sum())
        if not ray.size:
            return
    owner, entry = ragged_pairs(g[:, 0], cnt)
    pr = ray[owner]
    hit = _test_pairs(tex, o, d, tm, pr, entry, stats)
    occ[pr[hit]] = True


def _node_bvh(tex, o, d, tm, occ, ray, root, stats):
    """Object-BVH walk of crowded grid nodes, one (ray, root) pair each, in lock step (mirrors
    hs_node_bvh_occludes): widened slab test, leaves = runs of grid-index entries."""
    P = len(ray)
    hit = np.zeros(P, bool)
    r = tex.bvh[root]
    end = r[:, 3].astype(np.int64)
    ao = np.abs(o[ray])
    rlo = np.abs(r[:, 0:3].view(F))
    rhi = np.abs(r[:, 4:7].view(F))
    with np.errstate(over="ignore", invalid="ignore"):
        e = OBVH_EPS * (((ao[:, 0] + ao[:, 1]) + ao[:, 2])
                        + (((rlo[:, 0] + rlo[:, 1]) + rlo[:, 2]) + ((rhi[:, 0] + rhi[:, 1]) + rhi[:, 2])))
    inv = slab_inv(d[ray])
    i = root.copy()
    act = np.nonzero(i < end)[0]
    while act.size:
        node = tex.bvh[i[act]]
        ea = e[act][:, None]
        with np.errstate(over="ignore", invalid="ignore"):
            bmin = node[:, 0:3].view(F) - ea
            bmax = node[:, 4:7].view(F) + ea
        esc = node[:, 3].astype(np.int64)
        leaf = node[:, 7].astype(np.int64)
        ra = ray[act]
        bh = slab_hit(o[ra], inv[act], bmin, bmax, tm[ra])
        if stats is not None:
            stats["obvh_nodes"] += act.size
        is_leaf = leaf != 0
        lt = np.nonzero(bh & is_leaf)[0]
        if lt.size:
            owner, entry = ragged_pairs(leaf[lt] >> 3, leaf[lt] & 7)
            p = act[lt[owner]]
            h = _test_pairs(tex, o, d, tm, ray[p], entry, stats)
            hit[p[h]] = True
        nxt = np.where(bh & ~is_leaf, i[act] + 1, esc)
        i[act] = nxt
        act = act[(nxt < end[act]) & ~hit[act]]
    occ[ray[hit]] = True


def _walk_level(tex, o, d, tm, t_dda, occ, rays, gx, gy, s, nx, ny, off, stats):
    """DDA over one grid level for ``rays`` in lock step (mirrors hs_walk_level in GLSL)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u0 = (o[rays, 0] - gx) / s
        v0 = (o[rays, 1] - gy) / s
        du = d[rays, 0] / s
        dv = d[rays, 1] / s
        dz = d[rays, 2]
        oz = o[rays, 2]
        t_lo = np.zeros(rays.size, F)
        t_hi = t_dda[rays].copy()
        alive = np.ones(rays.size, bool)
        invs = []
        for p0, dp, n in ((u0, du, nx), (v0, dv, ny)):
            zero = dp == 0
            alive &= ~(zero & ((p0 < 0) | (p0 > F(n))))
            inv = np.where(zero, F(0), F(1) / np.where(zero, F(1), dp)).astype(F)
            ta = (F(0) - p0) * inv
            tb = (F(n) - p0) * inv
            t_lo = np.where(zero, t_lo, np.maximum(t_lo, np.minimum(ta, tb)))
            t_hi = np.where(zero, t_hi, np.minimum(t_hi, np.maximum(ta, tb)))
            invs.append(inv)
        invu, invv = invs
        alive &= t_lo <= t_hi
        cx = np.clip(np.floor(u0 + du * t_lo), 0, nx - 1).astype(np.int64)
        cy = np.clip(np.floor(v0 + dv * t_lo), 0, ny - 1).astype(np.int64)
        dmax = np.maximum(np.abs(du), np.abs(dv))
        inv_dmax = np.where(dmax > 0, F(1) / np.where(dmax > 0, dmax, F(1)), BIG).astype(F)
        slack = (np.abs(u0) + np.abs(v0) + F(2)) * inv_dmax
        t_enter = t_lo
        sx = np.where(du > 0, 1, -1)
        sy = np.where(dv > 0, 1, -1)
        idx = np.nonzero(alive)[0]
        while idx.size:
            r = rays[idx]
            tx = np.where(du[idx] > 0, ((cx[idx] + 1).astype(F) - u0[idx]) * invu[idx],
                          np.where(du[idx] < 0, (cx[idx].astype(F) - u0[idx]) * invu[idx], BIG)).astype(F)
            ty = np.where(dv[idx] > 0, ((cy[idx] + 1).astype(F) - v0[idx]) * invv[idx],
                          np.where(dv[idx] < 0, (cy[idx].astype(F) - v0[idx]) * invv[idx], BIG)).astype(F)
            te = t_enter[idx]
            tx_exit = np.minimum(np.minimum(tx, ty), t_hi[idx])
            delta = EPS16 * (tx_exit - te + slack[idx])
            zlo = np.where(dz[idx] > 0, oz[idx] + dz[idx] * np.maximum(te - delta, F(0)),
                           np.where(dz[idx] < 0, oz[idx] + dz[idx] * np.minimum(tx_exit + delta, tm[r]),
                                    oz[idx])).astype(F)
            node = off + cy[idx] * nx + cx[idx]
            if stats is not None:
                stats["dda_steps"] += idx.size
            _visit(tex, o, d, tm, occ, r, node, stats, zmin=zlo)
            done = (tx_exit >= t_hi[idx]) | occ[r]
            stepx = tx <= ty
            cx[idx] += np.where(stepx, sx[idx], 0)
            cy[idx] += np.where(stepx, 0, sy[idx])
            done |= (cx[idx] < 0) | (cx[idx] >= nx) | (cy[idx] < 0) | (cy[idx] >= ny)
            t_enter[idx] = tx_exit
            idx = idx[~done]

