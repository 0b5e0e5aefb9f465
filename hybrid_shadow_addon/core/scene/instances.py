"""Every placed object as a structure of arrays (one row per instance), so 100k instances cost
arrays, not Python objects; with the affine-matrix helpers they use."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .arrays import as_f32

#: Cycles' default Shadow Terminator Geometry Offset of an object
DEFAULT_TERMINATOR = 0.1
#: an instance's light-linking membership outside any linking collection: every set
ALL_SETS = np.uint64(0xFFFFFFFFFFFFFFFF)


@dataclass
class Instances:
    """All placed objects, one row each.

    ``matrices`` are world matrices; ``inverse`` their inverses (derived when not given).
    ``model_ids`` index ``Scene.models``. ``sphere`` marks analytic sphere primitives: the
    instance is traced as its model's bounding sphere (model space, then the world matrix),
    with no triangles. ``terminator`` is the object's Shadow Terminator Geometry Offset (Cycles'
    ``Object.shadow_terminator_geometry_offset``): on smooth-shaded triangles, shadow rays towards
    lights within that cosine of the terminator start lifted towards the smooth surface.
    ``emission``: linear RGB x strength of an emitting surface (an Emission shader): the camera
    sees that colour and no lighting on it; it still casts shadows. Zero: not an emitter.
    ``visible_camera`` False: not drawn (Cycles' camera ray visibility off, an indirect-only
    collection), still a caster where ``casts_shadow``. ``holdout``: drawn as a hole in the image
    (alpha 0, no colour: Cycles' holdout), still a caster where ``casts_shadow``.
    ``light_sets`` / ``shadow_sets``: light and shadow linking (:mod:`.linking`), bit s set where
    the lights whose receiver (blocker) collection is set s light (shadow) the instance.
    """

    names: list = field(default_factory=list)  # list[str], len N
    model_ids: np.ndarray = None  # (N,) int32
    matrices: np.ndarray = None  # (N, 4, 4) float64
    inverse: np.ndarray = None  # (N, 4, 4) float64
    casts_shadow: np.ndarray = None  # (N,) bool
    base_color: np.ndarray = None  # (N, 4) float32, linear RGBA
    specular: np.ndarray = None  # (N,) float32, 0..1 (Principled "Specular IOR Level", clamped)
    roughness: np.ndarray = None  # (N,) float32
    sphere: np.ndarray = None  # (N,) bool
    material_ids: np.ndarray = None  # (N,) int32 index into Scene.materials; -1: plain colour
    terminator: np.ndarray = None  # (N,) float32 shadow terminator geometry offset, 0..1 (Cycles: 0.1)
    emission: np.ndarray = None  # (N, 3) float32 linear RGB x strength seen by the camera; 0: none
    visible_camera: np.ndarray = None  # (N,) bool: drawn in the G-buffer (default True)
    holdout: np.ndarray = None  # (N,) bool: drawn as a hole in the image (default False)
    light_sets: np.ndarray = None  # (N,) uint64 receiver light sets the instance belongs to
    shadow_sets: np.ndarray = None  # (N,) uint64 blocker shadow sets the instance belongs to

    def __post_init__(self):
        n = len(self.names)
        self.model_ids = (np.zeros(n, np.int32) if self.model_ids is None
                          else np.ascontiguousarray(self.model_ids, np.int32).reshape(n))
        self.matrices = (np.tile(np.eye(4), (n, 1, 1)) if self.matrices is None
                         else np.ascontiguousarray(self.matrices, np.float64).reshape(n, 4, 4))
        if self.inverse is None:
            self.inverse = affine_inverse(self.matrices)
        else:
            self.inverse = np.ascontiguousarray(self.inverse, np.float64).reshape(n, 4, 4)
        self.casts_shadow = (np.ones(n, bool) if self.casts_shadow is None
                             else np.ascontiguousarray(self.casts_shadow, bool).reshape(n))
        self.base_color = (np.tile(np.float32([0.8, 0.8, 0.8, 1.0]), (n, 1)) if self.base_color is None
                           else as_f32(self.base_color, (4,)))
        self.specular = np.full(n, 0.5, np.float32) if self.specular is None else as_f32(self.specular).reshape(n)
        self.roughness = np.full(n, 0.5, np.float32) if self.roughness is None else as_f32(self.roughness).reshape(n)
        self.sphere = np.zeros(n, bool) if self.sphere is None else np.ascontiguousarray(self.sphere, bool).reshape(n)
        self.material_ids = (np.full(n, -1, np.int32) if self.material_ids is None
                             else np.ascontiguousarray(self.material_ids, np.int32).reshape(n))
        self.terminator = (np.full(n, DEFAULT_TERMINATOR, np.float32) if self.terminator is None
                           else as_f32(self.terminator).reshape(n))
        self.emission = np.zeros((n, 3), np.float32) if self.emission is None else as_f32(self.emission, (3,))
        self.visible_camera = (np.ones(n, bool) if self.visible_camera is None
                               else np.ascontiguousarray(self.visible_camera, bool).reshape(n))
        self.holdout = (np.zeros(n, bool) if self.holdout is None
                        else np.ascontiguousarray(self.holdout, bool).reshape(n))
        self.light_sets = (np.full(n, ALL_SETS, np.uint64) if self.light_sets is None
                           else np.ascontiguousarray(self.light_sets, np.uint64).reshape(n))
        self.shadow_sets = (np.full(n, ALL_SETS, np.uint64) if self.shadow_sets is None
                            else np.ascontiguousarray(self.shadow_sets, np.uint64).reshape(n))

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def concatenate(cls, parts: Sequence[Instances]) -> Instances:
        """All rows of ``parts``, in order (empty parts skipped)."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls()
        return cls(
            names=[n for p in parts for n in p.names],
            model_ids=np.concatenate([p.model_ids for p in parts]),
            matrices=np.concatenate([p.matrices for p in parts]),
            inverse=np.concatenate([p.inverse for p in parts]),
            casts_shadow=np.concatenate([p.casts_shadow for p in parts]),
            base_color=np.concatenate([p.base_color for p in parts]),
            specular=np.concatenate([p.specular for p in parts]),
            roughness=np.concatenate([p.roughness for p in parts]),
            sphere=np.concatenate([p.sphere for p in parts]),
            material_ids=np.concatenate([p.material_ids for p in parts]),
            terminator=np.concatenate([p.terminator for p in parts]),
            emission=np.concatenate([p.emission for p in parts]),
            visible_camera=np.concatenate([p.visible_camera for p in parts]),
            holdout=np.concatenate([p.holdout for p in parts]),
            light_sets=np.concatenate([p.light_sets for p in parts]),
            shadow_sets=np.concatenate([p.shadow_sets for p in parts]),
        )

    def take(self, rows) -> Instances:
        """The instances at ``rows`` (indices or a boolean mask), in that order."""
        rows = np.arange(len(self))[np.asarray(rows)] if len(self) else np.zeros(0, np.int64)
        return Instances(names=[self.names[i] for i in rows.tolist()], model_ids=self.model_ids[rows],
                         matrices=self.matrices[rows], inverse=self.inverse[rows],
                         casts_shadow=self.casts_shadow[rows], base_color=self.base_color[rows],
                         specular=self.specular[rows], roughness=self.roughness[rows], sphere=self.sphere[rows],
                         material_ids=self.material_ids[rows], terminator=self.terminator[rows],
                         emission=self.emission[rows],
                         visible_camera=self.visible_camera[rows], holdout=self.holdout[rows],
                         light_sets=self.light_sets[rows], shadow_sets=self.shadow_sets[rows])

    def max_scale(self) -> np.ndarray:
        """(N,) largest axis scale of each world matrix (length of the 3x3 columns)."""
        return max_scale(self.matrices)

    def set_matrices(self, index, matrices) -> None:
        """Move instances: new world matrices (and inverses) for rows ``index``."""
        m = np.asarray(matrices, np.float64).reshape(-1, 4, 4)
        self.matrices[index] = m
        self.inverse[index] = affine_inverse(m)


def max_scale(m: np.ndarray) -> np.ndarray:
    """(N,) largest axis scale of a stack of 4x4 matrices (length of the 3x3 columns)."""
    return np.sqrt((m[:, :3, :3] ** 2).sum(axis=1)).max(axis=1)


def affine_inverse(m: np.ndarray) -> np.ndarray:
    """Inverses of a stack of affine 4x4 matrices (bottom row 0 0 0 1) by vectorised cofactors.
    Singular (zero-scale) or non-finite ones give NaN, which ``Scene.validate`` then reports by name."""
    m = np.asarray(m, np.float64)
    r0, r1, r2 = m[:, 0, :3], m[:, 1, :3], m[:, 2, :3]
    adj = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=2)  # columns
    det = np.einsum("ni,ni->n", r0, adj[:, :, 0])
    ok = np.isfinite(m).all(axis=(1, 2)) & (det != 0)
    out = np.full_like(m, np.nan)
    inv3 = adj[ok] / det[ok, None, None]
    out[ok, :3, :3] = inv3
    out[ok, :3, 3] = -np.einsum("nij,nj->ni", inv3, m[ok, :3, 3])
    out[ok, 3] = (0, 0, 0, 1)
    return out
