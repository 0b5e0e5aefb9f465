"""The bake's configuration. The report of an incremental update: :mod:`.report`; the
structures' own state: ``structures/``."""
from __future__ import annotations

from dataclasses import dataclass


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
