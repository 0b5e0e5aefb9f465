"""The state of a hierarchical-grid bake, declared once: its texture set and the per-model,
per-instance and per-grid-node arrays. Texel layouts: ``shaders/common/scene_grid.glsl``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..grid import GridLayout, plan_grid
from ..textures import TextureData, alloc_texture
from .base import ModelSlots

#: (components, format) of each scene texture, in upload order
TEXTURE_FORMATS = {
    "grid": (4, "u4"),
    "grid_index": (2, "u4"),
    "object": (4, "f4"),
    "model": (4, "u4"),
    "bvh": (4, "u4"),
    "tri": (3, "f4"),
    # alpha-cut shadows only (scenes whose casters' materials cut their shadows; else absent)
    "uv": (4, "f4"),
    "object_mat": (1, "u4"),
}
TEXTURE_NAMES = tuple(TEXTURE_FORMATS)
#: the textures every grid bake has; the others (ALPHA_TEXTURE_NAMES) only when needed
BASE_TEXTURE_NAMES = TEXTURE_NAMES[:6]
ALPHA_TEXTURE_NAMES = ("uv", "object_mat")
#: [uv] texels per [tri] record: (u0 v0 u1 v1), (u2 v2 0 0)
UV_TEXELS = 2


def new_texture(name: str, n_texels: int, width: int) -> TextureData:
    """A zeroed scene texture ``name`` holding ``n_texels`` (its ``used`` count)."""
    components, fmt = TEXTURE_FORMATS[name]
    return alloc_texture(name, n_texels, components, fmt, width)


@dataclass
class TextureSet:
    """The six scene textures, the two of alpha-cut shadows (None unless the scene has such
    casters) and how many records of [bvh] and [tri] are allocated."""

    grid: TextureData
    grid_index: TextureData
    object: TextureData
    model: TextureData
    bvh: TextureData
    tri: TextureData
    bvh_tail: int = 0  # [bvh] records allocated: model BVHs, then the grid's object BVHs
    tri_tail: int = 0  # [tri] records allocated
    uv: TextureData | None = None  # [uv]: UV_TEXELS per [tri] record (mirrors [tri])
    object_mat: TextureData | None = None  # [object_mat]: 1 texel per instance

    @classmethod
    def empty(cls, width: int) -> TextureSet:
        return cls(**{name: new_texture(name, 0, width) for name in BASE_TEXTURE_NAMES})

    def __getitem__(self, name: str) -> TextureData:
        if name not in TEXTURE_FORMATS or getattr(self, name) is None:
            raise KeyError(name)
        return getattr(self, name)

    def as_dict(self) -> dict[str, TextureData]:
        return {name: getattr(self, name) for name in TEXTURE_NAMES if getattr(self, name) is not None}


@dataclass
class GridModels(ModelSlots):
    """:class:`ModelSlots` in [bvh] / [tri] records, plus which models' UVs are in [uv]."""

    #: (M,) bool: the model's UVs are in [uv] (alpha-cut shadows); None: the bake has no [uv]
    uv: np.ndarray | None = None

    @classmethod
    def from_build(cls, build) -> GridModels:
        """The models of a :class:`~..bvh.BVHBuild` packed from record 0, no spare room."""
        return cls(node_start=build.node_start.copy(), node_count=build.node_count.copy(),
                   node_cap=build.node_count.copy(), tri_start=build.tri_start.copy(),
                   tri_count=build.tri_count.copy(), tri_cap=build.tri_count.copy(), depth=build.depth.copy())


@dataclass
class InstanceState:
    """Per instance, in bake space: the bounding sphere as stored and where the grid holds it."""

    center: np.ndarray  # (N, 3) float64 world sphere centre minus the origin
    radius: np.ndarray  # (N,) float64 world radius (not enlarged)
    top: np.ndarray  # (N,) float64 top of the stored (enlarged) sphere
    model: np.ndarray  # (N,) int64 model id
    sphere: np.ndarray  # (N,) bool analytic sphere primitive
    node: np.ndarray  # (N,) int64 global grid node, -1: not in the grid (not a caster)
    slot: np.ndarray  # (N,) int64 [grid_index] slot, -1: none

    @classmethod
    def empty(cls, n: int = 0) -> InstanceState:
        return cls(np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n, np.int64), np.zeros(n, bool),
                   np.full(n, -1, np.int64), np.full(n, -1, np.int64))

    def __len__(self) -> int:
        return len(self.node)


@dataclass
class GridState:
    """The grid layout and its nodes: (nodes,) arrays indexed by global node id."""

    layout: GridLayout
    count: np.ndarray  # int64 objects in the node
    cap: np.ndarray  # int64 [grid_index] slots reserved
    offset: np.ndarray  # int64 first slot
    maxh: np.ndarray  # float64 highest stored sphere top, -inf when empty
    obvh: np.ndarray  # int64 root [bvh] record of the node's object BVH, -1: flat list
    obvh_start: np.ndarray  # int64 first [bvh] record allocated to the node's object BVH
    obvh_cap: np.ndarray  # int64 [bvh] records allocated to it
    level_count: np.ndarray  # (levels,) int64 casters per level
    index_tail: int = 0  # [grid_index] slots allocated
    bvh_range: tuple[int, int] = (0, 0)  # [bvh] records the grid build wrote
    bvh_grown: bool = False  # the grid build resized [bvh]

    @classmethod
    def new(cls, layout: GridLayout) -> GridState:
        """Empty nodes of ``layout``."""
        n = layout.n_nodes
        return cls(layout, np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64),
                   np.full(n, -np.inf), np.full(n, -1, np.int64), np.zeros(n, np.int64),
                   np.zeros(n, np.int64), np.zeros(layout.levels, np.int64))

    @classmethod
    def empty(cls) -> GridState:
        return cls.new(plan_grid(np.zeros((0, 3)), np.zeros(0)))


