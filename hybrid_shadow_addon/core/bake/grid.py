"""Hierarchical 2D grid over the ground plane (Blender X/Y; height is Z).

Level ``l`` has square nodes of size ``base * 2**l`` over the same rectangle (origin ``origin``);
the top level is a single node covering the whole rectangle. Each shadow caster goes to the lowest
level whose node fully holds its world bounding sphere *with a margin* (``MARGIN_CELLS`` of the
node size plus a relative epsilon), so a sphere touching or crossing a node border moves up, and
float32 rounding in the GPU's DDA can never put a hit point in a neighbouring node.

All nodes of all levels are numbered globally (level ``l`` starts at ``level_offset[l]``, node
``(ix, iy)`` is ``level_offset[l] + iy * nx + ix``); one extra node, ``outside_node`` (the last),
holds casters whose sphere is not inside the grid rectangle (only possible after incremental
moves); every ray tests it. Node contents are ``(offset, count)`` into a packed index list
(``grid_index`` texture) with per-node spare capacity for incremental updates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .textures import REL_EPS, f32_down, f32_up

MARGIN_CELLS = 2.0 ** -8  # sphere must be this fraction of a node size inside the node


@dataclass
class GridLayout:
    origin: np.ndarray  # (2,) float64 (float32-exact)
    base_size: float  # float32-exact
    levels: int
    dims: np.ndarray  # (L, 2) int64: nodes in x, y per level
    level_offset: np.ndarray  # (L,) int64
    n_nodes: int  # including the outside node

    @property
    def node_sizes(self) -> np.ndarray:
        return self.base_size * (2.0 ** np.arange(self.levels))

    @property
    def outside_node(self) -> int:
        return self.n_nodes - 1

    def node_level(self, nodes: np.ndarray) -> np.ndarray:
        """Level of each global node id (``levels`` for the outside node)."""
        return np.searchsorted(self.level_offset, nodes, side="right") - 1 + (np.asarray(nodes) == self.outside_node)

    def nodes_at(self, xy: np.ndarray) -> np.ndarray:
        """Global node id of the node of each level that contains each point, (levels, N) int64;
        -1 where the point lies outside that level's rectangle (or is not finite).

        ``xy``: (N, 2) positions in the space the layout was planned in (bake space: world minus
        ``BakedScene.origin``), not relative to the layout origin. Same floor arithmetic as
        :func:`place` (a point is a sphere of radius zero, without the margin).
        """
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        px = xy[:, 0] - self.origin[0]
        py = xy[:, 1] - self.origin[1]
        out = np.full((self.levels, len(xy)), -1, np.int64)
        for lvl, s in enumerate(self.node_sizes):
            nx, ny = (int(v) for v in self.dims[lvl])
            ix = np.floor(px / s)
            iy = np.floor(py / s)
            inside = (ix >= 0) & (iy >= 0) & (ix < nx) & (iy < ny)
            out[lvl, inside] = (self.level_offset[lvl] + iy[inside].astype(np.int64) * nx
                                + ix[inside].astype(np.int64))
        return out


def plan_grid(centers: np.ndarray, radii: np.ndarray, base_node_size=None, max_level0_nodes=None,
              max_dim: int = 16384) -> GridLayout:
    """Fit the grid rectangle and node size to the casters' spheres (``centers`` (N,3), ``radii``)."""
    n = len(radii)
    if n == 0:
        return GridLayout(np.zeros(2), 1.0, 1, np.ones((1, 2), np.int64), np.zeros(1, np.int64), 2)
    lo = (centers[:, :2] - radii[:, None]).min(axis=0)
    hi = (centers[:, :2] + radii[:, None]).max(axis=0)
    ext = hi - lo
    big = float(np.abs(np.concatenate([lo, hi])).max())
    e = float(ext.max())
    pad = e / 64.0 + 1e-6 * (1.0 + big)
    origin = f32_down(lo - pad).astype(np.float64)  # float32-exact: the GPU sees the same grid
    size = (hi + pad) - origin  # rectangle extent per axis
    emax = float(size.max())
    if max_level0_nodes is None:
        max_level0_nodes = min(max(64, 4 * n), 1 << 22)
    if base_node_size is None:
        d_med = float(np.median(2.0 * radii))
        area = float(max(size[0], 1e-12) * max(size[1], 1e-12))
        base = max(2.0 * d_med, np.sqrt(area / n))
    else:
        base = float(base_node_size)
    base = max(base, emax * 2.0 ** -14, 1e-9)
    while (np.ceil(size / base).prod() > max_level0_nodes) or (np.ceil(size / base).max() > max_dim):
        base *= 2.0
    base = float(f32_up(base))
    levels = 1
    while base * 2.0 ** (levels - 1) < emax * (1.0 + 2.0 ** -6):
        levels += 1
    sizes = base * 2.0 ** np.arange(levels)
    dims = np.maximum(1, np.ceil(size[None, :] / sizes[:, None])).astype(np.int64)
    counts = dims.prod(axis=1)
    level_offset = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return GridLayout(origin, base, levels, dims, level_offset, int(counts.sum()) + 1)


def place(layout: GridLayout, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Global node id of each sphere: the lowest level whose node holds it (with the margin);
    ``outside_node`` when no node does."""
    n = len(radii)
    node = np.full(n, layout.outside_node, np.int64)
    if n == 0:
        return node
    px = centers[:, 0] - layout.origin[0]
    py = centers[:, 1] - layout.origin[1]
    absm = REL_EPS * (np.abs(centers[:, 0]) + np.abs(centers[:, 1]) + np.abs(layout.origin).sum())
    r = radii * (1.0 + REL_EPS) + absm
    todo = np.isfinite(px) & np.isfinite(py) & np.isfinite(r)
    idx = np.nonzero(todo)[0]
    px, py, r = px[idx], py[idx], r[idx]
    for lvl, s in enumerate(layout.node_sizes):
        if idx.size == 0:
            break
        m = r + s * MARGIN_CELLS
        x0 = np.floor((px - m) / s)
        x1 = np.floor((px + m) / s)
        y0 = np.floor((py - m) / s)
        y1 = np.floor((py + m) / s)
        nx, ny = layout.dims[lvl]
        ok = (x0 == x1) & (y0 == y1) & (x0 >= 0) & (y0 >= 0) & (x1 < nx) & (y1 < ny)
        if ok.any():
            node[idx[ok]] = layout.level_offset[lvl] + y0[ok].astype(np.int64) * nx + x0[ok].astype(np.int64)
            keep = ~ok
            idx, px, py, r = idx[keep], px[keep], py[keep], r[keep]
    return node


def node_capacity(counts: np.ndarray, slack: float) -> np.ndarray:
    """Slots reserved per node: the count plus spare room for objects moving in."""
    counts = np.asarray(counts, np.int64)
    return counts + np.where(counts > 0, np.ceil(counts * slack).astype(np.int64) + 1, 0)
