"""One unique triangle mesh in model space, shared by its instances."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError
from .arrays import as_f32


@dataclass
class Model:
    """One unique triangle mesh in model space (``normals``: optional smooth shading normals per
    triangle corner; shading only, shadows use the triangles).

    ``bounds_min``/``bounds_max`` and the bounding sphere (``sphere_center``, ``sphere_radius``)
    are derived from the vertices when not given. The sphere is centred on the box centre, its
    radius the farthest vertex from it (cheap, vectorised, and never smaller than needed).
    """

    name: str
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) uint32, indices into vertices
    bounds_min: np.ndarray = None  # (3,) float32
    bounds_max: np.ndarray = None  # (3,) float32
    sphere_center: np.ndarray = None  # (3,) float32
    sphere_radius: float = None
    normals: np.ndarray = None  # (T, 3, 3) float32 smooth shading normal per corner; None: flat
    uvs: np.ndarray = None  # (T, 3, 2) float32 texture coordinates per corner; None: no UV map

    def __post_init__(self):
        self.vertices = as_f32(self.vertices, (3,))
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.uint32).reshape(-1, 3)
        if self.normals is not None:
            self.normals = as_f32(self.normals).reshape(-1, 3, 3)
        if self.uvs is not None:
            self.uvs = as_f32(self.uvs).reshape(-1, 3, 2)
        if self.bounds_min is None or self.bounds_max is None:
            if len(self.vertices):
                self.bounds_min = self.vertices.min(axis=0)
                self.bounds_max = self.vertices.max(axis=0)
            else:
                self.bounds_min = np.zeros(3, np.float32)
                self.bounds_max = np.zeros(3, np.float32)
        self.bounds_min = as_f32(self.bounds_min).reshape(3)
        self.bounds_max = as_f32(self.bounds_max).reshape(3)
        if self.sphere_center is None or self.sphere_radius is None:
            self._derive_sphere()
        self.sphere_center = as_f32(self.sphere_center).reshape(3)
        self.sphere_radius = float(self.sphere_radius)

    def _derive_sphere(self) -> None:
        """Bounding sphere around the box centre, rounded so its float32 copy still encloses every vertex."""
        with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf meshes are reported by validate()
            c = (self.bounds_min.astype(np.float64) + self.bounds_max) * 0.5
            if len(self.vertices):
                d = self.vertices.astype(np.float64) - c
                r = float(np.sqrt((d * d).sum(axis=1).max()))
            else:
                r = 0.0
            # float32 storage must never shrink the sphere: add the centre's rounding, round r up
            c32 = c.astype(np.float32)
            r += float(np.linalg.norm(c - c32))
        self.sphere_center = c32
        self.sphere_radius = float(np.nextafter(np.float32(r), np.float32(np.inf)))

    @property
    def triangle_count(self) -> int:
        """Number of triangles."""
        return int(self.triangles.shape[0])

    @property
    def vertex_count(self) -> int:
        """Number of vertices."""
        return int(self.vertices.shape[0])

    def validate(self) -> None:
        """Raise :class:`SceneError` for non-finite data or indices and per-corner arrays that do not fit."""
        if not np.isfinite(self.vertices).all():
            raise SceneError(f"mesh '{self.name}' has NaN or infinite vertex coordinates")
        if len(self.triangles) and int(self.triangles.max()) >= len(self.vertices):
            raise SceneError(f"mesh '{self.name}' has triangle indices beyond its {len(self.vertices)} vertices")
        if self.normals is not None:
            if self.normals.shape != (len(self.triangles), 3, 3):
                raise SceneError(f"mesh '{self.name}' has {len(self.normals)} normal triples for "
                                 f"{len(self.triangles)} triangles")
            if not np.isfinite(self.normals).all():
                raise SceneError(f"mesh '{self.name}' has NaN or infinite normals")
        if self.uvs is not None:
            if self.uvs.shape != (len(self.triangles), 3, 2):
                raise SceneError(f"mesh '{self.name}' has {len(self.uvs)} UV triples for "
                                 f"{len(self.triangles)} triangles")
            if not np.isfinite(self.uvs).all():
                raise SceneError(f"mesh '{self.name}' has NaN or infinite UVs")
