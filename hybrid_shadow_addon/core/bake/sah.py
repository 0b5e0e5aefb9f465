"""Binned SAH BVH builder, vectorised over every node of a depth (and every tree) at once.

Top down, one numpy pass per depth. Large nodes (``spatial_min``) bin their items' centroids
into ``bins`` bins along the longest axis of their centroid box, evaluate the surface-area cost of
the ``bins - 1`` splits between bins (bin bounds by ``np.minimum.at``) and partition their item
range stably (left items first; all centroids in one bin: count median). Mid-sized nodes
(``sah_min``) evaluate the same cost between ``bins`` equal runs of their current (Morton) order,
which needs no reordering; small ones split that order in the middle. A node with at most
``leaf_size`` items is a leaf. Nodes are numbered in depth-first pre-order per tree (left child
``i + 1``, escape = the node after the subtree), the layout the stackless walks read.

The items are rows of one table (min xyz, id bits, max xyz, 0: 32 or 64 bytes, which ``np.take``
copies as one block). The rows of the spatially split nodes' items travel with them, node after
node: each depth gathers them partitioned (a 16-bit radix sort on each row's child), first those
of the children split spatially again; the other children's items go to their places in
``perm``. Where some node splits between runs of the current order, the table follows the
current order (the rows that drop out are written back), which the run splits read; else it
stays in item order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..progress import checkpoint

_KEY_NODES = 1 << 15  # nodes per 16-bit partition key (two children each)
_LANES = 4  # copies of the bins np.minimum.at updates in turn (a power of two)
_FEW_NODES = 128  # depths of fewer nodes scan their bins by one accumulate call each way
_LANE_ROWS = 4096  # depths of fewer rows: one copy of the bins (see _bin_bounds)


@dataclass
class SAHBuild:
    """Trees over groups of items; indices local to this build."""

    node_min: np.ndarray  # (Nn, 3) exact union of the item boxes (their float type; a view)
    node_max: np.ndarray
    escape: np.ndarray  # (Nn,) int64
    leaf_start: np.ndarray  # (Nn,) position in ``perm`` of the leaf's first item, -1 inner
    leaf_count: np.ndarray  # (Nn,) 0 for inner nodes
    perm: np.ndarray  # (N,) item ids in leaf order (each group's items stay in its range)
    node_start: np.ndarray  # (G,) first node of each tree
    node_count: np.ndarray  # (G,)
    depth: np.ndarray  # (G,)


@dataclass
class _Items:
    """The items being ordered: ``perm`` (position -> item id) and their rows (see the module
    docstring); ``by_item``: the table is in item order, else in the current order."""

    tab: np.ndarray  # (N + 1, 8): min xyz, id bits, max xyz, 0 (a pad row: _run_split's last bound)
    perm: np.ndarray
    by_item: bool


def _excl_cumsum(counts) -> np.ndarray:
    out = np.cumsum(counts)
    out -= counts
    return out


def _ranges(starts, counts) -> np.ndarray:
    """The positions ``starts[i] .. starts[i] + counts[i]``, range after range."""
    n = int(counts.sum())
    return np.arange(n) + np.repeat(starts - _excl_cumsum(counts), counts)


def _area3(lo, hi):
    """Half the surface area of boxes stored by component first: (3, ...) arrays."""
    e = np.maximum(hi - lo, 0.0)
    return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]


def _run_split(tab, ss, cc, B) -> np.ndarray:
    """SAH split of each node [ss, ss + cc) between ``B`` equal runs of its current order
    (``tab``: the item rows in that order, with the pad row: the last bound may be N)."""
    order = np.argsort(ss)
    ss, cc = ss[order], cc[order]
    R = ss.size
    j = np.arange(B + 1)
    bnd = ss[:, None] + (j[None, :] * cc[:, None]) // B  # (R, B + 1), strictly increasing
    idx = bnd.reshape(-1)
    lo = np.minimum.reduceat(tab[:, 0:3], idx, axis=0).reshape(R, B + 1, 3)[:, :B].transpose(2, 1, 0)  # (3, B, R)
    hi = np.maximum.reduceat(tab[:, 4:7], idx, axis=0).reshape(R, B + 1, 3)[:, :B].transpose(2, 1, 0)
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


def _scans(v, op):
    """Prefix and suffix ``op`` over the bins (axis 1) of ``v`` (3, B, R): ``pre[:, k]`` over
    bins ``0..k``, ``suf[:, k]`` over bins ``k + 1..`` (k < B - 1), accumulated in bin order:
    ``op.accumulate`` for few nodes, else one call per bin (an accumulate along the middle axis
    of a large array is slow)."""
    if v.shape[2] < _FEW_NODES:
        return op.accumulate(v, axis=1)[:, :-1], op.accumulate(v[:, ::-1], axis=1)[:, ::-1][:, 1:]
    B = v.shape[1]
    pre = np.empty((3, B - 1, v.shape[2]), v.dtype)
    suf = np.empty_like(pre)
    pre[:, 0] = v[:, 0]
    for k in range(1, B - 1):
        op(pre[:, k - 1], v[:, k], out=pre[:, k])
    suf[:, B - 2] = v[:, B - 1]
    for k in range(B - 3, -1, -1):
        op(suf[:, k + 1], v[:, k + 1], out=suf[:, k])
    return pre, suf


def _best_bin_split(lo, hi, cnt, ci):
    """The cheapest split between bins of each node (``lo`` / ``hi``: (3, B, R) bin bounds,
    ``cnt``: (B, R) items per bin, ``ci``: (R,) items per node): the last left bin, whether both
    sides hold items (else the split is unusable) and the left count."""
    llo, rlo = _scans(lo, np.minimum)
    lhi, rhi = _scans(hi, np.maximum)
    nl = np.cumsum(cnt, axis=0)[:-1]
    nr = ci[None, :] - nl
    el = np.maximum(lhi - llo, 0.0)
    er = np.maximum(rhi - rlo, 0.0)
    al = el[0] * el[1] + el[1] * el[2] + el[2] * el[0]
    ar = er[0] * er[1] + er[1] * er[2] + er[2] * er[0]
    cost = np.where((nl > 0) & (nr > 0), al * nl + ar * nr, np.inf)
    best = np.argmin(cost, axis=0)
    r = np.arange(ci.size)
    return best, np.isfinite(cost[best, r]), nl[best, r]


def _spatial_split(items: _Items, rows, ss, ci, nmid, B, keep_min):
    """Split nodes ``[ss, ss + ci)`` (``rows``: their items' rows, node after node) by spatially
    binned SAH (a count split at ``nmid`` where all centroids share a bin) and partition each
    node's items stably, left items first. Children of more than ``keep_min`` items stay in the
    returned rows (in order: the next depth's spatially split nodes); the others' items go to
    their places in ``perm``. Returns the left counts and those rows (None: none stay)."""
    R = ss.size
    first = _excl_cumsum(ci)  # each node's first row
    key = _bin_keys(rows, ci, first, B)
    cnt = np.bincount(key, minlength=B * R).reshape(B, R)
    lo, hi = _bin_bounds(rows, key, B * R)
    best, ok, nl = _best_bin_split(lo.reshape(3, B, R), hi.reshape(3, B, R), cnt, ci)
    bad = np.nonzero(~ok)[0]  # a count split: the first nmid items
    nl[bad] = nmid[bad]
    cc = np.empty(2 * R, np.int64)  # the children: left and right of node 0, of node 1, ...
    cc[0::2], cc[1::2] = nl, ci - nl
    keep = cc > keep_min
    rank = _child_ranks(keep)
    right = np.arange(B)[:, None] > best  # (B, R): the bins right of the split
    child = np.take(rank[2 * np.arange(R) + right].astype(np.uint16), key)  # of each item
    if bad.size:
        child[_ranges(first[bad], ci[bad])] = np.repeat(rank[2 * bad + 1], ci[bad])
        child[_ranges(first[bad], nmid[bad])] = np.repeat(rank[2 * bad], nmid[bad])
    kept, src = _child_order(child, ci, cc, keep)
    if src.size:  # the items of the children left behind: to their places in perm (and tab)
        gone = ~keep
        cs = np.empty(2 * R, np.int64)
        cs[0::2], cs[1::2] = ss, ss + nl
        dst = _ranges(cs[gone], cc[gone])
        items.perm[dst] = _ids(rows)[src]
        if not items.by_item:
            items.tab[dst] = rows[src]
    return nl, (np.take(rows, kept, axis=0) if kept.size else None)


def _bin_bounds(rows, key, m):
    """The box of the items in each of ``m`` bins (``key``: each row's bin): (3, m) min and max.
    ``np.minimum.at`` into ``_LANES`` copies of the bins, row ``j`` into copy ``j % _LANES`` (the
    rows of a node mostly share a bin: one copy would chain every update on the one before);
    the min of a bin does not depend on the order (at most on a zero's sign, which no cost sees).
    Few rows: one copy."""
    lanes = _LANES if key.size >= _LANE_ROWS else 1
    if lanes > 1:
        key = (np.arange(key.size) & (lanes - 1)) * m + key
    lo = np.full((3, lanes * m), np.inf, rows.dtype)
    hi = np.full((3, lanes * m), -np.inf, rows.dtype)
    for k in range(3):
        np.minimum.at(lo[k], key, rows[:, k])
        np.maximum.at(hi[k], key, rows[:, 4 + k])
    if lanes == 1:
        return lo, hi
    return np.min(lo.reshape(3, lanes, m), axis=1), np.max(hi.reshape(3, lanes, m), axis=1)


def _bin_keys(rows, ci, first, B) -> np.ndarray:
    """The bin of each item times the node count plus its node (bin-major: the scans over bins
    run over contiguous rows; ``rows``: nodes of ``ci`` items back to back, from ``first``):
    ``B`` equal bins over its node's centroid box along that box's longest axis."""
    R = ci.size
    n = rows.shape[0]
    dt = rows.dtype
    ce = np.empty((3, n), dt)  # twice the centroids (the bins are the same)
    cmin = np.empty((3, R), dt)
    cmax = np.empty((3, R), dt)
    for k in range(3):
        np.add(rows[:, k], rows[:, 4 + k], out=ce[k])
        np.minimum.reduceat(ce[k], first, out=cmin[k])
        np.maximum.reduceat(ce[k], first, out=cmax[k])
    ext = cmax - cmin
    axis = np.argmax(ext, axis=0)
    eax = np.max(ext, axis=0)
    c0 = cmin[axis, np.arange(R)]
    scale = np.where(eax > 0, B / np.where(eax > 0, eax, 1.0), 0.0)
    at = np.arange(n)
    at += np.repeat(axis * n, ci)
    t = np.take(ce.reshape(-1), at)  # each item's centroid on its node's axis
    t -= np.repeat(c0, ci)
    t *= np.repeat(scale, ci)
    b = t.astype(np.int64)
    np.clip(b, 0, B - 1, out=b)
    b *= R
    b += np.repeat(np.arange(R), ci)
    return b


def _ids(rows) -> np.ndarray:
    """The item ids of ``rows`` (the bits of column 3)."""
    return rows[:, 3].view(np.int32 if rows.dtype == np.float32 else np.int64)


def _child_ranks(keep) -> np.ndarray:
    """Each child's place in the 16-bit partition keys: in its run of ``_KEY_NODES`` nodes, the
    children flagged in ``keep`` first (in order), then the others."""
    rank = np.empty(keep.size, np.int64)
    step = 2 * _KEY_NODES
    for a in range(0, keep.size, step):
        k = keep[a:a + step]
        r = rank[a:a + step]
        nk = int(k.sum())
        r[k] = np.arange(nk)
        r[~k] = np.arange(nk, k.size)
    return rank


def _child_order(child, ci, cc, keep):
    """The rows of the children (nodes of ``ci`` rows back to back, ``child``: the 16-bit key of
    each row's child, :func:`_child_ranks`; children of ``cc`` rows), stably: those of the
    children flagged in ``keep`` (child after child), and those of the others. A radix sort
    (numpy's stable sort of 16-bit ints) per run of ``_KEY_NODES`` nodes."""
    kept, gone = [], []
    base = 0
    for a in range(0, ci.size, _KEY_NODES):
        z = min(ci.size, a + _KEY_NODES)
        m = int(ci[a:z].sum())
        o = np.argsort(child[base:base + m], kind="stable")
        if base:
            o += base
        mk = int(cc[2 * a:2 * z][keep[2 * a:2 * z]].sum())
        kept.append(o[:mk])
        gone.append(o[mk:])
        base += m
    if len(kept) == 1:
        return kept[0], gone[0]
    return np.concatenate(kept), np.concatenate(gone)


def _items(item_min, item_max, spatial_min, sah_min, B) -> _Items:
    """The item rows in item order (float32 boxes stay float32: exact, and half the traffic)."""
    dt = np.float32 if np.asarray(item_min).dtype == np.float32 else np.float64
    imin = np.asarray(item_min, dt).reshape(-1, 3)
    imax = np.asarray(item_max, dt).reshape(-1, 3)
    N = len(imin)
    tab = np.empty((N + 1, 8), dt)
    tab[:N, 0:3] = imin
    tab[:N, 4:7] = imax
    _ids(tab)[:N] = np.arange(N)
    tab[:N, 7] = 0
    tab[N] = 0
    # where no node splits between runs of the current order, the table stays in item order
    # (read through perm)
    by_item = 0 < spatial_min <= max(sah_min, B)
    return _Items(tab, np.arange(N, dtype=np.int64), by_item)


def _split_levels(items: _Items, gs, gc, L, B, sah_min, spatial_min) -> list:
    """The nodes of every depth, top down: dicts of ``s`` / ``c`` (item range), ``grp`` (tree),
    ``leaf`` and, where some split, ``kids`` (the inner nodes, whose children are the next
    depth's nodes ``2 k`` and ``2 k + 1``); ``items`` ends in leaf order."""
    levels = []
    has = gc > 0
    s = gs[has].copy()
    c = gc[has].copy()
    grp = np.nonzero(has)[0]
    act = None  # the rows of the spatially split nodes' items (their tables still in item order)
    while s.size:
        checkpoint()
        leaf = c <= L
        lv = {"s": s, "c": c, "grp": grp, "leaf": leaf}
        levels.append(lv)
        inner = np.nonzero(~leaf)[0]
        if not inner.size:
            break
        si = s[inner]
        ci = c[inner]
        nleft = L * ((-(-ci // L) + 1) // 2)
        big = ci > spatial_min if spatial_min > 0 else np.zeros(ci.size, bool)
        if big.any():
            if act is None:  # the first depth with such nodes: their rows as they lie
                act = np.take(items.tab, _ranges(si[big], ci[big]), axis=0)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # (empty bins, boxes of inf)
                nleft[big], act = _spatial_split(items, act, si[big], ci[big], nleft[big], B, max(spatial_min, L))
        run = (ci > max(sah_min, B)) & ~big
        if run.any():
            nleft[run] = _run_split(items.tab, si[run], ci[run], B)
        # the next depth in pre-order too: the children of inner node k at 2 k (left), 2 k + 1
        s = np.empty(2 * inner.size, np.int64)
        s[0::2], s[1::2] = si, si + nleft
        c = np.empty(2 * inner.size, np.int64)
        c[0::2], c[1::2] = nleft, ci - nleft
        grp = np.repeat(grp[inner], 2)
        lv["kids"] = inner
    return levels


def build_sah(item_min, item_max, group_start, group_count, leaf_size: int = 4, bins: int = 16,
              sah_min: int = 16, spatial_min: int = 0) -> SAHBuild:
    """Trees, one per group ``g`` over items ``[group_start[g], + group_count[g])``, the items of
    each group in Morton order. Nodes with more than ``spatial_min`` items (0: none) split by
    spatially binned SAH (``bins`` bins along the longest centroid axis, stable partition);
    nodes with more than ``sah_min`` items by SAH over ``bins`` equal runs of their item order
    (the split lies between runs; no reordering); smaller ones at the middle of their order."""
    B = int(bins)
    items = _items(item_min, item_max, spatial_min, sah_min, B)
    gs = np.asarray(group_start, np.int64)
    gc = np.asarray(group_count, np.int64)
    levels = _split_levels(items, gs, gc, max(1, int(leaf_size)), B, sah_min, spatial_min)
    checkpoint()
    tree = _layout(levels, len(gc))
    checkpoint()
    node_min, node_max = _node_boxes(levels, tree.pop("dfs"), items, tree["leaf_start"], tree["leaf_count"])
    return SAHBuild(node_min, node_max, perm=items.perm, **tree)


def _layout(levels, G) -> dict:
    """The depth-first pre-order numbering of the nodes of ``levels`` (trees back to back in
    group order): escape, leaf_start, leaf_count per node, node_start, node_count, depth per
    tree, and ``dfs``: each depth's nodes' numbers."""
    sizes = [None] * len(levels)  # subtree sizes, bottom up
    for d in range(len(levels) - 1, -1, -1):
        lv = levels[d]
        sz = np.ones(lv["s"].size, np.int64)
        if "kids" in lv:
            nxt = sizes[d + 1]
            sz[lv["kids"]] = 1 + nxt[0::2] + nxt[1::2]
        sizes[d] = sz
    node_count = np.zeros(G, np.int64)
    depth = np.zeros(G, np.int64)
    if levels:
        node_count[levels[0]["grp"]] = sizes[0]
        for d, lv in enumerate(levels):  # (the deepest depth a tree reaches is written last)
            depth[lv["grp"]] = d
    node_start = _excl_cumsum(node_count)
    n_nodes = int(node_count.sum())
    escape = np.empty(n_nodes, np.int64)
    leaf_start = np.full(n_nodes, -1, np.int64)
    leaf_count = np.zeros(n_nodes, np.int64)
    dfs = []
    if levels:
        df = node_start[levels[0]["grp"]]
        for d, lv in enumerate(levels):
            checkpoint()
            dfs.append(df)
            escape[df] = df + sizes[d]
            lf = lv["leaf"]
            at = df[lf]
            leaf_start[at] = lv["s"][lf]
            leaf_count[at] = lv["c"][lf]
            if "kids" in lv:
                ldf = df[lv["kids"]] + 1
                df = np.empty(2 * ldf.size, np.int64)
                df[0::2], df[1::2] = ldf, ldf + sizes[d + 1][0::2]
    return {"escape": escape, "leaf_start": leaf_start, "leaf_count": leaf_count, "node_start": node_start,
            "node_count": node_count, "depth": depth, "dfs": dfs}


def _node_boxes(levels, dfs, items: _Items, leaf_start, leaf_count):
    """Node boxes, (Nn, 3) min and max, in rows like the items' (min xyz, 0, max xyz, 0): each
    node first the box at its first item (the leaves' boxes: one item, or a reduceat over the
    leaf, as in pre-order the leaves tile the item positions), then the inner nodes bottom up,
    one depth at a time from the next (every depth is in pre-order: the reads and writes run
    forward)."""
    first = np.maximum(leaf_start, 0)  # (inner nodes: 0, overwritten below)
    if np.count_nonzero(leaf_count) < items.perm.size:  # leaves of several items
        N = items.perm.size
        rows = np.take(items.tab, items.perm, axis=0) if items.by_item else items.tab[:N]  # leaf order
        nb = np.take(_leaf_rows(rows, leaf_start, leaf_count), first, axis=0)
    else:  # one item per leaf: the item rows themselves
        if items.by_item:
            np.take(items.perm, first, out=first, mode="clip")
        nb = np.take(items.tab, first, axis=0)
    nb[:, 3] = 0  # (the id bits)
    whole = nb.view(np.dtype((np.void, nb.strides[0]))).reshape(-1)  # a node row as one item
    for d in range(len(levels) - 2, -1, -1):
        lv = levels[d]
        checkpoint()
        if "kids" in lv:
            ch = dfs[d + 1]
            x = np.take(nb, ch[0::2], axis=0)
            y = np.take(nb, ch[1::2], axis=0)
            box = np.minimum(x, y)
            _halves(box)[:] = _halves(np.maximum(x, y))
            np.put(whole, dfs[d][lv["kids"]], box.view(whole.dtype).reshape(-1))
    return nb[:, 0:3], nb[:, 4:7]


def _halves(a) -> np.ndarray:
    """The (max xyz, -) halves of rows ``a`` (R, 8), as complex128 items (a copy of 16-byte items
    is the fastest)."""
    return a.view(np.complex128).reshape(len(a), 2, a.itemsize // 4)[:, 1]


def _leaf_rows(rows, leaf_start, leaf_count) -> np.ndarray:
    """``rows`` with the box of each leaf of several items at its first item's place (a reduceat
    from each leaf's start to the next's)."""
    ls = np.sort(leaf_start[leaf_count > 0])
    if not ls.size:
        return rows
    out = rows.copy()
    lo = np.minimum.reduceat(rows, ls, axis=0)
    _halves(lo)[:] = _halves(np.maximum.reduceat(rows, ls, axis=0))
    out[ls] = lo
    return out


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
