"""The top level of the two-level BVH: an SAH tree over the casters' world boxes, one caster per
leaf, boxes quantised on one grid over the scene; refitted in place when instances move."""
from __future__ import annotations

import numpy as np

from ..sah import build_sah
from .blas import FRAME_MARGIN, LEAF_FLAG, QMAX, RUN_SAH_MIN, morton_order, pack_nodes, quant_frame, quantise

#: top-level nodes of more instances than this split by spatially binned SAH, smaller ones between
#: runs of their Morton order (above RUN_SAH_MIN) or at its middle
TLAS_SPATIAL_MIN = 2


def tree_depths(left, right) -> np.ndarray:
    """Depth of every node of a tree given by its child indices (-1: leaf), root 0."""
    n = len(left)
    depth = np.zeros(n, np.int64)
    frontier = np.array([0]) if n else np.zeros(0, np.int64)
    d = 0
    while frontier.size:
        depth[frontier] = d
        inner = frontier[left[frontier] >= 0]
        frontier = np.concatenate([left[inner], right[inner]])
        d += 1
    return depth


def box_areas(lo, hi):
    """Half the surface area of each box (the SAH cost measure)."""
    e = np.maximum(hi - lo, 0.0)
    return e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]


class TopLevel:
    """The tree over the member instances: shape (local node indices, depth-first pre-order),
    exact float64 boxes as last refitted, the quantisation frame and where its [node] records
    start. A refit moves leaf boxes and their ancestors only."""

    def __init__(self):
        self.start = 0  # first [node] record
        self.count = 0  # nodes
        self.cap = 0  # [node] records allocated
        self.leaf_inst = np.zeros(0, np.int64)  # instance of each node (-1 inner)
        self.left = np.zeros(0, np.int64)  # child indices (-1 for leaves)
        self.right = np.zeros(0, np.int64)
        self.depth = np.zeros(0, np.int64)
        self.parent = np.zeros(0, np.int64)  # -1 for the root
        self.node_of = np.zeros(0, np.int64)  # (N,) leaf of each member instance, -1 none
        self.lo = np.zeros((0, 3))  # (count, 3) node boxes (exact unions)
        self.hi = np.zeros((0, 3))
        self.areas = np.zeros(0)  # their SAH areas
        self.escape = np.zeros(0, np.int64)  # local
        self.base = np.zeros(3)
        self.inv_s = 1.0
        self.area = 0.0  # SAH area sum at the last build

    def plan(self, member, box_lo, box_hi) -> int:
        """Build the tree over the instances flagged in ``member``: shape, frame, boxes and
        areas (no texels yet). Returns its node count."""
        mem = np.nonzero(member)[0]
        n = mem.size
        if n:
            lo_m, hi_m = box_lo[mem], box_hi[mem]
            c = (lo_m + hi_m) * 0.5
            cmin, cmax = c.min(axis=0), c.max(axis=0)
            q = np.clip((c - cmin) * (1023.0 / np.maximum((cmax - cmin).max(), 1e-30)), 0, 1023).astype(np.uint32)
            mem = mem[morton_order(q)]
            sb = build_sah(box_lo[mem], box_hi[mem], [0], [n], leaf_size=1, bins=16, sah_min=RUN_SAH_MIN,
                           spatial_min=TLAS_SPATIAL_MIN)
            cnt = int(sb.node_count[0])
            lo, hi = sb.node_min[0], sb.node_max[0]  # the root: the exact union of the member boxes
            margin = FRAME_MARGIN * (hi - lo).max()  # room for moves before the frame must change
            base, inv_s = quant_frame(lo - margin, hi + margin)
            self.base, self.inv_s = base[0], float(inv_s[0])
            leaf = sb.leaf_count > 0
            self.leaf_inst = np.where(leaf, mem[sb.perm[np.maximum(sb.leaf_start, 0)]], -1)
            self.escape = sb.escape
            left = np.where(leaf, -1, np.arange(cnt) + 1)
            right = np.where(leaf, -1, sb.escape[np.minimum(np.arange(cnt) + 1, cnt - 1)])
            self.left, self.right = left, right
            self.depth = tree_depths(left, right)
            inner = np.nonzero(~leaf)[0]
            self.parent = np.full(cnt, -1, np.int64)
            self.parent[left[inner]] = inner
            self.parent[right[inner]] = inner
            self.lo, self.hi = sb.node_min, sb.node_max  # the exact unions a refit gives
        else:
            cnt = 0
            self.base, self.inv_s = np.zeros(3), 1.0
            self.leaf_inst = np.zeros(0, np.int64)
            self.escape = self.left = self.right = self.depth = np.zeros(0, np.int64)
            self.parent = np.zeros(0, np.int64)
            self.lo, self.hi = np.zeros((0, 3)), np.zeros((0, 3))
        self.node_of = np.full(len(member), -1, np.int64)
        lf = np.nonzero(self.leaf_inst >= 0)[0]
        self.node_of[self.leaf_inst[lf]] = lf
        self.areas = box_areas(self.lo, self.hi)
        self.area = float(self.areas.sum())
        return cnt

    def refit(self, idx, box_lo, box_hi) -> np.ndarray:
        """Refit after instances ``idx`` got new boxes: their leaves and every ancestor, deepest
        first (the other nodes keep their boxes). Returns the refitted nodes (ascending)."""
        nodes = self.node_of[idx]
        nodes = np.unique(nodes[nodes >= 0])
        if not nodes.size:
            return nodes
        li = self.leaf_inst[nodes]
        self.lo[nodes] = box_lo[li]
        self.hi[nodes] = box_hi[li]
        anc = []
        f = self.parent[nodes]
        f = f[f >= 0]
        while f.size:
            f = np.unique(f)
            anc.append(f)
            f = self.parent[f]
            f = f[f >= 0]
        if anc:
            a = np.unique(np.concatenate(anc))
            dep = self.depth[a]
            o = np.argsort(-dep, kind="stable")
            a, dep = a[o], dep[o]
            for k in np.split(a, np.nonzero(np.diff(dep))[0] + 1):
                lc, rc = self.left[k], self.right[k]
                self.lo[k] = np.minimum(self.lo[lc], self.lo[rc])
                self.hi[k] = np.maximum(self.hi[lc], self.hi[rc])
            nodes = np.union1d(nodes, a)
        self.areas[nodes] = box_areas(self.lo[nodes], self.hi[nodes])
        return nodes

    def degraded(self) -> bool:
        """The refitted boxes' SAH area more than doubled since the build: rebuild."""
        return float(self.areas.sum()) > 2.0 * self.area

    def texels(self, nodes) -> np.ndarray:
        """Packed [node] texels of nodes ``nodes`` (local indices, or a slice)."""
        lo, hi = self.lo[nodes], self.hi[nodes]
        inv = np.full(len(lo), self.inv_s)
        qlo, qhi = quantise(lo, hi, self.base[None, :], inv)
        li = self.leaf_inst[nodes]
        w = np.where(li >= 0, LEAF_FLAG | np.maximum(li, 0).astype(np.uint32),
                     (self.escape[nodes] + self.start).astype(np.uint32))
        return pack_nodes(qlo, qhi, w.astype(np.uint32))

    def write(self, node_texture, nodes=None) -> np.ndarray:
        """Write the texels of nodes ``nodes`` (local, ascending; None: all) into the [node]
        texture; returns the [node] indices whose texels changed."""
        tex = node_texture.linear()
        if nodes is None:
            nodes = slice(0, self.count)
            pos = np.arange(self.start, self.start + self.count)
        else:
            pos = self.start + nodes
        new = self.texels(nodes)
        old = tex[pos]
        tex[pos] = new
        return pos[(old != new).any(axis=1)]

    def holds(self, box_lo, box_hi) -> bool:
        """The boxes fit the quantisation frame (a refit can keep it)."""
        if not self.count:
            return False
        lo = (box_lo - self.base) * self.inv_s
        hi = (box_hi - self.base) * self.inv_s
        return bool((lo >= 0).all() and (hi <= QMAX).all())

    def uniforms(self) -> dict:
        base = np.asarray(self.base, np.float32)
        inv = np.float32(self.inv_s)
        return {
            "hs_tlas_base": base,
            "hs_tlas_inv_scale": float(inv),
            "hs_tlas_babs": float(np.abs(base.astype(np.float64) * float(inv)).sum()),
            "hs_tlas_root": int(self.start),
            "hs_tlas_end": int(self.start + self.count),
        }

    def column_counts(self, xy: np.ndarray) -> np.ndarray:
        """(N,) how many leaf boxes cover each bake-space point ``xy`` (N, 2) in x and y (the
        casters over that vertical column), by a breadth-first walk of the tree."""
        counts = np.zeros(len(xy), np.float64)
        if not self.count:
            return counts
        pt = np.arange(len(xy))
        node = np.zeros(len(xy), np.int64)
        while pt.size:
            p = xy[pt]
            lo, hi = self.lo[node], self.hi[node]
            inside = ((p >= lo[:, :2]) & (p <= hi[:, :2])).all(axis=1)
            pt, node = pt[inside], node[inside]
            leaf = self.left[node] < 0
            np.add.at(counts, pt[leaf], 1.0)
            pt, node = pt[~leaf], node[~leaf]
            pt = np.concatenate([pt, pt])
            node = np.concatenate([self.left[node], self.right[node]])
        return counts
