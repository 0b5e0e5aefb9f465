"""The bpy-free scene model: plain dataclasses over numpy arrays.

Conventions (Blender's): right-handed, Z up, metres. Matrices are 4x4 float64, column vectors
(``p_world = M @ [x, y, z, 1]``), exactly as ``Object.matrix_world`` reads in numpy.

- :class:`Model`: one unique mesh (model space): float32 vertices, uint32 triangles, bounds and a
  bounding sphere. Many instances share one model.
- :class:`Instances`: every placed object as a structure of arrays (one row per instance), so
  100k instances cost arrays, not Python objects.
- :class:`Light`: sun, point, spot, area (Blender's parameters and units).
- :class:`Camera`: perspective or orthographic with Blender's sensor fit, shift and clip range.
- :class:`Image`, :class:`Material`: textures and the alpha of textured/cut-out materials
  (foliage cards, fences), referenced by instances through ``Instances.material_ids``.
- :class:`Scene`: all of the above plus the world colour and the render resolution.

``Scene.validate()`` rejects NaN/inf (and other unusable values) with a message naming the object.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from .errors import SceneError

LIGHT_TYPES = ("SUN", "POINT", "SPOT", "AREA")
#: transforms with a value this large are rejected (Blender stores an infinite scale as FLT_MAX)
MAX_COORD = 1e18
CAMERA_TYPES = ("PERSP", "ORTHO")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


def _f32(a, shape_tail=None) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float32)
    if shape_tail is not None:
        a = a.reshape((-1,) + tuple(shape_tail))
    return a


# --------------------------------------------------------------------------------------------
# Models
# --------------------------------------------------------------------------------------------
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
        self.vertices = _f32(self.vertices, (3,))
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.uint32).reshape(-1, 3)
        if self.normals is not None:
            self.normals = _f32(self.normals).reshape(-1, 3, 3)
        if self.uvs is not None:
            self.uvs = _f32(self.uvs).reshape(-1, 3, 2)
        if self.bounds_min is None or self.bounds_max is None:
            if len(self.vertices):
                self.bounds_min = self.vertices.min(axis=0)
                self.bounds_max = self.vertices.max(axis=0)
            else:
                self.bounds_min = np.zeros(3, np.float32)
                self.bounds_max = np.zeros(3, np.float32)
        self.bounds_min = _f32(self.bounds_min).reshape(3)
        self.bounds_max = _f32(self.bounds_max).reshape(3)
        if self.sphere_center is None or self.sphere_radius is None:
            self._derive_sphere()
        self.sphere_center = _f32(self.sphere_center).reshape(3)
        self.sphere_radius = float(self.sphere_radius)

    def _derive_sphere(self) -> None:
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
        return int(self.triangles.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.vertices.shape[0])

    def validate(self) -> None:
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


# --------------------------------------------------------------------------------------------
# Instances (structure of arrays)
# --------------------------------------------------------------------------------------------
@dataclass
class Instances:
    """All placed objects, one row each.

    ``matrices`` are world matrices; ``inverse`` their inverses (derived when not given).
    ``model_ids`` index ``Scene.models``. ``sphere`` marks analytic sphere primitives: the
    instance is traced as its model's bounding sphere (model space, then the world matrix),
    with no triangles.
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

    def __post_init__(self):
        n = len(self.names)
        self.model_ids = np.zeros(n, np.int32) if self.model_ids is None else np.ascontiguousarray(self.model_ids, np.int32).reshape(n)
        self.matrices = (np.tile(np.eye(4), (n, 1, 1)) if self.matrices is None
                         else np.ascontiguousarray(self.matrices, np.float64).reshape(n, 4, 4))
        if self.inverse is None:
            self.inverse = affine_inverse(self.matrices)
        else:
            self.inverse = np.ascontiguousarray(self.inverse, np.float64).reshape(n, 4, 4)
        self.casts_shadow = np.ones(n, bool) if self.casts_shadow is None else np.ascontiguousarray(self.casts_shadow, bool).reshape(n)
        self.base_color = (np.tile(np.float32([0.8, 0.8, 0.8, 1.0]), (n, 1)) if self.base_color is None
                           else _f32(self.base_color, (4,)))
        self.specular = np.full(n, 0.5, np.float32) if self.specular is None else _f32(self.specular).reshape(n)
        self.roughness = np.full(n, 0.5, np.float32) if self.roughness is None else _f32(self.roughness).reshape(n)
        self.sphere = np.zeros(n, bool) if self.sphere is None else np.ascontiguousarray(self.sphere, bool).reshape(n)
        self.material_ids = (np.full(n, -1, np.int32) if self.material_ids is None
                             else np.ascontiguousarray(self.material_ids, np.int32).reshape(n))

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def concatenate(cls, parts: Sequence["Instances"]) -> "Instances":
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
        )

    def take(self, rows) -> "Instances":
        """The instances at ``rows`` (indices or a boolean mask), in that order."""
        rows = np.arange(len(self))[np.asarray(rows)] if len(self) else np.zeros(0, np.int64)
        return Instances(names=[self.names[i] for i in rows.tolist()], model_ids=self.model_ids[rows],
                         matrices=self.matrices[rows], inverse=self.inverse[rows],
                         casts_shadow=self.casts_shadow[rows], base_color=self.base_color[rows],
                         specular=self.specular[rows], roughness=self.roughness[rows], sphere=self.sphere[rows],
                         material_ids=self.material_ids[rows])

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
    """Inverses of a stack of affine 4x4 matrices (bottom row 0 0 0 1) by cofactors, ~10x
    faster than ``np.linalg.inv``. Singular (zero-scale) or non-finite ones give NaN, which
    ``Scene.validate`` then reports by name."""
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


# --------------------------------------------------------------------------------------------
# Images and materials
# --------------------------------------------------------------------------------------------
IMAGE_EXTENSIONS = ("REPEAT", "EXTEND", "CLIP", "MIRROR")
IMAGE_INTERPOLATIONS = ("Linear", "Closest")
ALPHA_MODES = ("BLEND", "CLIP")
ALPHA_CHANNELS = ("A", "LUMA")
#: Rec. 709 luminance (Blender's default scene-linear space): a Color socket linked to a float one
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass
class Image:
    """An image texture as Blender stores it: ``pixels`` (H, W, 4) uint8 RGBA, row 0 at the
    bottom (v = 0), the stored values (``srgb``: the colour channels are sRGB-encoded and are
    decoded for the albedo; alpha is always linear).

    Sampling rule (the GPU and the numpy oracle both follow it): texel (i, j) has its centre at
    ``((i + 0.5) / W, (j + 0.5) / H)``; ``"Linear"`` blends the 4 nearest texels bilinearly,
    ``"Closest"`` takes ``floor(u W), floor(v H)``; outside [0, 1) ``"REPEAT"`` wraps, ``"EXTEND"``
    clamps to the edge texel, ``"MIRROR"`` reflects, ``"CLIP"`` reads transparent black.
    """

    name: str
    pixels: np.ndarray
    srgb: bool = True
    extension: str = "REPEAT"
    interpolation: str = "Linear"

    def __post_init__(self):
        px = np.asarray(self.pixels)
        if px.dtype != np.uint8:
            with np.errstate(invalid="ignore"):
                px = np.round(np.clip(np.nan_to_num(px.astype(np.float64)), 0.0, 1.0) * 255.0).astype(np.uint8)
        if px.ndim == 2:
            px = px[:, :, None]
        if px.ndim != 3 or px.shape[2] not in (1, 3, 4):
            raise SceneError(f"image '{self.name}' has pixels of shape {px.shape}; expected (H, W, 4)")
        if px.shape[2] == 1:
            px = np.concatenate([np.repeat(px, 3, axis=2), np.full(px.shape[:2] + (1,), 255, np.uint8)], axis=2)
        elif px.shape[2] == 3:
            px = np.concatenate([px, np.full(px.shape[:2] + (1,), 255, np.uint8)], axis=2)
        self.pixels = np.ascontiguousarray(px)
        self.extension = str(self.extension).upper()
        self.interpolation = str(self.interpolation).capitalize()

    @property
    def size(self) -> tuple:
        return int(self.pixels.shape[1]), int(self.pixels.shape[0])

    def validate(self) -> None:
        w, h = self.size
        if w < 1 or h < 1:
            raise SceneError(f"image '{self.name}' is empty ({w}x{h})")
        if self.extension not in IMAGE_EXTENSIONS:
            raise SceneError(f"image '{self.name}' has unsupported extension {self.extension!r}")
        if self.interpolation not in IMAGE_INTERPOLATIONS:
            raise SceneError(f"image '{self.name}' has unsupported interpolation {self.interpolation!r}")


@dataclass
class Material:
    """What the engine reads of a (Principled) material beyond the instance's flat colour.

    - ``color_image``: index into ``Scene.images`` whose RGB multiplies the instance's base
      colour (the export sets that colour to white when Base Color is the image); -1: none.
    - ``alpha`` (constant) or ``alpha_image`` (index; ``alpha_channel`` "A": the image's Alpha
      output, "LUMA": its Color output through Rec. 709 luminance, as Blender converts a colour
      linked to a float socket), times ``alpha`` when both are given.
    - ``uv_transform``: (2, 3) affine map from the mesh's UVs to the image's (a Mapping node).
    - ``alpha_mode``: "BLEND" (as Cycles: a shadow ray crossing the surface keeps 1 - alpha of
      its light; the G-buffer keeps fragments with alpha >= 0.5) or "CLIP" (alpha below
      ``alpha_threshold`` lets the ray through, the rest blocks it; the G-buffer discards the same).
    - ``transparent_shadow``: False casts the whole surface's shadow (Blender's
      ``use_transparent_shadow`` off); the G-buffer still cuts the alpha.

    A material "cuts" (:attr:`has_alpha`) when its alpha can be below 1 somewhere.
    """

    name: str
    color_image: int = -1
    alpha: float = 1.0
    alpha_image: int = -1
    alpha_channel: str = "A"
    uv_transform: np.ndarray = None
    alpha_mode: str = "BLEND"
    alpha_threshold: float = 0.5
    transparent_shadow: bool = True

    def __post_init__(self):
        self.uv_transform = (np.float32([[1, 0, 0], [0, 1, 0]]) if self.uv_transform is None
                             else _f32(self.uv_transform).reshape(2, 3))
        self.alpha_mode = str(self.alpha_mode).upper()
        self.alpha_channel = str(self.alpha_channel).upper()
        self.alpha = float(self.alpha)
        self.alpha_threshold = float(self.alpha_threshold)

    @property
    def has_alpha(self) -> bool:
        return self.alpha_image >= 0 or self.alpha < 1.0

    @property
    def textured(self) -> bool:
        return self.color_image >= 0 or self.alpha_image >= 0

    def validate(self, n_images: int) -> None:
        if self.alpha_mode not in ALPHA_MODES:
            raise SceneError(f"material '{self.name}' has unsupported alpha mode {self.alpha_mode!r}")
        if self.alpha_channel not in ALPHA_CHANNELS:
            raise SceneError(f"material '{self.name}' has unsupported alpha channel {self.alpha_channel!r}")
        for label, i in (("colour", self.color_image), ("alpha", self.alpha_image)):
            if not -1 <= int(i) < n_images:
                raise SceneError(f"material '{self.name}' refers to a missing {label} image ({i})")
        if not (np.isfinite(self.uv_transform).all() and np.isfinite([self.alpha, self.alpha_threshold]).all()):
            raise SceneError(f"material '{self.name}' has a NaN or infinite alpha or UV mapping")


# --------------------------------------------------------------------------------------------
# Lights
# --------------------------------------------------------------------------------------------
@dataclass
class Light:
    """A Blender light. Lights shine along their local -Z axis.

    ``power``: watts for point/spot/area (Blender's ``energy``), irradiance in W/m^2 for a sun
    (Blender's ``energy`` of a sun is its strength). ``radius`` is ``shadow_soft_size`` (point,
    spot); ``angle`` the sun's angular diameter; ``size``/``size_y`` the area light's extent.
    ``spot_size`` is the full cone angle in radians, ``spot_blend`` 0..1.
    """

    name: str
    type: str
    color: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    power: float = 1000.0
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    use_shadow: bool = True
    radius: float = 0.0
    angle: float = 0.0
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    size: float = 0.0
    size_y: float = 0.0
    area_shape: str = "SQUARE"
    spread: float = float(np.pi)  # area light: full angle of its emission cone (Blender's spread)

    def __post_init__(self):
        self.type = str(self.type).upper()
        self.color = _f32(self.color).reshape(3)
        self.matrix = np.asarray(self.matrix, np.float64).reshape(4, 4)

    @property
    def position(self) -> np.ndarray:
        return self.matrix[:3, 3].copy()

    @property
    def direction(self) -> np.ndarray:
        """Unit world direction the light shines towards (local -Z)."""
        d = -self.matrix[:3, 2]
        n = np.linalg.norm(d)
        return d / n if n > 0 else np.array([0.0, 0.0, -1.0])

    def validate(self) -> None:
        if self.type not in LIGHT_TYPES:
            raise SceneError(f"light '{self.name}' has unsupported type {self.type!r}")
        for label, v in (("colour", self.color), ("transform", self.matrix), ("power", self.power),
                         ("radius", self.radius), ("spot size", self.spot_size),
                         ("spot blend", self.spot_blend), ("angle", self.angle), ("spread", self.spread)):
            if not np.isfinite(np.asarray(v, np.float64)).all():
                raise SceneError(f"light '{self.name}' has a NaN or infinite {label}")
        if (np.abs(self.matrix) >= MAX_COORD).any():
            raise SceneError(f"light '{self.name}' has an infinite or absurd transform (a value beyond {MAX_COORD:.0e})")
        if not np.linalg.norm(self.matrix[:3, 2]) > 0:
            raise SceneError(f"light '{self.name}' has a zero-scale matrix (no direction)")


# --------------------------------------------------------------------------------------------
# Camera
# --------------------------------------------------------------------------------------------
@dataclass
class Camera:
    """A Blender camera. Looks down its local -Z, +Y up. ``lens`` and the sensor are in mm."""

    name: str = "Camera"
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    type: str = "PERSP"
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    ortho_scale: float = 7.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 0.1
    clip_end: float = 1000.0

    def __post_init__(self):
        self.matrix = np.asarray(self.matrix, np.float64).reshape(4, 4)
        self.type = str(self.type).upper()
        self.sensor_fit = str(self.sensor_fit).upper()

    def validate(self) -> None:
        if not np.isfinite(self.matrix).all():
            raise SceneError(f"camera '{self.name}' has a NaN or infinite transform")
        vals = [self.matrix, self.lens, self.sensor_width, self.sensor_height, self.ortho_scale,
                self.shift_x, self.shift_y, self.clip_start, self.clip_end]
        if not all(np.isfinite(np.asarray(v, np.float64)).all() for v in vals):
            raise SceneError(f"camera '{self.name}' has NaN or infinite values")
        if (np.abs(self.matrix) >= MAX_COORD).any():
            raise SceneError(f"camera '{self.name}' has an infinite or absurd transform (a value beyond {MAX_COORD:.0e})")
        if self.type not in CAMERA_TYPES:
            raise SceneError(f"camera '{self.name}' has unsupported type {self.type!r} (perspective or orthographic only)")
        if self.sensor_fit not in SENSOR_FITS:
            raise SceneError(f"camera '{self.name}' has unknown sensor fit {self.sensor_fit!r}")
        if not (0 < self.clip_start < self.clip_end):
            raise SceneError(f"camera '{self.name}' needs 0 < clip start < clip end")
        if abs(np.linalg.det(self.matrix[:3, :3])) == 0:
            raise SceneError(f"camera '{self.name}' has a zero-scale matrix")

    # -- Blender's conventions (BKE_camera_params_compute_viewplane) --------------------------
    def world_matrix_normalized(self) -> np.ndarray:
        """Camera-to-world with unit axes (Blender normalises the camera matrix for rendering)."""
        m = self.matrix.copy()
        m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
        return m

    def view_matrix(self) -> np.ndarray:
        """World-to-camera (camera looks down -Z)."""
        return np.linalg.inv(self.world_matrix_normalized())

    def viewplane(self, width: int, height: int, pixel_aspect: float = 1.0):
        """(xmin, xmax, ymin, ymax) of the view plane: at distance ``clip_start`` for a
        perspective camera, in world units for an orthographic one."""
        winx, winy = float(width), float(height)
        xasp, yasp = 1.0, float(pixel_aspect)
        ycor = yasp / xasp
        fit = self.sensor_fit
        sensor = self.sensor_height if fit == "VERTICAL" else self.sensor_width
        if fit == "AUTO":
            fit = "HORIZONTAL" if xasp * winx >= yasp * winy else "VERTICAL"
        if self.type == "ORTHO":
            pixsize = self.ortho_scale
        else:
            pixsize = sensor * self.clip_start / self.lens
        viewfac = winx if fit == "HORIZONTAL" else ycor * winy
        pixsize /= viewfac
        dx = self.shift_x * viewfac
        dy = self.shift_y * viewfac
        xmin = (-0.5 * winx + dx) * pixsize
        xmax = (0.5 * winx + dx) * pixsize
        ymin = (-0.5 * ycor * winy + dy) * pixsize
        ymax = (0.5 * ycor * winy + dy) * pixsize
        return xmin, xmax, ymin, ymax

    def projection_matrix(self, width: int, height: int) -> np.ndarray:
        """OpenGL clip-from-camera matrix (NDC z in -1..1) matching Blender's render."""
        l, r, b, t = self.viewplane(width, height)
        n, f = float(self.clip_start), float(self.clip_end)
        p = np.zeros((4, 4))
        if self.type == "ORTHO":
            p[0, 0] = 2 / (r - l)
            p[1, 1] = 2 / (t - b)
            p[2, 2] = -2 / (f - n)
            p[0, 3] = -(r + l) / (r - l)
            p[1, 3] = -(t + b) / (t - b)
            p[2, 3] = -(f + n) / (f - n)
            p[3, 3] = 1
        else:
            p[0, 0] = 2 * n / (r - l)
            p[1, 1] = 2 * n / (t - b)
            p[0, 2] = (r + l) / (r - l)
            p[1, 2] = (t + b) / (t - b)
            p[2, 2] = -(f + n) / (f - n)
            p[2, 3] = -2 * f * n / (f - n)
            p[3, 2] = -1
        return p

    def pixel_rays(self, width: int, height: int):
        """World-space primary rays through pixel centres, row 0 = top row of the image.

        Returns ``(origins, directions)``, each (H, W, 3) float64; directions are unit length.
        For an orthographic camera origins lie on the view plane at ``clip_start``.
        """
        l, r, b, t = self.viewplane(width, height)
        xs = l + (np.arange(width) + 0.5) * (r - l) / width
        ys = t - (np.arange(height) + 0.5) * (t - b) / height
        X, Y = np.meshgrid(xs, ys)
        cam = self.world_matrix_normalized()
        R, o = cam[:3, :3], cam[:3, 3]
        if self.type == "ORTHO":
            local = np.stack([X, Y, np.full_like(X, -self.clip_start)], axis=-1)
            origins = local @ R.T + o
            d = -R[:, 2] / np.linalg.norm(R[:, 2])
            dirs = np.broadcast_to(d, origins.shape).copy()
        else:
            local = np.stack([X, Y, np.full_like(X, -self.clip_start)], axis=-1)
            dirs = local @ R.T
            dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
            origins = np.broadcast_to(o, dirs.shape).copy()
        return origins, dirs


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------
@dataclass
class Scene:
    name: str = "Scene"
    models: list = field(default_factory=list)  # list[Model]
    instances: Instances = field(default_factory=Instances)
    lights: list = field(default_factory=list)  # list[Light]
    camera: Optional[Camera] = None
    world_color: np.ndarray = field(default_factory=lambda: np.float32([0.05, 0.05, 0.05]))
    resolution: tuple = (1920, 1080)
    frame: int = 1
    materials: list = field(default_factory=list)  # list[Material], see Instances.material_ids
    images: list = field(default_factory=list)  # list[Image], see Material

    def __post_init__(self):
        self.world_color = _f32(self.world_color).reshape(3)
        self.resolution = (int(self.resolution[0]), int(self.resolution[1]))

    # -- counts -------------------------------------------------------------------------------
    @property
    def triangle_count(self) -> int:
        """Triangles placed in the world (instanced triangles counted once per instance)."""
        if not len(self.instances):
            return 0
        per_model = np.array([m.triangle_count for m in self.models], np.int64)
        return int(per_model[self.instances.model_ids].sum())

    @property
    def unique_triangle_count(self) -> int:
        return int(sum(m.triangle_count for m in self.models))

    def lights_by_type(self) -> dict:
        out = {t: 0 for t in LIGHT_TYPES}
        for light in self.lights:
            out[light.type] = out.get(light.type, 0) + 1
        return out

    def alpha_models(self) -> np.ndarray:
        """(M,) bool: models shown by at least one shadow-casting instance whose material cuts
        its shadow (alpha below 1 somewhere, transparent shadows on): their triangles need UVs
        and the any-hit alpha test. An opaque scene has none."""
        out = np.zeros(len(self.models), bool)
        inst = self.instances
        if not len(inst) or not self.materials:
            return out
        cuts = np.array([m.has_alpha and m.transparent_shadow for m in self.materials] + [False])
        rows = cuts[inst.material_ids] & inst.casts_shadow & ~inst.sphere
        out[np.unique(inst.model_ids[rows])] = True
        return out

    def instance_spheres(self, idx=None):
        """World bounding spheres of instances ``idx`` (all when None): centres (N, 3) and radii
        (N,), float64."""
        inst = self.instances
        mids, mats = (inst.model_ids, inst.matrices) if idx is None else (inst.model_ids[idx], inst.matrices[idx])
        if len(mids) == 0 or not self.models:
            return np.zeros((len(mids), 3)), np.zeros(len(mids))
        centers_m = np.array([m.sphere_center for m in self.models], np.float64).reshape(-1, 3)
        radii_m = np.array([m.sphere_radius for m in self.models], np.float64)
        centers = np.einsum("nij,nj->ni", mats[:, :3, :3], centers_m[mids]) + mats[:, :3, 3]
        radii = radii_m[mids] * max_scale(mats)
        return centers, radii

    def world_bounds(self):
        """(min, max) of the world-space boxes of all instances (exact box transform), or
        ``None`` for an empty scene."""
        inst = self.instances
        if not len(inst):
            return None
        bmin = np.array([m.bounds_min for m in self.models], np.float64).reshape(-1, 3)[inst.model_ids]
        bmax = np.array([m.bounds_max for m in self.models], np.float64).reshape(-1, 3)[inst.model_ids]
        center = (bmin + bmax) * 0.5
        half = (bmax - bmin) * 0.5
        R = inst.matrices[:, :3, :3]
        wc = np.einsum("nij,nj->ni", R, center) + inst.matrices[:, :3, 3]
        wh = np.einsum("nij,nj->ni", np.abs(R), half)
        return (wc - wh).min(axis=0), (wc + wh).max(axis=0)

    # -- validation ---------------------------------------------------------------------------
    def check_transforms(self) -> "Scene":
        """Raise :class:`SceneError` naming the first object, light or camera with a NaN or
        infinite transform (what the export rejects at once; :meth:`validate` checks the rest)."""
        inst = self.instances
        if len(inst):
            bad = ~np.isfinite(inst.matrices).all(axis=(1, 2))
            if bad.any():
                raise SceneError(f"object '{inst.names[int(np.argmax(bad))]}' has a NaN or infinite transform")
        for light in self.lights:
            if not np.isfinite(light.matrix).all():
                raise SceneError(f"light '{light.name}' has a NaN or infinite transform")
        if self.camera is not None and not np.isfinite(self.camera.matrix).all():
            raise SceneError(f"camera '{self.camera.name}' has a NaN or infinite transform")
        return self

    def validate(self, require_camera: bool = True) -> "Scene":
        """Raise :class:`SceneError` naming the first unusable object; return self."""
        for m in self.models:
            m.validate()
        inst = self.instances
        n = len(inst)
        if n:
            if inst.model_ids.min() < 0 or inst.model_ids.max() >= len(self.models):
                bad = int(np.nonzero((inst.model_ids < 0) | (inst.model_ids >= len(self.models)))[0][0])
                raise SceneError(f"object '{inst.names[bad]}' refers to a missing mesh")
        self.check_transforms()
        if n:
            huge = (np.abs(inst.matrices) >= MAX_COORD).any(axis=(1, 2))
            if huge.any():  # Blender clamps an infinite scale/location to FLT_MAX: still unusable
                raise SceneError(f"object '{inst.names[int(np.argmax(huge))]}' has an infinite or absurd transform "
                                 f"(a value beyond {MAX_COORD:.0e})")
            bad_i = ~np.isfinite(inst.inverse).all(axis=(1, 2))
            if bad_i.any():
                raise SceneError(f"object '{inst.names[int(np.argmax(bad_i))]}' has a zero scale (its transform cannot be inverted)")
            if inst.material_ids.min() < -1 or inst.material_ids.max() >= len(self.materials):
                bad = int(np.nonzero((inst.material_ids < -1) | (inst.material_ids >= len(self.materials)))[0][0])
                raise SceneError(f"object '{inst.names[bad]}' refers to a missing material")
            for label, arr in (("colour", inst.base_color), ("specular", inst.specular)):
                bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
                if bad.any():
                    raise SceneError(f"object '{inst.names[int(np.argmax(bad))]}' has a NaN or infinite {label}")
        for img in self.images:
            img.validate()
        for mat in self.materials:
            mat.validate(len(self.images))
        if n and self.materials:
            for m in np.unique(inst.model_ids[inst.material_ids >= 0]).tolist():
                rows = np.nonzero((inst.model_ids == m) & (inst.material_ids >= 0))[0]
                if self.models[m].uvs is None and any(self.materials[k].textured for k in inst.material_ids[rows].tolist()):
                    raise SceneError(f"object '{inst.names[int(rows[0])]}' has a textured material but its mesh "
                                     f"'{self.models[m].name}' has no UV map")
        for light in self.lights:
            light.validate()
        if self.camera is None:
            if require_camera:
                raise SceneError(f"scene '{self.name}' has no camera")
        else:
            self.camera.validate()
        if not np.isfinite(self.world_color).all():
            raise SceneError(f"scene '{self.name}' has a NaN or infinite world colour")
        w, h = self.resolution
        if w <= 0 or h <= 0:
            raise SceneError(f"scene '{self.name}' has resolution {w}x{h}; both sides must be at least 1")
        return self

    # -- summary (CLI `info`) -----------------------------------------------------------------
    def summary(self) -> dict:
        b = self.world_bounds()
        return {
            "scene": self.name,
            "frame": self.frame,
            "resolution": list(self.resolution),
            "instances": len(self.instances),
            "shadow_casters": int(self.instances.casts_shadow.sum()) if len(self.instances) else 0,
            "sphere_primitives": int(self.instances.sphere.sum()) if len(self.instances) else 0,
            "models": len(self.models),
            "triangles": self.triangle_count,
            "unique_triangles": self.unique_triangle_count,
            "lights": self.lights_by_type(),
            "shadowed_lights": sum(1 for l in self.lights if l.use_shadow),
            "materials": len(self.materials),
            "images": len(self.images),
            "alpha_models": int(self.alpha_models().sum()),
            "camera": None if self.camera is None else {"name": self.camera.name, "type": self.camera.type},
            "world_bounds": None if b is None else {"min": [float(x) for x in b[0]], "max": [float(x) for x in b[1]]},
        }
