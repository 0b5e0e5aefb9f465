"""The two-level BVH walk of ``shaders/common/scene_bvh.glsl``: the same nodes in the same order
per ray, all rays in lock step (one numpy pass per loop iteration of the shader)."""
from __future__ import annotations

import numpy as np

from ...bake.textures import SPHERE_FLAG
from .primitives import (
    F,
    bake_space,
    prepare_rays,
    ragged_pairs,
    slab_inv,
    slab_span_hit,
    sphere_hit,
    transform_rays,
    woop_hit,
    woop_setup,
)

LEAF_FLAG = np.uint32(1 << 31)
QEPS = F(2.0 ** -20)
TLAS_EPS = F(2.0 ** -18)


def _qbox_hit(rlo, rhi, inv, n, tmax) -> np.ndarray:
    """Slab test of quantised rays against nodes' 16-bit boxes (``n``: the node texels)."""
    blo = np.stack([n[:, 0] & 0xFFFF, n[:, 0] >> 16, n[:, 1] & 0xFFFF], 1).astype(F)
    bhi = np.stack([n[:, 1] >> 16, n[:, 2] & 0xFFFF, n[:, 2] >> 16], 1).astype(F)
    with np.errstate(over="ignore", invalid="ignore"):
        return slab_span_hit((blo - rlo) * inv, (bhi - rhi) * inv, tmax)


def _l1(v):
    """Float32 L1 norm of each row, summed in the shader's order."""
    a = np.abs(v)
    return (a[:, 0] + a[:, 1]) + a[:, 2]


def _count_by(counts: dict, keys) -> None:
    """Add the occurrences of each key to ``counts``."""
    k, c = np.unique(keys, return_counts=True)
    for a, b in zip(k.tolist(), c.tolist()):
        counts[a] = counts.get(a, 0) + b


def tlas_ray(baked, o, d) -> tuple:
    """Rays ``o``, ``d`` (bake space) quantised on the top level's grid: ``(lo, hi, inv)``, the
    origin planes widened by the top level's epsilon and 1 / d_q."""
    u = baked.uniforms
    base = np.asarray(u["hs_tlas_base"], F)
    qs = F(u["hs_tlas_inv_scale"])
    with np.errstate(over="ignore", invalid="ignore"):
        toq = ((o - base) * qs).astype(F)
        te = TLAS_EPS * (_l1(toq) + F(u["hs_tlas_babs"]))
        return toq + te[:, None], toq - te[:, None], slab_inv((d * qs).astype(F))


def enter_instances(leafd, ids, r, o, d, tm, occ, q, om, dm):
    """Rays ``r`` at instance records ``ids``: each ray moved into its instance's model space; a
    sphere's hit marked in ``occ``; for meshes, the quantised ray ``q`` = (lo, hi, inv) and the
    model-space ray ``om``, ``dm`` set. ``(positions in r of the meshes, the records)``: the
    caller enters their model trees (record texel 3: root, end)."""
    rec = leafd[(5 * ids)[:, None] + np.arange(5)].reshape(-1, 20)
    mo, md = transform_rays(rec[:, 0:12].view(F), o[r], d[r])
    sph = (rec[:, 14] & SPHERE_FLAG) != 0
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
            q[0][rm] = oq + e[:, None]
            q[1][rm] = oq - e[:, None]
            q[2][rm] = slab_inv((md[m_] * fr[:, 3:4]).astype(F))
        om[rm], dm[rm] = mo[m_], md[m_]
    return m_, rec


def leaf_hits(tri, words, r, om, dm, tm):
    """Rays ``r`` at model leaves (payloads ``words``: first [leaf] texel << 3 | count): each
    triangle tested against its ray in model space (``om``, ``dm``). ``(the ray of each
    triangle, whether it hits)``."""
    first, cnt = words >> 3, words & 7
    owner, j = ragged_pairs(np.zeros(len(words), np.int64), cnt)
    f0 = first[owner] * 4 + j * 9
    v = tri[f0[:, None] + np.arange(9)].reshape(-1, 3, 3)
    p = r[owner]
    return p, woop_hit(om[p], woop_setup(dm[p]), v[:, 0], v[:, 1], v[:, 2], tm[p], floor=True)


def trace_twolevel(baked, origins, dirs, tmax=np.inf, stats: dict | None = None) -> np.ndarray:
    """The two-level walk of ``shaders/common/scene_bvh.glsl``, all rays at once. ``stats``
    (when given) gets totals of node steps (``iterations``: top level ``tlas_nodes`` + model
    trees ``bvh_nodes``), instances entered and triangle tests; with ``stats["per_ray"]`` True
    also each ray's node steps (``ray_iterations``), its dependent fetches (``ray_fetches``: a
    node a step, then an instance record or a leaf's triangles where the step enters one) and
    the model-tree node steps and triangle tests per model tree (``tree_nodes``,
    ``tree_triangles``: keyed by the tree's end node)."""
    o, d, tm, valid = prepare_rays(bake_space(baked, origins), dirs, tmax)
    N = len(o)
    occ = np.zeros(N, bool)
    per_ray = stats is not None and bool(stats.get("per_ray"))
    if stats is not None:
        stats.update({"iterations": 0, "tlas_nodes": 0, "bvh_nodes": 0, "objects": 0, "triangles": 0})
    if per_ray:  # (N,) node steps of each ray; model-tree node steps and triangle tests per tree
        ray_steps = stats["ray_iterations"] = np.zeros(N, np.int64)
        ray_fetches = stats["ray_fetches"] = np.zeros(N, np.int64)
        tree_nodes = stats["tree_nodes"] = {}
        tree_tris = stats["tree_triangles"] = {}
    t = baked.textures
    node = t["node"].linear()
    leafd = t["leaf"].linear()
    tri = leafd.reshape(-1).view(F)
    u = baked.uniforms
    end = int(u["hs_tlas_end"])
    t_lo, t_hi, t_inv = tlas_ray(baked, o, d)
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
            ray_fetches[act] += 1 + (hit & leaf)  # (the node; an instance record or a leaf's triangles)
            _count_by(tree_nodes, bend[act][~in_tlas])
        nxt = np.where(hit | leaf, i[act] + 1, w.astype(np.int64))
        pay = (w & np.uint32(0x7FFFFFFF)).astype(np.int64)
        # instances: transform, sphere test or enter the model tree
        k = np.nonzero(hit & leaf & in_tlas)[0]
        if k.size:
            if stats is not None:
                stats["objects"] += k.size
            m_, rec = enter_instances(leafd, pay[k], act[k], o, d, tm, occ, (q_lo, q_hi, q_inv), om, dm)
            if m_.size:
                rm = act[k][m_]
                ret[rm] = i[rm] + 1
                nxt[k[m_]] = rec[m_, 12].astype(np.int64)
                bend[rm] = rec[m_, 13].astype(np.int64)
        # model leaves: up to 4 triangles, 9 floats each from texel (pay >> 3)
        k = np.nonzero(hit & leaf & ~in_tlas)[0]
        if k.size:
            p, h = leaf_hits(tri, pay[k], act[k], om, dm, tm)
            if stats is not None:
                stats["triangles"] += p.size
            if per_ray:
                _count_by(tree_tris, bend[p])
            occ[p[h]] = True
        i[act] = nxt
        act = act[~occ[act]]
    return occ

