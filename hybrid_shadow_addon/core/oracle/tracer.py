"""Reference shadow-ray tracers in numpy: the oracle for the GLSL tracer.

- :func:`trace_structured` walks exactly the baked textures (it reads nothing else but
  ``BakedScene.textures`` and ``.uniforms``): the always-tested outside node, then each non-empty
  grid level with the DDA, node max-height culling, the object BVH of crowded nodes (else the
  flat node list), the world-sphere pre-test, the ray transform,
  the analytic sphere test or the stackless BVH walk and the watertight triangle test. It follows
  ``shaders/common/scene_data.glsl`` operation by operation in float32, but runs all rays in lock
  step (one numpy pass per DDA step / BVH step) instead of one ray per invocation.
- for ``structure="bvh"`` bakes, :func:`trace_structured` runs ``_trace_bvh`` instead: the
  two-level walk of ``shaders/common/scene_bvh.glsl`` (same nodes in the same order per ray).
- :func:`trace_brute` tests every shadow caster of a :class:`Scene` (no acceleration structure)
  with the same float32 ray transform, triangle and sphere tests.

Ray convention: ``origins`` (N,3), ``dirs`` (N,3) world space (not necessarily unit), ``tmax``
(N,) or scalar in units of |dir| (may be inf). Occluded when any caster is hit at t in (0, tmax).
Rays are transformed per instance with the inverse world matrix, the direction is not normalised.
A zero direction, tmax <= 0 or NaN input gives "not occluded".
"""
from __future__ import annotations

import numpy as np

from ..bake.textures import (BVH_TEXELS, FLT_BIG, MODEL_TEXELS, OBJECT_TEXELS, SPHERE_FLAG, TRI_TEXELS, f32_up)

F = np.float32
BIG = F(3.4e38)  # "no boundary" t of the DDA; > FLT_BIG
SLAB_BIG = F(1e30)  # 1/d for d == 0 in the slab test
EPS16 = F(2.0 ** -16)
TFAR_SCALE = F(1.0 + 2.0 ** -20)
PRETEST_EPS = F(2.0 ** -18)
OBVH_EPS = F(2.0 ** -16)  # object-BVH box widening (HS_OBVH_EPS)


# ------------------------------------------------------------------------------------------
# primitives shared by both tracers (float32, in the order the GLSL evaluates them)
# ------------------------------------------------------------------------------------------
def prepare_rays(origins, dirs, tmax):
    o = np.ascontiguousarray(np.asarray(origins, np.float64).reshape(-1, 3), F)
    d = np.ascontiguousarray(np.asarray(dirs, np.float64).reshape(-1, 3), F)
    t = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),)).astype(np.float64)
    t = np.where(np.isnan(t), 0.0, np.minimum(t, float(FLT_BIG))).astype(F)
    valid = (d != 0).any(axis=1) & (t > 0) & np.isfinite(o).all(axis=1) & np.isfinite(d).all(axis=1)
    return o, d, t, valid


def bake_space(baked, points) -> np.ndarray:
    """World points (N, 3) in the baked scene's space (float64)."""
    return np.asarray(points, np.float64).reshape(-1, 3) - baked.origin


def transform_rays(rows: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Model-space rays: ``rows`` (P, 12) float32 = rows 0..2 of the inverse world matrix."""
    r = rows.reshape(-1, 3, 4)
    om = ((r[:, :, 0] * o[:, None, 0] + r[:, :, 1] * o[:, None, 1]) + r[:, :, 2] * o[:, None, 2]) + r[:, :, 3]
    dm = (r[:, :, 0] * d[:, None, 0] + r[:, :, 1] * d[:, None, 1]) + r[:, :, 2] * d[:, None, 2]
    return om.astype(F), dm.astype(F)


def woop_setup(d: np.ndarray):
    """Watertight test set-up per ray: axis permutation (kx, ky, kz) and shear (Sx, Sy, Sz)."""
    a = np.abs(d)
    kz = np.where(a[:, 0] > a[:, 1], np.where(a[:, 0] > a[:, 2], 0, 2), np.where(a[:, 1] > a[:, 2], 1, 2))
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    n = np.arange(len(d))
    dz = d[n, kz]
    swap = dz < 0
    kx, ky = np.where(swap, ky, kx), np.where(swap, kx, ky)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = d[n, kx] / dz
        sy = d[n, ky] / dz
        sz = F(1.0) / dz
    return kx, ky, kz, sx.astype(F), sy.astype(F), sz.astype(F)


TFLOOR = F(2.0 ** -19)  # the BVH walk's nearest hit, x the vertices' reach along the ray axis


def _woop(o, setup, v0, v1, v2, tmax, floor: bool):
    """The watertight test's float32 values: ``(hit, U, V, W, T, det)``."""
    kx, ky, kz, sx, sy, sz = setup
    n = np.arange(len(o))
    A = (v0 - o).astype(F)
    B = (v1 - o).astype(F)
    C = (v2 - o).astype(F)
    Akz, Bkz, Ckz = A[n, kz], B[n, kz], C[n, kz]
    Ax = A[n, kx] - sx * Akz
    Ay = A[n, ky] - sy * Akz
    Bx = B[n, kx] - sx * Bkz
    By = B[n, ky] - sy * Bkz
    Cx = C[n, kx] - sx * Ckz
    Cy = C[n, ky] - sy * Ckz
    U = Cx * By - Cy * Bx
    V = Ax * Cy - Ay * Cx
    W = Bx * Ay - By * Ax
    inside = ~(((U < 0) | (V < 0) | (W < 0)) & ((U > 0) | (V > 0) | (W > 0)))
    det = U + V + W
    T = (U * (sz * Akz) + V * (sz * Bkz)) + W * (sz * Ckz)
    with np.errstate(over="ignore", invalid="ignore"):
        td = tmax * det
        lo = np.zeros_like(det)
        if floor:
            lo = (TFLOOR * np.maximum(np.maximum(np.abs(Akz), np.abs(Bkz)), np.abs(Ckz)) * np.abs(sz)).astype(F)
            lo = (lo * det).astype(F)
        pos = (det > 0) & (T > lo) & (T < td)
        neg = (det < 0) & (T < lo) & (T > td)
    return inside & (pos | neg), U, V, W, T, det


def woop_hit(o, setup, v0, v1, v2, tmax, floor: bool = False) -> np.ndarray:
    """Watertight ray/triangle (Woop, Benthin, Wald 2013), double-sided, hit iff t in (0, tmax);
    with ``floor`` (the BVH walk, ``scene_bvh.glsl``) only beyond ``TFLOOR * max|v_kz - o_kz| *
    |Sz|``, the float32 error of t, so that a huge triangle never shadows its own surface.
    All arguments broadcast per pair: o (P,3), setup arrays (P,), v* (P,3), tmax (P,)."""
    return _woop(o, setup, v0, v1, v2, tmax, floor)[0]


def sphere_hit(o, d, c, r, tmax) -> np.ndarray:
    """Ray/sphere surface hit with t in (0, tmax) (Ray Tracing Gems ch. 7, unnormalised d)."""
    f = (o - c).astype(F)
    a = (d * d).sum(axis=1, dtype=F)
    b = -(f * d).sum(axis=1, dtype=F)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        l = f + (b / a)[:, None] * d
        rr = r * r
        disc = rr - (l * l).sum(axis=1, dtype=F)
        cc = (f * f).sum(axis=1, dtype=F) - rr
        sq = np.sqrt(np.maximum(a * disc, F(0)))
        q = b + np.where(b >= 0, sq, -sq)
        t0 = cc / q
        t1 = q / a
        ok = (disc >= 0) & (q != 0)
        hit = ((t0 > 0) & (t0 < tmax)) | ((t1 > 0) & (t1 < tmax))
    return ok & hit


def sphere_pretest(o, d, c, r, tmax) -> np.ndarray:
    """Conservative: does segment o + t d, t in [0, tmax], come within r of c?"""
    f = (o - c).astype(F)
    a = (d * d).sum(axis=1, dtype=F)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tc = np.clip(-(f * d).sum(axis=1, dtype=F) / a, F(0), tmax)
        p = f + tc[:, None] * d
        e = PRETEST_EPS * (np.abs(f).sum(axis=1, dtype=F) + tc * np.abs(d).sum(axis=1, dtype=F))
        re = r + e
        return (p * p).sum(axis=1, dtype=F) <= re * re


def slab_inv(d: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.where(d != 0, F(1.0) / np.where(d != 0, d, F(1)), SLAB_BIG).astype(F)


def slab_hit(o, inv, bmin, bmax, tmax) -> np.ndarray:
    """Robust slab test (conservative: far t scaled by 1 + 2^-20)."""
    with np.errstate(over="ignore", invalid="ignore"):
        t1 = (bmin - o) * inv
        t2 = (bmax - o) * inv
        tn = np.minimum(t1, t2).max(axis=1)
        tf = np.maximum(t1, t2).min(axis=1) * TFAR_SCALE
    return np.maximum(tn, F(0)) <= np.minimum(tf, tmax)


def _ragged(starts, counts):
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return owner, np.asarray(starts, np.int64)[owner] + np.arange(total) - first[owner]


# ------------------------------------------------------------------------------------------
# structured tracer: reads the baked textures only
# ------------------------------------------------------------------------------------------
class _Tex:
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
            owner, tri = _ragged(leaf[lt] >> 3, leaf[lt] & 7)
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


def trace_structured(baked, origins, dirs, tmax=np.inf, stats: dict | None = None) -> np.ndarray:
    """Occlusion of each ray through the baked textures (the GPU algorithm of the bake's
    structure: the grid + BVH walk, or the two-level BVH walk of ``_trace_bvh``).
    ``origins`` are world space; they move into bake space (``baked.origin``) in float64."""
    if getattr(baked, "bvh", None) is not None:
        return _trace_bvh(baked, origins, dirs, tmax, stats)
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
    owner, entry = _ragged(g[:, 0], cnt)
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
            owner, entry = _ragged(leaf[lt] >> 3, leaf[lt] & 7)
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
                           np.where(dz[idx] < 0, oz[idx] + dz[idx] * np.minimum(tx_exit + delta, tm[r]), oz[idx])).astype(F)
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


# ------------------------------------------------------------------------------------------
# two-level BVH: mirrors shaders/common/scene_bvh.glsl (all rays in lock step, one numpy pass
# per loop iteration of the shader)
# ------------------------------------------------------------------------------------------
LEAF_FLAG = np.uint32(1 << 31)
QEPS = F(2.0 ** -20)
TLAS_EPS = F(2.0 ** -18)


def _qbox_hit(rlo, rhi, inv, n, tmax) -> np.ndarray:
    blo = np.stack([n[:, 0] & 0xFFFF, n[:, 0] >> 16, n[:, 1] & 0xFFFF], 1).astype(F)
    bhi = np.stack([n[:, 1] >> 16, n[:, 2] & 0xFFFF, n[:, 2] >> 16], 1).astype(F)
    with np.errstate(over="ignore", invalid="ignore"):
        t1 = (blo - rlo) * inv
        t2 = (bhi - rhi) * inv
        tn = np.minimum(t1, t2).max(axis=1)
        tf = np.maximum(t1, t2).min(axis=1) * TFAR_SCALE
    return np.maximum(tn, F(0)) <= np.minimum(tf, tmax)


def _l1(v):
    a = np.abs(v)
    return (a[:, 0] + a[:, 1]) + a[:, 2]


def _count_by(counts: dict, keys) -> None:
    k, c = np.unique(keys, return_counts=True)
    for a, b in zip(k.tolist(), c.tolist()):
        counts[a] = counts.get(a, 0) + b


def _trace_bvh(baked, origins, dirs, tmax, stats) -> np.ndarray:
    """The two-level walk of ``shaders/common/scene_bvh.glsl``, all rays at once. ``stats``
    (when given) gets totals of node steps (``iterations``: top level ``tlas_nodes`` + model
    trees ``bvh_nodes``), instances entered and triangle tests; with ``stats["per_ray"]`` True
    also each ray's node steps (``ray_iterations``) and the model-tree node steps and triangle
    tests per model tree (``tree_nodes``, ``tree_triangles``: keyed by the tree's end node)."""
    o, d, tm, valid = prepare_rays(bake_space(baked, origins), dirs, tmax)
    N = len(o)
    occ = np.zeros(N, bool)
    per_ray = stats is not None and bool(stats.get("per_ray"))
    if stats is not None:
        stats.update({"iterations": 0, "tlas_nodes": 0, "bvh_nodes": 0, "objects": 0, "triangles": 0})
    if per_ray:  # (N,) node steps of each ray; model-tree node steps and triangle tests per tree
        ray_steps = stats["ray_iterations"] = np.zeros(N, np.int64)
        tree_nodes = stats["tree_nodes"] = {}
        tree_tris = stats["tree_triangles"] = {}
    t = baked.textures
    node = t["node"].linear()
    leafd = t["leaf"].linear()
    tri = leafd.reshape(-1).view(F)
    u = baked.uniforms
    base = np.asarray(u["hs_tlas_base"], F)
    qs = F(u["hs_tlas_inv_scale"])
    end = int(u["hs_tlas_end"])
    with np.errstate(over="ignore", invalid="ignore"):
        toq = ((o - base) * qs).astype(F)
        te = TLAS_EPS * (_l1(toq) + F(u["hs_tlas_babs"]))
        t_lo = toq + te[:, None]
        t_hi = toq - te[:, None]
    t_inv = slab_inv((d * qs).astype(F))
    q_lo, q_hi, q_inv = t_lo.copy(), t_hi.copy(), t_inv.copy()
    i = np.full(N, int(u["hs_tlas_root"]), np.int64)
    ret = np.full(N, -1, np.int64)
    bend = np.zeros(N, np.int64)
    om = np.zeros((N, 3), F)
    dm = np.zeros((N, 3), F)
    act = np.nonzero(valid)[0]
    while act.size:
        back = act[(ret[act] >= 0) & (i[act] >= bend[act])]
        i[back] = ret[back]
        ret[back] = -1
        q_lo[back], q_hi[back], q_inv[back] = t_lo[back], t_hi[back], t_inv[back]
        act = act[~((ret[act] < 0) & (i[act] >= end))]
        if not act.size:
            break
        n = node[i[act]]
        w = n[:, 3]
        leaf = (w & LEAF_FLAG) != 0
        in_tlas = ret[act] < 0
        hit = _qbox_hit(q_lo[act], q_hi[act], q_inv[act], n, tm[act])
        if stats is not None:
            stats["iterations"] += act.size
            stats["tlas_nodes"] += int(in_tlas.sum())
            stats["bvh_nodes"] += int((~in_tlas).sum())
        if per_ray:
            ray_steps[act] += 1
            _count_by(tree_nodes, bend[act][~in_tlas])
        nxt = np.where(hit | leaf, i[act] + 1, w.astype(np.int64))
        pay = (w & np.uint32(0x7FFFFFFF)).astype(np.int64)
        # instances: transform, sphere test or enter the model tree
        k = np.nonzero(hit & leaf & in_tlas)[0]
        if k.size:
            r = act[k]
            rec = leafd[(5 * pay[k])[:, None] + np.arange(5)].reshape(-1, 20)
            mo, md = transform_rays(rec[:, 0:12].view(F), o[r], d[r])
            sph = (rec[:, 14] & SPHERE_FLAG) != 0
            if stats is not None:
                stats["objects"] += k.size
            if sph.any():
                s_ = np.nonzero(sph)[0]
                sp = rec[s_, 16:20].view(F)
                occ[r[s_]] |= sphere_hit(mo[s_], md[s_], sp[:, 0:3], sp[:, 3], tm[r[s_]])
            m_ = np.nonzero(~sph)[0]
            if m_.size:
                rm = r[m_]
                fr = rec[m_, 16:20].view(F)
                with np.errstate(over="ignore", invalid="ignore"):
                    oq = ((mo[m_] - fr[:, 0:3]) * fr[:, 3:4]).astype(F)
                    e = QEPS * _l1(oq)
                    q_lo[rm] = oq + e[:, None]
                    q_hi[rm] = oq - e[:, None]
                    q_inv[rm] = slab_inv((md[m_] * fr[:, 3:4]).astype(F))
                om[rm], dm[rm] = mo[m_], md[m_]
                ret[rm] = i[rm] + 1
                nxt[k[m_]] = rec[m_, 12].astype(np.int64)
                bend[rm] = rec[m_, 13].astype(np.int64)
        # model leaves: up to 4 triangles, 9 floats each from texel (pay >> 3)
        k = np.nonzero(hit & leaf & ~in_tlas)[0]
        if k.size:
            r = act[k]
            first, cnt = pay[k] >> 3, pay[k] & 7
            owner, j = _ragged(np.zeros(k.size, np.int64), cnt)
            f0 = first[owner] * 4 + j * 9
            v = tri[f0[:, None] + np.arange(9)].reshape(-1, 3, 3)
            p = r[owner]
            setup = woop_setup(dm[p])
            h = woop_hit(om[p], setup, v[:, 0], v[:, 1], v[:, 2], tm[p], floor=True)
            if stats is not None:
                stats["triangles"] += owner.size
            if per_ray:
                _count_by(tree_tris, bend[p])
            occ[p[h]] = True
        i[act] = nxt
        act = act[~occ[act]]
    return occ


# ------------------------------------------------------------------------------------------
# brute force: every caster, no acceleration structure
# ------------------------------------------------------------------------------------------
def trace_brute(scene, origins, dirs, tmax=np.inf, chunk: int = 1 << 21) -> np.ndarray:
    """Occlusion of each ray against every shadow caster of ``scene`` (small scenes only)."""
    o, d, tm, valid = prepare_rays(origins, dirs, tmax)
    occ = np.zeros(len(o), bool)
    inst = scene.instances
    if not len(inst):
        return occ
    for i in np.nonzero(inst.casts_shadow)[0].tolist():
        rays = np.nonzero(valid & ~occ)[0]
        if not rays.size:
            break
        model = scene.models[int(inst.model_ids[i])]
        rows = np.broadcast_to(inst.inverse[i, :3, :].astype(F).reshape(1, 12), (rays.size, 12))
        om, dm = transform_rays(rows, o[rays], d[rays])
        if inst.sphere[i]:
            c = np.broadcast_to(model.sphere_center.astype(F), om.shape)
            r = np.broadcast_to(f32_up(model.sphere_radius), (rays.size,))
            occ[rays[sphere_hit(om, dm, c, r, tm[rays])]] = True
            continue
        T = model.triangle_count
        if T == 0:
            continue
        v = model.vertices[model.triangles]  # (T, 3, 3)
        setup = woop_setup(dm)
        per = max(1, chunk // T)
        for a in range(0, rays.size, per):
            sl = slice(a, a + per)
            n = min(per, rays.size - a)
            rr = np.repeat(np.arange(a, a + n), T)
            tt = np.tile(np.arange(T), n)
            s = tuple(x[rr] for x in setup)
            h = woop_hit(om[rr], s, v[tt, 0], v[tt, 1], v[tt, 2], tm[rays[rr]])
            occ[rays[sl]] |= h.reshape(n, T).any(axis=1)
    return occ


# ------------------------------------------------------------------------------------------
# alpha-textured shadows: the watertight test with barycentrics, brute-force visibility
# ------------------------------------------------------------------------------------------
def woop_hit_bary(o, setup, v0, v1, v2, tmax, floor: bool = False):
    """:func:`woop_hit` (same float32 operations, same ``floor`` semantics, the same hits) that
    also returns the hit's barycentric weights and distance.

    Returns ``(hit (P,) bool, bary (P, 3) float64, t (P,) float64)``: ``bary`` = (U, V, W) / det,
    the weights of v0, v1, v2 (U = Cx By - Cy Bx, ...), non-negative and summing to 1; ``t`` =
    T / det in units of |d| (U, V, W, T are the test's float32 values; det = U + V + W is summed
    in float64 so the weights sum to 1). Both are 0 where there is no hit."""
    hit, U, V, W, T, _ = _woop(o, setup, v0, v1, v2, tmax, floor)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        uvw = np.stack([U, V, W], axis=1).astype(np.float64)
        dd = np.where(hit, uvw.sum(axis=1), 1.0)  # det in float64: the weights sum to 1
        bary = uvw / dd[:, None]
        t = T.astype(np.float64) / dd
    bary = np.where(hit[:, None], bary, 0.0)
    t = np.where(hit, t, 0.0)
    return hit, bary, t


def visibility_brute(scene, origins, dirs, tmax=np.inf, chunk: int = 1 << 21) -> np.ndarray:
    """(N,) float64 visibility in [0, 1] of each ray against every shadow caster of ``scene``
    (small scenes only): the product, over every caster surface the ray crosses at t in
    (0, tmax), of that surface's transmittance (:func:`core.oracle.alpha.transmittance`:
    0 for opaque surfaces and analytic spheres; BLEND 1 - alpha(uv); CLIP alpha < threshold).

    Same ray preparation, float32 transform and watertight test (``floor=False``) as
    :func:`trace_brute`, so ``visibility == 0`` exactly where ``trace_brute`` reports occluded
    on a scene without alpha. A triangle's UV is the barycentric blend of its corners' UVs
    (``Model.uvs``). Invalid rays (zero direction, tmax <= 0, NaN) get 1."""
    from .alpha import is_opaque, transmittance

    o, d, tm, valid = prepare_rays(origins, dirs, tmax)
    vis = np.ones(len(o), np.float64)
    inst = scene.instances
    if not len(inst):
        return vis
    for i in np.nonzero(inst.casts_shadow)[0].tolist():
        rays = np.nonzero(valid & (vis > 0))[0]
        if not rays.size:
            break
        model = scene.models[int(inst.model_ids[i])]
        rows = np.broadcast_to(inst.inverse[i, :3, :].astype(F).reshape(1, 12), (rays.size, 12))
        om, dm = transform_rays(rows, o[rays], d[rays])
        if inst.sphere[i]:
            c = np.broadcast_to(model.sphere_center.astype(F), om.shape)
            r = np.broadcast_to(f32_up(model.sphere_radius), (rays.size,))
            vis[rays[sphere_hit(om, dm, c, r, tm[rays])]] = 0.0
            continue
        T = model.triangle_count
        if T == 0:
            continue
        mid = int(inst.material_ids[i])
        opaque = is_opaque(scene, mid)
        v = model.vertices[model.triangles]  # (T, 3, 3)
        uvs = (model.uvs.astype(np.float64) if model.uvs is not None
               else np.zeros((T, 3, 2), np.float64))
        setup = woop_setup(dm)
        per = max(1, chunk // T)
        for a in range(0, rays.size, per):
            n = min(per, rays.size - a)
            rr = np.repeat(np.arange(a, a + n), T)
            tt = np.tile(np.arange(T), n)
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


# ------------------------------------------------------------------------------------------
# a hard light's light-space grid (core/bake/lightgrid.py, shaders/common/scene_lightgrid.glsl)
# ------------------------------------------------------------------------------------------
def _dot32(a, b) -> np.ndarray:
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
        g = np.stack([np.minimum(uu * inv, r - F(1.0 / 256.0)), np.minimum(vv * inv, r - F(1.0 / 256.0)) + face * r], axis=1)
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
    own, ent = _ragged(st, cnt)
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
