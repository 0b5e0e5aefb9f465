"""The report of an incremental update, which every structure fills (``structures/``)."""
from __future__ import annotations

from dataclasses import dataclass, field

from .textures import merge_ranges


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
