"""Binned SAH BVH builder, vectorised over every node of a depth (and every tree) at once.

Top down, one numpy pass per depth. Large nodes (``spatial_min``) bin their items' centroids
into ``bins`` bins along the longest axis of their centroid box, evaluate the surface-area cost of
the ``bins - 1`` splits between bins (bin bounds by ``np.minimum.at``) and partition their item
range stably (left items first; all centroids in one bin: count median). Mid-sized nodes
(``sah_min``) evaluate the same cost between ``bins`` equal runs of their current (Morton) order,
which needs no reordering; small ones split that order in the middle. A node with at most
``leaf_size`` items is a leaf. Nodes are numbered in depth-first pre-order per tree (left child
``i + 1``, escape = the node after the subtree), the layout the stackless walks read.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..progress import checkpoint


@dataclass
class SAHBuild:
    """Trees over groups of items; indices local to this build."""

    node_min: np.ndarray  # (Nn, 3) float64 exact union of the item boxes
    node_max: np.ndarray
    escape: np.ndarray  # (Nn,) int64
    leaf_start: np.ndarray  # (Nn,) position in ``perm`` of the leaf's first item, -1 inner
    leaf_count: np.ndarray  # (Nn,) 0 for inner nodes
    perm: np.ndarray  # (N,) item ids in leaf order (each group's items stay in its range)
    node_start: np.ndarray  # (G,) first node of each tree
    node_count: np.ndarray  # (G,)
    depth: np.ndarray  # (G,)


def _ragged(starts, counts):
    counts = np.asarray(counts, np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    own = np.repeat(np.arange(len(counts)), counts)
    return own, first, np.asarray(starts, np.int64)[own] + np.arange(int(counts.sum())) - first[own]


def _run_split(mnT, mxT, ss, cc, B) -> np.ndarray:
    """SAH split of each node [ss, ss + cc) between ``B`` equal runs of its current order.
    ``mnT`` / ``mxT``: (3, N + 1) item boxes by component (a pad column: the last bound may be N)."""
    order = np.argsort(ss)
    ss, cc = ss[order], cc[order]
    R = ss.size
    j = np.arange(B + 1)
    bnd = ss[:, None] + (j[None, :] * cc[:, None]) // B  # (R, B + 1), strictly increasing
    idx = bnd.reshape(-1)
    lo = np.minimum.reduceat(mnT, idx, axis=1).reshape(3, R, B + 1)[:, :, :B].transpose(0, 2, 1)  # (3, B, R)
    hi = np.maximum.reduceat(mxT, idx, axis=1).reshape(3, R, B + 1)[:, :, :B].transpose(0, 2, 1)
    llo = np.minimum.accumulate(lo, axis=1)[:, :-1]
    lhi = np.maximum.accumulate(hi, axis=1)[:, :-1]
    rlo = np.minimum.accumulate(lo[:, ::-1], axis=1)[:, ::-1][:, 1:]
    rhi = np.maximum.accumulate(hi[:, ::-1], axis=1)[:, ::-1][:, 1:]
    nl = (bnd[:, 1:B] - ss[:, None]).T  # (B - 1, R)
    nr = cc[None, :] - nl
    cost = _area3(llo, lhi) * nl + _area3(rlo, rhi) * nr
    best = np.argmin(cost, axis=0)
    out = np.empty(R, np.int64)
    out[order] = nl[best, np.arange(R)]
    return out


def _area3(lo, hi):
    """Half the surface area of boxes stored by component first: (3, ...) arrays."""
    e = np.maximum(hi - lo, 0.0)
    return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]


def build_sah(item_min, item_max, group_start, group_count, leaf_size: int = 4, bins: int = 16,
              sah_min: int = 16, spatial_min: int = 0) -> SAHBuild:
    """Trees, one per group ``g`` over items ``[group_start[g], + group_count[g])``, the items of
    each group in Morton order. Nodes with more than ``spatial_min`` items (0: none) split by
    spatially binned SAH (``bins`` bins along the longest centroid axis, stable partition);
    nodes with more than ``sah_min`` items by SAH over ``bins`` equal runs of their item order
    (the split lies between runs; no reordering); smaller ones at the middle of their order."""
    # item arrays kept in current order, by component (3, N + 1: a pad column for _run_split's
    # last bound); float32 boxes (exact for float32 input) halve the traffic
    dt = np.float32 if np.asarray(item_min).dtype == np.float32 else np.float64
    imin = np.asarray(item_min, dt).reshape(-1, 3)
    imax = np.asarray(item_max, dt).reshape(-1, 3)
    gs = np.asarray(group_start, np.int64)
    gc = np.asarray(group_count, np.int64)
    G = len(gc)
    N = len(imin)
    mnT = np.empty((3, N + 1), dt)
    mxT = np.empty((3, N + 1), dt)
    mnT[:, :N] = imin.T
    mxT[:, :N] = imax.T
    mnT[:, N:] = 0
    mxT[:, N:] = 0
    cmn, cmx = mnT[:, :N], mxT[:, :N]  # views
    perm = np.arange(N, dtype=np.int64)
    B = int(bins)
    # where no node splits between runs of the current order, the item boxes stay in item order
    # (read through perm) until the leaves want them in leaf order: no scatter per depth
    boxes_in_item_order = 0 < spatial_min <= max(sah_min, B)
    L = max(1, int(leaf_size))
    levels = []
    has = gc > 0
    s = gs[has].copy()
    c = gc[has].copy()
    grp = np.nonzero(has)[0]
    while s.size:
        checkpoint()
        leaf = c <= L
        lv = {"s": s, "c": c, "grp": grp, "leaf": leaf}
        levels.append(lv)
        inner = np.nonzero(~leaf)[0]
        if not inner.size:
            break
        ci_all = c[inner]
        nleft = L * ((-(-ci_all // L) + 1) // 2)
        big = (ci_all > spatial_min) if spatial_min > 0 else np.zeros(ci_all.size, bool)
        if big.any():
            sn = inner[big]
            ss, ci = s[sn], c[sn]
            Rb = sn.size
            o, st_i, pos = _ragged(ss, ci)

            def per_item(v, ci=ci):  # a value per node, repeated for its items (v[o], faster)
                return np.repeat(v, ci)

            ids = np.take(perm, pos)
            src = ids if boxes_in_item_order else pos
            imn = np.take(cmn, src, axis=1)  # (take: a gather several times faster than cmn[:, pos])
            imx = np.take(cmx, src, axis=1)
            ce = imn + imx  # twice the centroids (the bins are the same)
            cmin = np.minimum.reduceat(ce, st_i, axis=1).T
            cmax = np.maximum.reduceat(ce, st_i, axis=1).T
            ext = cmax - cmin
            axis = np.argmax(ext, axis=1)
            eax = np.max(ext, axis=1)
            ax_o = per_item(axis)
            ca = np.where(ax_o == 0, ce[0], np.where(ax_o == 1, ce[1], ce[2]))
            c0 = np.where(axis == 0, cmin[:, 0], np.where(axis == 1, cmin[:, 1], cmin[:, 2]))
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(eax > 0, B / np.where(eax > 0, eax, 1.0), 0.0)
            b = ((ca - per_item(c0)) * per_item(scale)).astype(np.int64)
            np.clip(b, 0, B - 1, out=b)
            key = b * Rb + o  # bin-major: the prefix scans run over contiguous rows
            cnt = np.bincount(key, minlength=Rb * B).reshape(B, Rb)
            lo = np.full((3, B * Rb), np.inf, dt)
            hi = np.full((3, B * Rb), -np.inf, dt)
            for k in range(3):
                np.minimum.at(lo[k], key, imn[k])
                np.maximum.at(hi[k], key, imx[k])
            lo = lo.reshape(3, B, Rb)
            hi = hi.reshape(3, B, Rb)
            llo = np.minimum.accumulate(lo, axis=1)[:, :-1]
            lhi = np.maximum.accumulate(hi, axis=1)[:, :-1]
            rlo = np.minimum.accumulate(lo[:, ::-1], axis=1)[:, ::-1][:, 1:]
            rhi = np.maximum.accumulate(hi[:, ::-1], axis=1)[:, ::-1][:, 1:]
            nl = np.cumsum(cnt, axis=0)[:-1]
            nr = ci[None, :] - nl
            with np.errstate(invalid="ignore", over="ignore"):
                el = np.maximum(lhi - llo, 0.0)
                er = np.maximum(rhi - rlo, 0.0)
                al = el[0] * el[1] + el[1] * el[2] + el[2] * el[0]
                ar = er[0] * er[1] + er[1] * er[2] + er[2] * er[0]
                cost = np.where((nl > 0) & (nr > 0), al * nl + ar * nr, np.inf)
            best = np.argmin(cost, axis=0)
            ok = np.isfinite(cost[best, np.arange(Rb)])
            rank = np.arange(len(o)) - per_item(st_i)
            left = np.where(per_item(ok), b <= per_item(best), rank < per_item(nleft[big]))
            nlb = np.add.reduceat(left, st_i, dtype=np.int64)
            csum = np.cumsum(left, dtype=np.int64)
            csum -= left
            rl = csum - per_item(csum[st_i])
            newpos = per_item(ss) + np.where(left, rl, per_item(nlb) + (rank - rl))
            perm[newpos] = ids
            if not boxes_in_item_order:
                for k in range(3):  # (row by row: a scatter several times faster than cmn[:, newpos])
                    cmn[k, newpos] = imn[k]
                    cmx[k, newpos] = imx[k]
            nleft[big] = nlb
        run = (ci_all > max(sah_min, B)) & ~big
        if run.any():
            nleft[run] = _run_split(mnT, mxT, s[inner][run], ci_all[run], B)
        # the next depth in pre-order too: the children of inner node k at 2 k (left), 2 k + 1
        si = s[inner]
        s = np.empty(2 * inner.size, np.int64)
        s[0::2], s[1::2] = si, si + nleft
        c = np.empty(2 * inner.size, np.int64)
        c[0::2], c[1::2] = nleft, ci_all - nleft
        grp = np.repeat(grp[inner], 2)
        lv["kids"] = inner
    checkpoint()
    if boxes_in_item_order and N:
        mnT[:, :N] = np.take(mnT[:, :N], perm, axis=1)
        mxT[:, :N] = np.take(mxT[:, :N], perm, axis=1)
    # subtree sizes, bottom up
    sizes = [None] * len(levels)
    for d in range(len(levels) - 1, -1, -1):
        lv = levels[d]
        sz = np.ones(lv["s"].size, np.int64)
        if "kids" in lv:
            sz[lv["kids"]] = 1 + sizes[d + 1][0::2] + sizes[d + 1][1::2]
        sizes[d] = sz
    checkpoint()
    node_count = np.zeros(G, np.int64)
    depth = np.zeros(G, np.int64)
    if levels:
        node_count[levels[0]["grp"]] = sizes[0]
        for d, lv in enumerate(levels):
            depth[lv["grp"]] = np.maximum(depth[lv["grp"]], d)
    node_start = np.concatenate([[0], np.cumsum(node_count)[:-1]]).astype(np.int64) if G else np.zeros(0, np.int64)
    n_nodes = int(node_count.sum())
    escape = np.zeros(n_nodes, np.int64)
    leaf_start = np.full(n_nodes, -1, np.int64)
    leaf_count = np.zeros(n_nodes, np.int64)
    checkpoint()
    # depth-first (pre-order) index of every node, top down
    dfs = []
    if levels:
        df = node_start[levels[0]["grp"]]
        for d, lv in enumerate(levels):
            dfs.append(df)
            escape[df] = df + sizes[d]
            lf = lv["leaf"]
            leaf_start[df[lf]] = lv["s"][lf]
            leaf_count[df[lf]] = lv["c"][lf]
            if "kids" in lv:
                ldf = df[lv["kids"]] + 1
                df = np.empty(2 * ldf.size, np.int64)
                df[0::2], df[1::2] = ldf, ldf + sizes[d + 1][0::2]
    checkpoint()
    # boxes by component: the leaves (in pre-order they tile the item positions) by one reduceat,
    # then the inner nodes bottom up, one depth at a time from the next (every depth is in
    # pre-order: the reads and writes run forward)
    bmn = np.zeros((3, n_nodes), dt)
    bmx = np.zeros((3, n_nodes), dt)
    leaf_nodes = np.nonzero(leaf_count > 0)[0]
    if leaf_nodes.size:
        ls = leaf_start[leaf_nodes]
        inc = ls.size < 2 or bool((ls[1:] > ls[:-1]).all())
        if not inc:  # groups out of item order
            o = np.argsort(ls, kind="stable")
            leaf_nodes, ls = leaf_nodes[o], ls[o]
        if inc and ls.size == N:  # one item per leaf (ls == arange(N)): the item boxes themselves
            bmn[:, leaf_nodes] = cmn
            bmx[:, leaf_nodes] = cmx
        else:
            bmn[:, leaf_nodes] = np.minimum.reduceat(cmn, ls, axis=1)
            bmx[:, leaf_nodes] = np.maximum.reduceat(cmx, ls, axis=1)
    for d in range(len(levels) - 2, -1, -1):
        lv = levels[d]
        checkpoint()
        if "kids" in lv:
            k = dfs[d][lv["kids"]]
            ch = dfs[d + 1]
            cmn_ = np.take(bmn, ch, axis=1)
            cmx_ = np.take(bmx, ch, axis=1)
            bmn[:, k] = np.minimum(cmn_[:, 0::2], cmn_[:, 1::2])
            bmx[:, k] = np.maximum(cmx_[:, 0::2], cmx_[:, 1::2])
    node_min, node_max = bmn.T, bmx.T  # (Nn, 3) views of the by-component arrays
    return SAHBuild(node_min, node_max, escape, leaf_start, leaf_count, perm, node_start, node_count, depth)


def sah_cost(build: SAHBuild, traverse: float = 1.0, intersect: float = 1.0) -> np.ndarray:
    """The surface-area cost of each tree of ``build`` (trees without nodes left out): the
    expected work of a ray through its root's box, ``traverse`` per inner node and
    ``intersect`` per leaf item visited, each node weighted by its area over the root's."""
    e = np.maximum(np.asarray(build.node_max, np.float64) - np.asarray(build.node_min, np.float64), 0.0)
    area = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    work = np.where(build.leaf_count > 0, intersect * build.leaf_count, traverse) * area
    has = build.node_count > 0
    starts = build.node_start[has]  # (the trees lie back to back)
    if not len(starts):
        return np.zeros(0)
    sums = np.add.reduceat(work, starts)
    return sums / np.maximum(area[starts], 1e-300)
