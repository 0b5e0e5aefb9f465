"""The bake's configuration and the report of an incremental update (what every structure
fills). The structures' own state: ``structures/``."""
from __future__ import annotations

from dataclasses import dataclass, field

from .textures import merge_ranges


@dataclass
class BakeConfig:
    """How to bake: the structure to build and its sizes (the grid's and the trees')."""

    tex_width: int = 4096  # power of two <= 16384; every texture wraps its rows at this width
    base_node_size: float | None = None  # level-0 node size (m); None: fit to the scene
    max_level0_nodes: int | None = None  # None: 4 * casters (at least 64, at most 4M)
    leaf_size: int = 4  # triangles per BVH leaf (1..7)
    index_slack: float = 0.25  # spare slots per grid node, as a fraction of its count (+1)
    index_reserve: float = 0.25  # spare tail of the grid index list, fraction of its length
    outside_rebake_fraction: float = 0.01  # regrid when more casters than this left the grid
    origin: tuple | None = None  # bake-space origin in world space; None: choose_origin()
    object_bvh_threshold: int = 32  # nodes with more objects than this get an object BVH
    object_leaf_size: int = 4  # grid-index entries per object-BVH leaf (1..7)
    structure: str | None = None  # a name of structures.STRUCTURES; None: DEFAULT_STRUCTURE
    bvh_leaf_size: int = 2  # structure "bvh": triangles per model-tree leaf (1..4)
    bvh_wide: bool = True  # structure "bvh": single rays walk 4-wide nodes ([wide]); False: binary

    def __post_init__(self):
        from .structures import DEFAULT_STRUCTURE, STRUCTURES  # (the structures import this module)
        if self.structure is None:
            self.structure = DEFAULT_STRUCTURE
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

    def merge(self, other: UpdateReport) -> UpdateReport:
        self.ranges = merge_ranges(self.ranges + other.ranges)
        self.resized |= other.resized
        self.uniforms_changed |= other.uniforms_changed
        self.defines_changed |= other.defines_changed
        self.regrid |= other.regrid
        self.objects += other.objects
        self.nodes_changed += other.nodes_changed
        return self
