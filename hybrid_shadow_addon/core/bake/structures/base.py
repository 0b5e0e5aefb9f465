"""The interface every acceleration structure implements, and what the implementations share:
where each model's tree and triangles sit (:class:`ModelSlots`) and the model rebuild's frame
(:meth:`AccelerationStructure.update_model`)."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from ..report import UpdateReport
from ..textures import TextureData, merge_ranges


@dataclass
class ModelSlots:
    """Per model, (M,) int64: where its tree and triangles sit in the structure's textures and
    how much room is allocated to each (an edit that fits stays in place). Triangle places and
    room are in the structure's own triangle units (records or texels)."""

    node_start: np.ndarray
    node_count: np.ndarray
    node_cap: np.ndarray
    tri_start: np.ndarray
    tri_count: np.ndarray  # triangles
    tri_cap: np.ndarray
    depth: np.ndarray

    @classmethod
    def empty(cls, m: int = 0) -> ModelSlots:
        return cls(*(np.zeros(m, np.int64) for _ in range(7)))

    def append(self) -> None:
        """One more model, with nothing allocated yet (every (M, ...) array grows by a zero row)."""
        for f in fields(self):
            a = getattr(self, f.name)
            if isinstance(a, np.ndarray):
                setattr(self, f.name, np.concatenate([a, np.zeros((1,) + a.shape[1:], a.dtype)]))

    def place(self, m: int, nodes: int, tris: int, node_tail: int, tri_tail: int) -> tuple[int, int, bool]:
        """Where model ``m``'s rebuilt tree (``nodes`` records) and triangles (``tris`` units) go:
        its own allocation when both fit, else the tails (``node_tail``, ``tri_tail``), which
        then become its allocation. Returns ``(node_base, tri_base, at_tail)``; the caller moves
        its tails when ``at_tail``."""
        if nodes <= self.node_cap[m] and tris <= self.tri_cap[m]:
            return int(self.node_start[m]), int(self.tri_start[m]), False
        self.node_cap[m], self.tri_cap[m] = nodes, tris
        return int(node_tail), int(tri_tail), True

    def __len__(self) -> int:
        return len(self.node_count)


def users_of(scene, m: int) -> np.ndarray:
    """The instances of model ``m``."""
    return np.nonzero(scene.instances.model_ids == m)[0] if len(scene.instances) else np.zeros(0, np.int64)


class AccelerationStructure(ABC):
    """One acceleration structure over a scene's shadow casters: it bakes the scene into textures
    (plus ``#define``s and uniforms for its GLSL walk), updates them incrementally, and walks them
    in numpy (the oracle of its shader). Positions are in bake space (world - ``origin``)."""

    #: registry name (``Settings.structure``, ``BakeConfig.structure``)
    name: ClassVar[str]
    #: the shader file that declares its textures and walks them (``shaders/``-relative)
    glsl_include: ClassVar[str]
    #: whether the per-light light grids can stand in for its walk (they reuse its triangle test
    #: and instance records)
    supports_light_grids: ClassVar[bool] = False
    #: whether a pixel's soft-shadow rays can walk it together (``shaders/common/scene_packet.glsl``)
    supports_packets: ClassVar[bool] = False
    #: user-facing label (Blender's enum, the CLI's help)
    label: ClassVar[str]
    description: ClassVar[str]

    def __init__(self, config, origin: np.ndarray, materials):
        #: where each model's tree and triangles sit (a :class:`ModelSlots`)
        self.models: ModelSlots = ModelSlots.empty()
        self.config = config
        self.origin = origin
        #: textured / alpha-cut materials (``materials.MaterialBake``) or None
        self.materials = materials
        #: bake timings and the derived entries of :meth:`refresh_stats`
        self.stats: dict = {}

    # -------------------------------------------------------------------------- building --
    @classmethod
    @abstractmethod
    def bake(cls, scene, config, origin: np.ndarray, materials) -> AccelerationStructure:
        """The structure over ``scene``, its textures filled and :attr:`stats` timed."""

    @abstractmethod
    def update_instances(self, scene, indices) -> UpdateReport:
        """Instances ``indices`` moved (``scene.instances`` already holds their new matrices)."""

    def update_model(self, scene, model_id: int) -> UpdateReport:
        """Mesh ``model_id`` was edited (or appended to ``scene.models``): rebuild that model's
        tree and triangles only, then re-place its instances."""
        m = int(model_id)
        if m > len(self.models) or m >= len(scene.models):
            raise ValueError(f"model id {m} is neither an existing model nor the next new one")
        rep = UpdateReport()
        old_defines = self.defines
        if m == len(self.models):
            self.append_model(rep)
        self.rebuild_model(scene, m, rep)
        users = users_of(scene, m)
        if users.size:
            rep.merge(self.update_instances(scene, users))
        if self.defines != old_defines:
            rep.defines_changed = True
        return self.finish_update(rep)

    def finish_update(self, rep: UpdateReport) -> UpdateReport:
        """``rep`` with its row ranges merged, less those of textures resized whole (uploaded
        whole), and :attr:`stats` refreshed: the last step of every update."""
        rep.ranges = merge_ranges([r for r in rep.ranges if r[0] not in rep.resized])
        self.refresh_stats()
        return rep

    @abstractmethod
    def append_model(self, rep: UpdateReport) -> None:
        """Room for one more model (its id: the current model count)."""

    @abstractmethod
    def rebuild_model(self, scene, m: int, rep: UpdateReport) -> None:
        """Build model ``m``'s tree again and write it and its triangles (its instances follow)."""

    # -------------------------------------------------------------------------- read-outs --
    @property
    @abstractmethod
    def textures(self) -> dict[str, TextureData]:
        """Its textures by name, in upload order."""

    @property
    @abstractmethod
    def defines(self) -> dict:
        """``#define``s of its GLSL (flags present only when true)."""

    @property
    @abstractmethod
    def uniforms(self) -> dict:
        """Uniform values by GLSL name."""

    @property
    @abstractmethod
    def has_meshes(self) -> bool:
        """Some caster is a mesh with triangles."""

    @property
    @abstractmethod
    def has_spheres(self) -> bool:
        """Some caster is an analytic sphere."""

    @property
    @abstractmethod
    def has_alpha(self) -> bool:
        """Some caster's material cuts its shadow: the walk runs the any-hit alpha test."""

    @abstractmethod
    def refresh_stats(self) -> dict:
        """Recompute the derived entries of :attr:`stats` (the timings stay)."""

    @abstractmethod
    def occupancy(self, xy: np.ndarray) -> np.ndarray:
        """(N,) float64: how much of the structure covers each bake-space point ``xy`` (N, 2)
        seen from above (the Grid Occupancy debug view)."""
