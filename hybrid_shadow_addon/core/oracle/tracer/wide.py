"""The two-level BVH walked as wide nodes: what a wide layout would cost a ray, measured on the
binary trees the bake builds (``benchmarks/profile_traversal.py --wide``).

Each binary tree (the top level, every model tree) is read as nodes of up to ``2**levels``
children: an inner binary node at a depth that is a multiple of ``levels`` (from its tree's root)
stands for a wide node whose children are its descendants ``levels`` levels down, or the leaves met
before. A ray pops one entry of its stack a step: a wide node (one dependent fetch: its children's
boxes, fetched together) tests its children's boxes and pushes those it hits; a leaf is an
instance record (enter its model tree, or test its sphere) or a model leaf's triangles (one
fetch each). The children's boxes are the binary nodes' own 16-bit boxes, tested as
``twolevel.py`` tests them, so every leaf the binary walk reaches is reached here and the answers
are the binary walk's. ``order``: children pushed so that the nearest box (its entry distance) is
popped first (``"distance"``), the farthest (``"far"``), or in tree order (``"tree"``).
"""
from __future__ import annotations

import numpy as np

from .primitives import TFAR_SCALE, F, bake_space, prepare_rays, slab_inv
from .twolevel import LEAF_FLAG, TLAS_EPS, _l1, enter_instances, leaf_hits

#: child orders: the nearest box popped first, the farthest, or the tree's own order
ORDERS = ("distance", "far", "tree")
RETURN = -2  # a stack entry: the model tree is done, back to the top level's ray
STACK = 96  # entries per ray (a wide node pushes at most 2**levels - 1 more than it pops)


def _children(node: np.ndarray, at: np.ndarray, levels: int) -> np.ndarray:
    """(M, 2**levels) binary node indices of the wide children of binary inner nodes ``at``
    (-1: none): each inner node's two children, ``levels`` times; a leaf stays as it is."""
    w = node[:, 3]
    leaf = (w & LEAF_FLAG) != 0
    front = at[:, None].astype(np.int64)
    for _ in range(levels):
        ok = front >= 0
        f = np.where(ok, front, 0)
        is_leaf = leaf[f] | ~ok
        left = f + 1
        right = np.where(leaf[left], left + 1, w[left].astype(np.int64))
        a = np.where(is_leaf, front, left)
        b = np.where(is_leaf, -1, right)
        front = np.stack([a, b], axis=2).reshape(len(at), -1)
    return front


def _box_entry(rlo, rhi, inv, n, tmax) -> np.ndarray:
    """Entry distance of rays into nodes' 16-bit boxes (``n``: (M, K, 4) texels), inf where
    the ray misses (``twolevel._qbox_hit``'s test)."""
    blo = np.stack([n[..., 0] & 0xFFFF, n[..., 0] >> 16, n[..., 1] & 0xFFFF], -1).astype(F)
    bhi = np.stack([n[..., 1] >> 16, n[..., 2] & 0xFFFF, n[..., 2] >> 16], -1).astype(F)
    with np.errstate(over="ignore", invalid="ignore"):
        t1 = (blo - rlo[:, None]) * inv[:, None]
        t2 = (bhi - rhi[:, None]) * inv[:, None]
        tn = np.minimum(t1, t2).max(axis=2)
        tf = np.maximum(t1, t2).min(axis=2) * TFAR_SCALE
        hit = np.maximum(tn, F(0)) <= np.minimum(tf, tmax[:, None])
    return np.where(hit, np.maximum(tn, F(0)), np.inf)


def trace_wide(baked, origins, dirs, tmax=np.inf, levels: int = 2, order: str = "distance") -> tuple:
    """``(occluded, fetches, wide nodes)`` of each ray: the walk above over ``baked`` (a two-level
    BVH bake), ``levels`` binary levels per wide node (2: 4-wide, 3: 8-wide)."""
    if order not in ORDERS:
        raise ValueError(f"order must be one of {', '.join(ORDERS)}, not {order!r}")
    o, d, tm, valid = prepare_rays(bake_space(baked, origins), dirs, tmax)
    N = len(o)
    occ = np.zeros(N, bool)
    fetches = np.zeros(N, np.int64)
    visits = np.zeros(N, np.int64)
    t = baked.textures
    node = t["node"].linear()
    leafd = t["leaf"].linear()
    tri = leafd.reshape(-1).view(F)
    u = baked.uniforms
    base = np.asarray(u["hs_tlas_base"], F)
    qs = F(u["hs_tlas_inv_scale"])
    with np.errstate(over="ignore", invalid="ignore"):
        toq = ((o - base) * qs).astype(F)
        te = TLAS_EPS * (_l1(toq) + F(u["hs_tlas_babs"]))
        t_lo = toq + te[:, None]
        t_hi = toq - te[:, None]
    t_inv = slab_inv((d * qs).astype(F))
    q_lo, q_hi, q_inv = t_lo.copy(), t_hi.copy(), t_inv.copy()
    om = np.zeros((N, 3), F)
    dm = np.zeros((N, 3), F)
    stack = np.zeros((N, STACK), np.int64)
    top = np.zeros(N, np.int64)  # entries on each ray's stack
    stack[:, 0] = int(u["hs_tlas_root"])
    top[valid] = 1
    in_model = np.zeros(N, bool)
    K = 2 ** levels
    act = np.nonzero(top > 0)[0]
    while act.size:
        top[act] -= 1
        e = stack[act, top[act]]
        back = e == RETURN
        if back.any():
            r = act[back]
            q_lo[r], q_hi[r], q_inv[r] = t_lo[r], t_hi[r], t_inv[r]
            in_model[r] = False
        act, e = act[~back], e[~back]
        w = node[np.maximum(e, 0), 3]
        leaf = (w & LEAF_FLAG) != 0
        inside = in_model[act]  # (before this step enters a model tree)
        fetches[act] += 1
        pay = (w & np.uint32(0x7FFFFFFF)).astype(np.int64)
        # wide nodes: their children's boxes, the hit ones pushed (the nearest on top)
        k = np.nonzero(~leaf)[0]
        if k.size:
            r = act[k]
            visits[r] += 1
            ch = _children(node, e[k], levels)
            tn = _box_entry(q_lo[r], q_hi[r], q_inv[r], node[np.maximum(ch, 0)], tm[r])
            tn[ch < 0] = np.inf
            if order == "distance":
                srt = np.argsort(-tn, axis=1, kind="stable")  # (far first: the nearest ends on top)
            elif order == "far":
                srt = np.argsort(np.where(np.isfinite(tn), tn, -np.inf), axis=1, kind="stable")
            else:
                srt = np.tile(np.arange(K)[::-1], (k.size, 1))
            ch = np.take_along_axis(ch, srt, axis=1)
            hit = np.isfinite(np.take_along_axis(tn, srt, axis=1))
            pos = top[r][:, None] + np.cumsum(hit, axis=1) - 1
            rr, cc = np.nonzero(hit)
            stack[r[rr], pos[rr, cc]] = ch[rr, cc]
            top[r] += hit.sum(axis=1)
        # instance records: a sphere's test, or the model tree entered
        k = np.nonzero(leaf & ~inside)[0]
        if k.size:
            m_, rec = enter_instances(leafd, pay[k], act[k], o, d, tm, occ, (q_lo, q_hi, q_inv), om, dm)
            if m_.size:
                rm = act[k][m_]
                in_model[rm] = True
                stack[rm, top[rm]] = RETURN
                stack[rm, top[rm] + 1] = rec[m_, 12].astype(np.int64)
                top[rm] += 2
        # model leaves: their triangles
        k = np.nonzero(leaf & inside)[0]
        if k.size:
            p, h = leaf_hits(tri, pay[k], act[k], om, dm, tm)
            occ[p[h]] = True
        if (top >= STACK - K).any():
            raise RuntimeError("a ray's stack outgrew STACK entries")
        act = np.nonzero((top > 0) & ~occ)[0]
    return occ, fetches, visits
