"""The two-level BVH walked as wide nodes: the packed 4-wide walk of ``shaders/common/scene_bvh.glsl``
(:func:`trace_wide_packed`, texture [wide]), and what other widths and child orders would cost a
ray, measured on the binary trees the bake builds (:func:`trace_wide`,
``benchmarks/profile_traversal.py --wide``).

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

from ...bake.structures.wide import STRIDE, WIDTH, grandchildren
from .primitives import TFAR_SCALE, F, bake_space, prepare_rays
from .twolevel import LEAF_FLAG, _qbox_hit, enter_instances, leaf_hits, tlas_ray, trace_twolevel

#: child orders: the nearest box popped first, the farthest, or the tree's own order
ORDERS = ("distance", "far", "tree")
RETURN = -2  # a stack entry: the model tree is done, back to the top level's ray
RETURN_WORD = 0x7FFFFFFF  # the packed walk's (HS_WIDE_RETURN)
STACK = 96  # entries per ray (a wide node pushes at most 2**levels - 1 more than it pops)


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


class _Walk:
    """What both wide walks start from: the rays (bake space, ``tm``, ``valid``), their answers
    and fetches so far, the textures, the top level's quantised rays (``t``) and the current
    tree's (``q``, starting as the top level's), and the model-space rays (``om``, ``dm``)."""

    def __init__(self, baked, origins, dirs, tmax):
        self.o, self.d, self.tm, self.valid = prepare_rays(bake_space(baked, origins), dirs, tmax)
        N = len(self.o)
        self.occ = np.zeros(N, bool)
        self.fetches = np.zeros(N, np.int64)
        tex = baked.textures
        self.node = tex["node"].linear()
        self.leafd = tex["leaf"].linear()
        self.tri = self.leafd.reshape(-1).view(F)
        self.t = tlas_ray(baked, self.o, self.d)
        self.q = tuple(a.copy() for a in self.t)
        self.om = np.zeros((N, 3), F)
        self.dm = np.zeros((N, 3), F)
        self.in_model = np.zeros(N, bool)

    def leave(self, r) -> None:
        """Rays ``r`` back from their model trees to the top level."""
        for q, t in zip(self.q, self.t):
            q[r] = t[r]
        self.in_model[r] = False

    def pop(self, stack, top, act, ret):
        """Each active ray ``act`` pops its stack's top entry; those that pop ``ret`` (a model
        tree done) go back to the top level. The other rays and their entries."""
        top[act] -= 1
        e = stack[act, top[act]]
        back = e == ret
        self.leave(act[back])
        return act[~back], e[~back]

    def enter(self, ids, r):
        """Rays ``r`` at instance records ``ids`` (:func:`.twolevel.enter_instances`)."""
        return enter_instances(self.leafd, ids, r, self.o, self.d, self.tm, self.occ, self.q, self.om, self.dm)

    def triangles(self, words, r) -> None:
        """Rays ``r`` at model leaves ``words``: their hits marked."""
        p, h = leaf_hits(self.tri, words, r, self.om, self.dm, self.tm)
        self.occ[p[h]] = True


def trace_wide(baked, origins, dirs, tmax=np.inf, levels: int = 2, order: str = "distance") -> tuple:
    """``(occluded, fetches, wide nodes)`` of each ray: the walk above over ``baked`` (a two-level
    BVH bake), ``levels`` binary levels per wide node (2: 4-wide, 3: 8-wide)."""
    if order not in ORDERS:
        raise ValueError(f"order must be one of {', '.join(ORDERS)}, not {order!r}")
    s = _Walk(baked, origins, dirs, tmax)
    node, tm = s.node, s.tm
    N = len(s.o)
    visits = np.zeros(N, np.int64)
    stack = np.zeros((N, STACK), np.int64)
    top = np.zeros(N, np.int64)  # entries on each ray's stack
    stack[:, 0] = int(baked.uniforms["hs_tlas_root"])
    top[s.valid] = 1
    K = 2 ** levels
    act = np.nonzero(top > 0)[0]
    while act.size:
        act, e = s.pop(stack, top, act, RETURN)
        w = node[np.maximum(e, 0), 3]
        leaf = (w & LEAF_FLAG) != 0
        inside = s.in_model[act]  # (before this step enters a model tree)
        s.fetches[act] += 1
        pay = (w & np.uint32(0x7FFFFFFF)).astype(np.int64)
        # wide nodes: their children's boxes, the hit ones pushed (the nearest on top)
        k = np.nonzero(~leaf)[0]
        if k.size:
            r = act[k]
            visits[r] += 1
            ch = grandchildren(node, e[k], levels)
            tn = _box_entry(*(q[r] for q in s.q), node[np.maximum(ch, 0)], tm[r])
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
            m_, rec = s.enter(pay[k], act[k])
            if m_.size:
                rm = act[k][m_]
                s.in_model[rm] = True
                stack[rm, top[rm]] = RETURN
                stack[rm, top[rm] + 1] = rec[m_, 12].astype(np.int64)
                top[rm] += 2
        # model leaves: their triangles
        k = np.nonzero(leaf & inside)[0]
        if k.size:
            s.triangles(pay[k], act[k])
        if (top >= STACK - K).any():
            raise RuntimeError("a ray's stack outgrew STACK entries")
        act = np.nonzero((top > 0) & ~s.occ)[0]
    return s.occ, s.fetches, visits


def _root_words(node, root, end) -> np.ndarray:
    """``hs_wide_root``: what a tree's walk starts from (its root's block, or a one-leaf tree's
    leaf word)."""
    root = np.asarray(root, np.int64)
    return np.where(np.asarray(end) - root == 1, node[root, 3].astype(np.int64), root)


def trace_wide_packed(baked, origins, dirs, tmax=np.inf, stack: int = 32, stats: dict | None = None) -> np.ndarray:
    """The 4-wide walk of ``shaders/common/scene_bvh.glsl`` (``HS_BVH_WIDE``) over the packed
    [wide] texture, all rays at once, each with a stack of ``stack`` entries; a ray whose stack
    would overflow is answered by the binary walk (:func:`.twolevel.trace_twolevel`), as the
    shader does. ``stats`` (when given) gets each ray's dependent fetches (``ray_fetches``: a
    wide node's block, an instance record, a leaf's triangles, a one-leaf tree's root),
    ``max_stack`` and ``fallbacks``."""
    s = _Walk(baked, origins, dirs, tmax)
    node, tm, fetches = s.node, s.tm, s.fetches
    wide = baked.textures["wide"].linear()
    N = len(s.o)
    stk = np.zeros((N, stack + 1), np.int64)
    top = np.zeros(N, np.int64)
    root, end = int(baked.uniforms["hs_tlas_root"]), int(baked.uniforms["hs_tlas_end"])
    if end > root:
        stk[:, 0] = _root_words(node, [root], [end])[0]
        top[s.valid] = 1
        fetches[s.valid] += end - root == 1
    binary = np.zeros(N, bool)  # rays whose stack would overflow
    deepest = int(top.max()) if N else 0
    act = np.nonzero(top > 0)[0]
    while act.size:
        act, e = s.pop(stk, top, act, RETURN_WORD)
        inner = (e & int(LEAF_FLAG)) == 0
        inside = s.in_model[act]  # (before this step enters a model tree)
        fetches[act] += 1
        # wide nodes: children pushed last first where their boxes are hit
        k = np.nonzero(inner)[0]
        full = top[act[k]] > stack - WIDTH
        binary[act[k[full]]] = True
        k = k[~full]
        if k.size:
            r = act[k]
            blk = wide[STRIDE * e[k][:, None] + np.arange(WIDTH)]  # (K, 4, 4)
            for c in range(WIDTH - 1, -1, -1):
                n = blk[:, c]
                h = _qbox_hit(*(q[r] for q in s.q), n, tm[r]) & (n[:, 3] != 0)
                rh = r[h]
                stk[rh, top[rh]] = n[h, 3].astype(np.int64)
                top[rh] += 1
        # instance records: a sphere's test, or the model tree entered
        pay = e & 0x7FFFFFFF
        k = np.nonzero(~inner & ~inside)[0]
        if k.size:
            m_, rec = s.enter(pay[k], act[k])
            if m_.size:
                rm = act[k][m_]
                a, b = rec[m_, 12].astype(np.int64), rec[m_, 13].astype(np.int64)
                go = b > a
                full = top[rm] > stack - 2
                binary[rm[go & full]] = True
                go &= ~full
                rm, a, b = rm[go], a[go], b[go]
                s.in_model[rm] = True
                stk[rm, top[rm]] = RETURN_WORD
                stk[rm, top[rm] + 1] = _root_words(node, a, b)
                fetches[rm] += b - a == 1
                top[rm] += 2
        # model leaves: their triangles
        k = np.nonzero(~inner & inside)[0]
        if k.size:
            s.triangles(pay[k], act[k])
        deepest = max(deepest, int(top.max()))
        act = np.nonzero((top > 0) & ~s.occ & ~binary)[0]
    occ = s.occ
    if binary.any():
        b = np.nonzero(binary)[0]
        occ[b] = trace_twolevel(baked, np.asarray(origins)[b], np.asarray(dirs)[b],
                                np.broadcast_to(np.asarray(tmax, np.float64), (N,))[b])
    if stats is not None:
        stats.update({"ray_fetches": fetches, "max_stack": deepest, "fallbacks": int(binary.sum())})
    return occ
