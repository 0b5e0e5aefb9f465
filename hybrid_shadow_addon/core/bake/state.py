"""The bake's configuration: what every structure shares (:class:`BakeConfig`) and each
structure's own (:class:`GridConfig`, :class:`BVHConfig`). The report of an incremental update:
:mod:`.report`; the structures' own state: ``structures/``."""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace


@dataclass(frozen=True)
class GridConfig:
    """The thesis' hierarchical grid (structure ``grid``)."""

    base_node_size: float | None = None  # level-0 node size (m); None: fit to the scene
    max_level0_nodes: int | None = None  # None: 4 * casters (at least 64, at most 4M)
    leaf_size: int = 4  # triangles per model-BVH leaf (1..7)
    index_slack: float = 0.25  # spare slots per grid node, as a fraction of its count (+1)
    index_reserve: float = 0.25  # spare tail of the grid index list, fraction of its length
    outside_rebake_fraction: float = 0.01  # regrid when more casters than this left the grid
    object_bvh_threshold: int = 32  # nodes with more objects than this get an object BVH
    object_leaf_size: int = 4  # grid-index entries per object-BVH leaf (1..7)

    def __post_init__(self):
        if not 1 <= int(self.leaf_size) <= 7:
            raise ValueError("grid leaf_size must be 1..7")
        if not 1 <= int(self.object_leaf_size) <= 7:
            raise ValueError("grid object_leaf_size must be 1..7")
        if int(self.object_bvh_threshold) < 1:
            raise ValueError("grid object_bvh_threshold must be >= 1")


@dataclass(frozen=True)
class BVHConfig:
    """The two-level BVH (structure ``bvh``)."""

    leaf_size: int = 2  # triangles per model-tree leaf (1..4)
    wide: bool = True  # single rays walk 4-wide nodes ([wide]); False: binary

    def __post_init__(self):
        if not 1 <= int(self.leaf_size) <= 4:
            raise ValueError("bvh leaf_size must be 1..4")


@dataclass
class BakeConfig:
    """How to bake: the structure to build, what every structure shares, and each structure's
    own config (the attribute of its registry name: ``grid``, ``bvh``)."""

    structure: str | None = None  # a name of structures.STRUCTURES; None: DEFAULT_STRUCTURE
    tex_width: int = 4096  # power of two <= 16384; every texture wraps its rows at this width
    origin: tuple | None = None  # bake-space origin in world space; None: choose_origin()
    grid: GridConfig = field(default_factory=GridConfig)
    bvh: BVHConfig = field(default_factory=BVHConfig)

    def __post_init__(self):
        from .structures import DEFAULT_STRUCTURE, STRUCTURES

        if self.structure is None:
            self.structure = DEFAULT_STRUCTURE
        if self.structure not in STRUCTURES:
            raise ValueError(f"structure must be one of {', '.join(STRUCTURES)}, not {self.structure!r}")
        w = int(self.tex_width)
        if w < 4 or w > 16384 or w & (w - 1):
            raise ValueError("tex_width must be a power of two between 4 and 16384")

    @property
    def own(self):
        """The config of the structure to build."""
        return getattr(self, self.structure)

    @classmethod
    def of(cls, structure: str | None = None, **options) -> BakeConfig:
        """A config for ``structure`` with ``options``: ``tex_width`` and ``origin``, or fields of
        that structure's own config (a name it does not have raises ``ValueError``)."""
        shared = {k: options.pop(k) for k in ("tex_width", "origin") if k in options}
        config = cls(structure=structure, **shared)
        if options:
            own = config.own
            known = {f.name for f in fields(own)}
            unknown = sorted(set(options) - known)
            if unknown:
                raise ValueError(f"structure {config.structure!r} has no option {', '.join(unknown)} "
                                 f"(its options: {', '.join(sorted(known))})")
            setattr(config, config.structure, replace(own, **options))
        return config
