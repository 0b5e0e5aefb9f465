"""The state of a baked scene, declared once: the bake configuration, the texture set, the
per-model, per-instance and per-grid-node arrays, and the report of an incremental update.

:class:`~.baked.BakedScene` holds one of each; the bake (``baked.py``) and the incremental update
(``update.py``) both fill them. Texel layouts: ``shaders/common/scene_data.glsl``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..settings import STRUCTURES  # "grid": grid.py + bvh.py; "bvh": twolevel.py
from .grid import GridLayout, plan_grid
from .textures import TextureData, alloc_texture, merge_ranges

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
class BakeConfig:
    tex_width: int = 4096  # power of two <= 16384; every texture wraps its rows at this width
    base_node_size: Optional[float] = None  # level-0 node size (m); None: fit to the scene
    max_level0_nodes: Optional[int] = None  # None: 4 * casters (at least 64, at most 4M)
    leaf_size: int = 4  # triangles per BVH leaf (1..7)
    index_slack: float = 0.25  # spare slots per grid node, as a fraction of its count (+1)
    index_reserve: float = 0.25  # spare tail of the grid index list, fraction of its length
    outside_rebake_fraction: float = 0.01  # regrid when more casters than this left the grid
    origin: Optional[tuple] = None  # bake-space origin in world space; None: choose_origin()
    object_bvh_threshold: int = 32  # nodes with more objects than this get an object BVH
    object_leaf_size: int = 4  # grid-index entries per object-BVH leaf (1..7)
    structure: str = "grid"  # one of STRUCTURES
    bvh_leaf_size: int = 2  # structure "bvh": triangles per model-tree leaf (1..4)

    def __post_init__(self):
        if self.structure not in STRUCTURES:
            raise ValueError(f"structure must be one of {', '.join(STRUCTURES)}, not {self.structure!r}")
        w = int(self.tex_width)
        if w < 4 or w > 16384 or w & (w - 1):
            raise ValueError("tex_width must be a power of two between 4 and 16384")
        if not 1 <= int(self.leaf_size) <= 7:
            raise ValueError("leaf_size must be 1..7")
        if not 1 <= int(self.bvh_leaf_size) <= 4:
            raise ValueError("bvh_leaf_size must be 1..4")
        if not 1 <= int(self.object_leaf_size) <= 7:
            raise ValueError("object_leaf_size must be 1..7")
        if int(self.object_bvh_threshold) < 1:
            raise ValueError("object_bvh_threshold must be >= 1")


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
    uv: Optional[TextureData] = None  # [uv]: UV_TEXELS per [tri] record (mirrors [tri])
    object_mat: Optional[TextureData] = None  # [object_mat]: 1 texel per instance

    @classmethod
    def empty(cls, width: int) -> "TextureSet":
        return cls(**{name: new_texture(name, 0, width) for name in BASE_TEXTURE_NAMES})

    def __getitem__(self, name: str) -> TextureData:
        if name not in TEXTURE_FORMATS or getattr(self, name) is None:
            raise KeyError(name)
        return getattr(self, name)

    def as_dict(self) -> dict[str, TextureData]:
        return {name: getattr(self, name) for name in TEXTURE_NAMES if getattr(self, name) is not None}


@dataclass
class ModelState:
    """Where each model's BVH and triangles sit: (M,) int64 record indices into [bvh] / [tri]."""

    node_start: np.ndarray  # first [bvh] record of the model's BVH
    node_count: np.ndarray  # BVH nodes
    tri_start: np.ndarray  # first [tri] record
    tri_count: np.ndarray  # triangles
    node_cap: np.ndarray  # [bvh] records allocated to the model (an edit fitting them stays)
    tri_cap: np.ndarray  # [tri] records allocated
    depth: np.ndarray  # BVH depth
    #: (M,) bool: the model's UVs are in [uv] (alpha-cut shadows); None: the bake has no [uv]
    uv: Optional[np.ndarray] = None

    @classmethod
    def empty(cls, m: int = 0) -> "ModelState":
        return cls(*(np.zeros(m, np.int64) for _ in range(7)))

    @classmethod
    def from_build(cls, build) -> "ModelState":
        """The models of a :class:`~.bvh.BVHBuild` packed from record 0, no spare room."""
        return cls(build.node_start.copy(), build.node_count.copy(), build.tri_start.copy(),
                   build.tri_count.copy(), build.node_count.copy(), build.tri_count.copy(),
                   build.depth.copy())

    def append(self) -> None:
        """One more model, with nothing allocated yet."""
        for name in ("node_start", "node_count", "tri_start", "tri_count", "node_cap", "tri_cap", "depth"):
            setattr(self, name, np.concatenate([getattr(self, name), [0]]).astype(np.int64))
        if self.uv is not None:
            self.uv = np.concatenate([self.uv, [False]])

    def __len__(self) -> int:
        return len(self.node_count)


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
    def empty(cls, n: int = 0) -> "InstanceState":
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
    def new(cls, layout: GridLayout) -> "GridState":
        """Empty nodes of ``layout``."""
        n = layout.n_nodes
        return cls(layout, np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64),
                   np.full(n, -np.inf), np.full(n, -1, np.int64), np.zeros(n, np.int64),
                   np.zeros(n, np.int64), np.zeros(layout.levels, np.int64))

    @classmethod
    def empty(cls) -> "GridState":
        return cls.new(plan_grid(np.zeros((0, 3)), np.zeros(0)))


@dataclass
class UpdateReport:
    """What an incremental update changed, for partial re-uploads.

    ``ranges``: ``(texture_name, layer, y0, y1)`` row ranges (y1 exclusive) whose texels changed;
    ``resized``: textures whose shape changed (re-create and upload whole; their rows are not
    listed); ``uniforms_changed`` / ``defines_changed``: re-read ``BakedScene.uniforms`` /
    ``.defines`` (defines mean recompiling the program); ``regrid``: the grid was rebuilt.
    """

    ranges: list = field(default_factory=list)
    resized: set = field(default_factory=set)
    uniforms_changed: bool = False
    defines_changed: bool = False
    regrid: bool = False
    objects: int = 0
    nodes_changed: int = 0
    ms: float = 0.0

    def texels_changed(self, baked) -> int:
        n = 0
        for name, _layer, y0, y1 in self.ranges:
            n += (y1 - y0) * baked.textures[name].width
        return n

    def merge(self, other: "UpdateReport") -> "UpdateReport":
        self.ranges = merge_ranges(self.ranges + other.ranges)
        self.resized |= other.resized
        self.uniforms_changed |= other.uniforms_changed
        self.defines_changed |= other.defines_changed
        self.regrid |= other.regrid
        self.objects += other.objects
        self.nodes_changed += other.nodes_changed
        return self
