"""Per-model BVHs, built once per model in model space, vectorised over all models at once.

Build (an LBVH variant): triangles of each model are sorted by the 30-bit Morton code of their
centroid (normalised to the model's centroid box); leaves are runs of ``leaf_size`` consecutive
triangles in that order; the tree over a model's ``L`` leaves is the balanced binary tree that
splits a leaf range ``[a, b)`` at ``a + ceil((b - a) / 2)`` (depth ``ceil(log2 L)``). Every level
of every model is processed by one set of numpy operations (no per-node Python).

Flattening: nodes in depth-first (pre-)order, so the left child of node ``i`` is ``i + 1``; each
node stores its *escape* index ``i + 2 * leaves(i) - 1`` (the node after its subtree). The GPU
walks it stackless (see ``hs_bvh_occluded`` in scene_grid.glsl): box hit -> ``i + 1`` (or test the
leaf's triangles, then escape), box miss -> escape.

Triangles are stored de-indexed (3 vertices per triangle, leaf order). Boxes are rounded outward
in float32 and enlarged by ``REL_EPS`` so rounding in the slab test never culls a hit the triangle
test would find.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..progress import checkpoint
from .textures import REL_EPS


@dataclass
class BVHBuild:
    """Packed BVHs of a list of models (node / triangle indices local to this build)."""

    node_min: np.ndarray  # (Nn, 3) float32
    node_max: np.ndarray  # (Nn, 3) float32
    escape: np.ndarray  # (Nn,) int64, local node index
    leaf_start: np.ndarray  # (Nn,) int64 local triangle index (leaves), -1 for inner nodes
    leaf_count: np.ndarray  # (Nn,) int64 (0 for inner nodes)
    tris: np.ndarray  # (Nt, 3, 3) float32, leaf order
    tri_src: np.ndarray  # (Nt,) int64 original triangle index within its model
    node_start: np.ndarray  # (M,) int64 per model
    node_count: np.ndarray  # (M,)
    tri_start: np.ndarray  # (M,)
    tri_count: np.ndarray  # (M,)
    depth: np.ndarray  # (M,) tree depth per model


def _morton3(q: np.ndarray) -> np.ndarray:
    """30-bit Morton codes of (N, 3) integer coordinates in [0, 1023]."""
    def spread(v):
        v = v.astype(np.uint32) & np.uint32(0x3FF)
        v = (v | (v << np.uint32(16))) & np.uint32(0x030000FF)
        v = (v | (v << np.uint32(8))) & np.uint32(0x0300F00F)
        v = (v | (v << np.uint32(4))) & np.uint32(0x030C30C3)
        v = (v | (v << np.uint32(2))) & np.uint32(0x09249249)
        return v
    return (spread(q[:, 0]) << np.uint32(2)) | (spread(q[:, 1]) << np.uint32(1)) | spread(q[:, 2])


def _segment_reduce(fn, values, starts, counts, fill):
    """fn.reduceat over segments that may be empty (empty -> fill)."""
    out = np.full((len(starts),) + values.shape[1:], fill, values.dtype)
    nz = counts > 0
    if nz.any() and len(values):
        out[nz] = fn.reduceat(values, starts[nz], axis=0)
    return out


def build_bvhs(models, leaf_size: int = 4) -> BVHBuild:
    """Build the BVHs of ``models`` (a list of :class:`Model`) in one vectorised pass."""
    m_count = len(models)
    tri_count = np.array([m.triangle_count for m in models], np.int64)
    tri_start = np.concatenate([[0], np.cumsum(tri_count)[:-1]]).astype(np.int64) if m_count else np.zeros(0, np.int64)
    total = int(tri_count.sum())
    # --- Morton order within each model (per model: sorts of ~T elements are cheap) ---------
    tris = np.empty((total, 3, 3), np.float32)
    tri_src = np.empty(total, np.int64)
    third = np.float32(1.0 / 3.0)
    for m, s0 in zip(models, tri_start.tolist()):
        checkpoint()
        T = m.triangle_count
        if not T:
            continue
        tr = m.vertices.take(m.triangles.ravel(), axis=0).reshape(T, 3, 3)
        checkpoint()
        cen = (tr[:, 0] + tr[:, 1] + tr[:, 2]) * third
        cmin = np.array([cen[:, k].min() for k in range(3)], np.float32)
        cmax = np.array([cen[:, k].max() for k in range(3)], np.float32)
        span = np.maximum(cmax - cmin, np.float32(1e-30))
        q = np.clip((cen - cmin) * (np.float32(1023.0) / span), 0, 1023).astype(np.uint32)
        checkpoint()
        order = np.argsort(_morton3(q), kind="stable")
        checkpoint()
        tris[s0:s0 + T] = tr.reshape(T, 9).take(order, axis=0).reshape(T, 3, 3)
        tri_src[s0:s0 + T] = order

    tmin = np.minimum(np.minimum(tris[:, 0], tris[:, 1]), tris[:, 2])
    tmax = np.maximum(np.maximum(tris[:, 0], tris[:, 1]), tris[:, 2])
    node_min, node_max, escape, leaf_start, leaf_count, node_start, node_count, depth = build_trees(
        tmin, tmax, tri_start, tri_count, leaf_size)

    return BVHBuild(node_min, node_max, escape, leaf_start, leaf_count, tris, tri_src,
                    node_start, node_count, tri_start, tri_count, depth)


def build_trees(item_min, item_max, item_start, item_count, leaf_size: int):
    """Balanced stackless BVHs over groups of items already in their final (e.g. Morton) order.

    ``item_min`` / ``item_max`` (N, 3) float32 item boxes; group ``g`` owns items
    ``[item_start[g], item_start[g] + item_count[g])``. Leaves are runs of ``leaf_size``
    consecutive items; nodes are in depth-first order per group (escape indices, see the module
    doc). Returns ``node_min, node_max, escape, leaf_start, leaf_count, node_start, node_count,
    depth`` (indices local to this build; leaf_start indexes items). One numpy pass per depth.
    """
    item_count = np.asarray(item_count, np.int64)
    item_start = np.asarray(item_start, np.int64)
    m_count = len(item_count)
    # --- leaves ----------------------------------------------------------------------------
    leaves = -(-item_count // leaf_size)  # per model
    leaf_off = np.concatenate([[0], np.cumsum(leaves)[:-1]]).astype(np.int64) if m_count else np.zeros(0, np.int64)
    n_leaves = int(leaves.sum())
    model_of_leaf = np.repeat(np.arange(m_count, dtype=np.int64), leaves)
    j = np.arange(n_leaves, dtype=np.int64) - leaf_off[model_of_leaf]
    leaf_item0 = item_start[model_of_leaf] + j * leaf_size
    leaf_icnt = np.minimum(leaf_size, item_count[model_of_leaf] - j * leaf_size)
    leaf_min = _segment_reduce(np.minimum, item_min, leaf_item0, leaf_icnt, 0.0)
    leaf_max = _segment_reduce(np.maximum, item_max, leaf_item0, leaf_icnt, 0.0)

    # --- nodes: top-down, one numpy pass per depth ----------------------------------------
    node_count = np.where(leaves > 0, 2 * leaves - 1, 0)
    node_start = (np.concatenate([[0], np.cumsum(node_count)[:-1]]).astype(np.int64) if m_count
                  else np.zeros(0, np.int64))
    n_nodes = int(node_count.sum())
    escape = np.zeros(n_nodes, np.int64)
    leaf_start = np.full(n_nodes, -1, np.int64)
    leaf_count = np.zeros(n_nodes, np.int64)
    depth = np.ceil(np.log2(np.maximum(leaves, 1))).astype(np.int64)
    has = leaves > 0
    a = leaf_off[has]
    b = a + leaves[has]
    df = node_start[has]
    mod = np.nonzero(has)[0]
    inner_levels = []
    level = 0
    while a.size:
        checkpoint()
        k = b - a
        escape[df] = df + 2 * k - 1
        is_leaf = k == 1
        if is_leaf.any():
            lf = a[is_leaf]
            leaf_start[df[is_leaf]] = leaf_item0[lf]
            leaf_count[df[is_leaf]] = leaf_icnt[lf]
        inner = ~is_leaf
        a, b, df, k, mod = a[inner], b[inner], df[inner], k[inner], mod[inner]
        mid = a + (k + 1) // 2
        l_df = df + 1
        r_df = df + 2 * (mid - a)
        inner_levels.append((df, a, b))
        a = np.concatenate([a, mid])
        b = np.concatenate([mid, b])
        df = np.concatenate([l_df, r_df])
        mod = np.concatenate([mod, mod])
        level += 1

    # boxes: a node's box is the union of its leaf range [a, b); the ranges of one depth are
    # disjoint, so one reduceat over the leaf boxes per depth (no dependency between depths)
    box6 = np.empty((n_nodes, 6), np.float32)  # (min, -max): one np.minimum does both
    leaf6 = np.concatenate([leaf_min, -leaf_max], axis=1)
    leaf_nodes = np.nonzero(leaf_count > 0)[0]  # depth-first order == leaf order
    box6[leaf_nodes] = leaf6
    if n_leaves:
        leaf6p = np.concatenate([leaf6, leaf6[:1]])
        for df, a_, b_ in inner_levels:
            checkpoint()
            o = np.argsort(a_)
            ab = np.empty(2 * len(o), np.int64)
            ab[0::2], ab[1::2] = a_[o], b_[o]
            box6[df[o]] = np.minimum.reduceat(leaf6p, ab)[0::2]
    # conservative enlargement: pad >= 2^-20 * (|lo| + |hi| + extent) >> float32 rounding
    lo, hi = box6[:, :3], -box6[:, 3:]
    pad = (np.abs(lo) + np.abs(hi) + (hi - lo)) * np.float32(REL_EPS) + np.float32(1e-30)
    node_min = lo - pad
    node_max = hi + pad

    return node_min, node_max, escape, leaf_start, leaf_count, node_start, node_count.astype(np.int64), depth


def morton_order_groups(centers: np.ndarray, group_start: np.ndarray, group_count: np.ndarray) -> np.ndarray:
    """Permutation putting the points of each contiguous group in Morton order of their centres
    (normalised to the cube over the group's own centre box); groups keep their place. Fully
    vectorised."""
    n = len(centers)
    group_count = np.asarray(group_count, np.int64)
    if n == 0:
        return np.zeros(0, np.int64)
    gid = np.repeat(np.arange(len(group_count), dtype=np.int64), group_count)
    starts = np.asarray(group_start, np.int64)
    nz = group_count > 0
    gmin = np.zeros((len(group_count), 3))
    gmax = np.zeros((len(group_count), 3))
    gmin[nz] = np.minimum.reduceat(centers, starts[nz], axis=0)
    gmax[nz] = np.maximum.reduceat(centers, starts[nz], axis=0)
    # one scale for all three axes (the group's largest extent): a flat crowd keeps square cells
    # instead of stretching its thin axis over all 10 bits
    span = np.maximum((gmax - gmin).max(axis=1, keepdims=True), 1e-300)
    q = np.clip((centers - gmin[gid]) * (1023.0 / span[gid]), 0, 1023).astype(np.uint32)
    key = (gid << np.int64(30)) | _morton3(q).astype(np.int64)
    return np.argsort(key, kind="stable")
