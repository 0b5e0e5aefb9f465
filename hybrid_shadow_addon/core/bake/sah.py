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


def _area(lo, hi):
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _run_split(cmn, cmx, ss, cc, B) -> np.ndarray:
    """SAH split of each node [ss, ss + cc) between ``B`` equal runs of its current order."""
    order = np.argsort(ss)
    ss, cc = ss[order], cc[order]
    R = ss.size
    j = np.arange(B + 1)
    bnd = ss[:, None] + (j[None, :] * cc[:, None]) // B  # (R, B + 1), strictly increasing
    idx = bnd.reshape(-1)
    pad_mn = np.concatenate([cmn, cmn[:1]])
    pad_mx = np.concatenate([cmx, cmx[:1]])
    lo = np.minimum.reduceat(pad_mn, idx, axis=0).reshape(R, B + 1, 3)[:, :B]
    hi = np.maximum.reduceat(pad_mx, idx, axis=0).reshape(R, B + 1, 3)[:, :B]
    lo = lo.transpose(1, 0, 2)  # (B, R, 3)
    hi = hi.transpose(1, 0, 2)
    llo = np.minimum.accumulate(lo, axis=0)[:-1]
    lhi = np.maximum.accumulate(hi, axis=0)[:-1]
    rlo = np.minimum.accumulate(lo[::-1], axis=0)[::-1][1:]
    rhi = np.maximum.accumulate(hi[::-1], axis=0)[::-1][1:]
    nl = (bnd[:, 1:B] - ss[:, None]).T  # (B - 1, R)
    nr = cc[None, :] - nl
    cost = _area(llo, lhi) * nl + _area(rlo, rhi) * nr
    best = np.argmin(cost, axis=0)
    out = np.empty(R, np.int64)
    out[order] = nl[best, np.arange(R)]
    return out


def build_sah(item_min, item_max, group_start, group_count, leaf_size: int = 4, bins: int = 16,
              sah_min: int = 16, spatial_min: int = 0) -> SAHBuild:
    """Trees, one per group ``g`` over items ``[group_start[g], + group_count[g])``, the items of
    each group in Morton order. Nodes with more than ``spatial_min`` items (0: none) split by
    spatially binned SAH (``bins`` bins along the longest centroid axis, stable partition);
    nodes with more than ``sah_min`` items by SAH over ``bins`` equal runs of their item order
    (the split lies between runs; no reordering); smaller ones at the middle of their order."""
    # item arrays kept in current order; float32 boxes (exact for float32 input) halve the traffic
    dt = np.float32 if np.asarray(item_min).dtype == np.float32 else np.float64
    cmn = np.array(item_min, dt).reshape(-1, 3)
    cmx = np.array(item_max, dt).reshape(-1, 3)
    gs = np.asarray(group_start, np.int64)
    gc = np.asarray(group_count, np.int64)
    G = len(gc)
    N = len(cmn)
    cen = (cmn + cmx) * 0.5
    perm = np.arange(N, dtype=np.int64)
    B = int(bins)
    L = max(1, int(leaf_size))
    levels = []
    has = gc > 0
    s = gs[has].copy()
    c = gc[has].copy()
    grp = np.nonzero(has)[0]
    while s.size:
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
            ce = cen[pos]
            imn, imx = cmn[pos], cmx[pos]
            cmin = np.minimum.reduceat(ce, st_i, axis=0)
            cmax = np.maximum.reduceat(ce, st_i, axis=0)
            ext = cmax - cmin
            axis = np.argmax(ext, axis=1)
            eax = np.max(ext, axis=1)
            ax_o = axis[o]
            ca = np.where(ax_o == 0, ce[:, 0], np.where(ax_o == 1, ce[:, 1], ce[:, 2]))
            c0 = np.where(axis == 0, cmin[:, 0], np.where(axis == 1, cmin[:, 1], cmin[:, 2]))
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(eax > 0, B / np.where(eax > 0, eax, 1.0), 0.0)
            b = np.clip(((ca - c0[o]) * scale[o]).astype(np.int64), 0, B - 1)
            key = b * Rb + o  # bin-major: the prefix scans run over contiguous rows
            cnt = np.bincount(key, minlength=Rb * B).reshape(B, Rb)
            lo = np.full((3, B * Rb), np.inf, dt)
            hi = np.full((3, B * Rb), -np.inf, dt)
            for k in range(3):
                np.minimum.at(lo[k], key, imn[:, k])
                np.maximum.at(hi[k], key, imx[:, k])
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
            rank = np.arange(len(o)) - st_i[o]
            left = np.where(ok[o], b <= best[o], rank < nleft[big][o]).astype(np.int64)
            nlb = np.bincount(o, weights=left, minlength=Rb).astype(np.int64)
            csum = np.cumsum(left) - left
            rl = csum - csum[st_i][o]
            newpos = ss[o] + np.where(left != 0, rl, nlb[o] + (rank - rl))
            perm[newpos] = perm[pos]
            cmn[newpos] = imn
            cmx[newpos] = imx
            cen[newpos] = ce
            nleft[big] = nlb
        run = (ci_all > max(sah_min, B)) & ~big
        if run.any():
            nleft[run] = _run_split(cmn, cmx, s[inner][run], ci_all[run], B)
        si = s[inner]
        s = np.concatenate([si, si + nleft])
        c = np.concatenate([ci_all, ci_all])
        c[: inner.size] = nleft
        c[inner.size:] -= nleft
        grp = np.concatenate([grp[inner], grp[inner]])
        lv["kids"] = inner  # node k of ``inner`` -> children k (left), k + len(inner) (right)
    # leaf boxes: the leaves of all trees tile the item positions
    for lv in levels:
        lv["min"] = np.zeros((lv["s"].size, 3), dt)
        lv["max"] = np.zeros((lv["s"].size, 3), dt)
    if levels:
        ls = np.concatenate([lv["s"][lv["leaf"]] for lv in levels])
        ref = [(d, np.nonzero(lv["leaf"])[0]) for d, lv in enumerate(levels)]
        order = np.argsort(ls, kind="stable")
        if ls.size:
            lmn = np.minimum.reduceat(cmn, ls[order], axis=0)
            lmx = np.maximum.reduceat(cmx, ls[order], axis=0)
            inv = np.empty_like(order)
            inv[order] = np.arange(order.size)
            k0 = 0
            for d, idx in ref:
                sl = inv[k0:k0 + idx.size]
                levels[d]["min"][idx] = lmn[sl]
                levels[d]["max"][idx] = lmx[sl]
                k0 += idx.size
    # inner boxes and subtree sizes, bottom up
    sizes = [None] * len(levels)
    for d in range(len(levels) - 1, -1, -1):
        lv = levels[d]
        sz = np.ones(lv["s"].size, np.int64)
        if "kids" in lv:
            nxt = levels[d + 1]
            m = lv["kids"].size
            sz[lv["kids"]] = 1 + sizes[d + 1][:m] + sizes[d + 1][m:]
            lv["min"][lv["kids"]] = np.minimum(nxt["min"][:m], nxt["min"][m:])
            lv["max"][lv["kids"]] = np.maximum(nxt["max"][:m], nxt["max"][m:])
        sizes[d] = sz
    node_count = np.zeros(G, np.int64)
    depth = np.zeros(G, np.int64)
    if levels:
        node_count[levels[0]["grp"]] = sizes[0]
        for d, lv in enumerate(levels):
            depth[lv["grp"]] = np.maximum(depth[lv["grp"]], d)
    node_start = np.concatenate([[0], np.cumsum(node_count)[:-1]]).astype(np.int64) if G else np.zeros(0, np.int64)
    n_nodes = int(node_count.sum())
    node_min = np.zeros((n_nodes, 3), dt)
    node_max = np.zeros((n_nodes, 3), dt)
    escape = np.zeros(n_nodes, np.int64)
    leaf_start = np.full(n_nodes, -1, np.int64)
    leaf_count = np.zeros(n_nodes, np.int64)
    if levels:
        df = node_start[levels[0]["grp"]]
        for d, lv in enumerate(levels):
            node_min[df] = lv["min"]
            node_max[df] = lv["max"]
            escape[df] = df + sizes[d]
            lf = lv["leaf"]
            leaf_start[df[lf]] = lv["s"][lf]
            leaf_count[df[lf]] = lv["c"][lf]
            if "kids" in lv:
                k = lv["kids"]
                m = k.size
                ldf = df[k] + 1
                rdf = ldf + sizes[d + 1][:m]
                df = np.concatenate([ldf, rdf])
    return SAHBuild(node_min, node_max, escape, leaf_start, leaf_count, perm, node_start, node_count, depth)
