"""The wide layout of the two-level BVH's trees: texture [wide] of ``shaders/common/scene_bvh.glsl``
(``HS_BVH_WIDE``), derived from the binary [node] texels.

Every binary inner node at an even depth of its tree (the root's depth is 0) is a 4-wide node:
its children are its grandchildren, or a child that is a leaf. Its block is the 4 [wide] texels
from ``2 i`` (``i``: its [node] index); two such nodes are never adjacent in [node]'s pre-order,
so the blocks never overlap and [wide] needs no allocator of its own (twice [node]'s texels).
A child texel is its binary node's texel with a different last word: the box words as they are,
then the leaf's word (``LEAF_FLAG | payload``) for a leaf, the [node] index of its own block for
an inner child, 0 for no child (an inner node's index is never 0: node 0 is a root). Children
keep the binary tree's order, so a walk that pops them first to last meets the leaves in the
binary walk's order.

:class:`WideIndex` keeps, per [node] texel of the top level, the [wide] texel that copies it: a
refit copies the changed boxes there; a rebuilt tree packs its blocks again from its root.
"""
from __future__ import annotations

import numpy as np

from .blas import LEAF_FLAG

WIDTH = 4  # children per wide node
STRIDE = 2  # [wide] texels per [node] index: the block of node i starts at texel STRIDE * i


def _texels(a: np.ndarray) -> np.ndarray:
    """(N, 4) uint32 texels as N 16-byte items (a texel gathered or scattered as one)."""
    return np.ascontiguousarray(a).view(np.dtype((np.void, 16))).reshape(-1)


def grandchildren(node: np.ndarray, at: np.ndarray, levels: int = 2) -> np.ndarray:
    """(M, 2**levels) [node] indices of the children ``levels`` binary levels below inner nodes
    ``at`` (-1: none), in tree order; a leaf met before stays as it is."""
    w = node[:, 3]
    leaf = (w & LEAF_FLAG) != 0
    front = np.asarray(at, np.int64)[:, None]
    for _ in range(levels):
        ok = front >= 0
        f = np.where(ok, front, 0)
        is_leaf = leaf[f] | ~ok
        left = np.minimum(f + 1, len(w) - 1)  # (a leaf's: not used)
        right = np.where(leaf[left], left + 1, w[left].astype(np.int64))
        a = np.where(is_leaf, front, left)
        b = np.where(is_leaf, -1, right)
        front = np.stack([a, b], axis=2).reshape(len(front), -1)
    return front


def wide_nodes(node: np.ndarray, roots, ends) -> np.ndarray:
    """The [node] indices of the inner nodes at even depths of the trees at ``[roots[k],
    ends[k])``. A node's depth is how many inner nodes' subtrees ``(i, escape(i))`` hold it: a
    prefix sum of +1 after each inner node and -1 at its escape, over every tree at once."""
    roots = np.asarray(roots, np.int64)
    ends = np.asarray(ends, np.int64)
    if not roots.size:
        return np.zeros(0, np.int64)
    lo, n = int(roots.min()), int(ends.max() - roots.min())
    w = node[lo:lo + n, 3]
    live = np.cumsum(np.bincount(roots - lo, minlength=n + 1) - np.bincount(ends - lo, minlength=n + 1))[:n] > 0
    i = np.flatnonzero(live & ((w & LEAF_FLAG) == 0))
    esc = w[i].astype(np.int64) - lo
    depth = np.cumsum(np.bincount(i + 1, minlength=n + 1) - np.bincount(esc, minlength=n + 1))
    return i[(depth[i] & 1) == 0] + lo


class WideIndex:
    """Where each [node] texel is copied in [wide] (``slot``: -1 where it is not a child)."""

    def __init__(self, capacity: int = 0):
        self.slot = np.full(capacity, -1, np.int64)

    def fit(self, capacity: int) -> None:
        """Room for ``capacity`` [node] texels."""
        if capacity > len(self.slot):
            self.slot = np.concatenate([self.slot, np.full(capacity - len(self.slot), -1, np.int64)])

    def pack(self, node: np.ndarray, wide: np.ndarray, roots, ends, refits: bool = False) -> np.ndarray:
        """Write the blocks of the trees at [node] ``[roots[k], ends[k])`` (``node``, ``wide``:
        the textures' linear texels); with ``refits``, note where each of their texels is copied
        (trees that :meth:`refit` later: the top level; a model tree is rebuilt whole). Returns
        the [wide] texels written."""
        roots = np.asarray(roots, np.int64)
        ends = np.asarray(ends, np.int64)
        if refits:
            for a, b in zip(roots.tolist(), ends.tolist()):
                self.slot[a:b] = -1
        at = wide_nodes(node, roots[ends > roots], ends[ends > roots])
        if not at.size:
            return at
        ch = grandchildren(node, at)
        pos = STRIDE * at[:, None] + np.arange(WIDTH)
        ok = ch >= 0
        c = np.maximum(ch, 0)
        tex = _texels(node)[c].view(np.uint32).reshape(c.shape + (4,))  # (a texel a copy)
        wc = tex[..., 3]
        np.copyto(wc, c.astype(np.uint32), where=(wc & LEAF_FLAG) == 0)  # an inner child: its block
        tex *= ok[..., None]  # (no child: zeros)
        _texels(wide)[pos] = _texels(tex.reshape(-1, 4)).reshape(pos.shape)
        if refits:
            self.slot[ch[ok]] = pos[ok]
        return pos.ravel()

    def refit(self, node: np.ndarray, wide: np.ndarray, changed: np.ndarray) -> np.ndarray:
        """Copy the boxes of [node] texels ``changed`` (their tree's shape unchanged) to their
        [wide] texels. Returns those texels."""
        changed = np.asarray(changed, np.int64)
        s = self.slot[changed]
        ok = s >= 0
        wide[s[ok], 0:3] = node[changed[ok], 0:3]
        return s[ok]
