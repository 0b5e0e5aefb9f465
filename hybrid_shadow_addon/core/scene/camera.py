"""A Blender camera: perspective or orthographic, with Blender's sensor fit, shift and clip range."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from .arrays import MAX_COORD

CAMERA_TYPES = ("PERSP", "ORTHO")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


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
        """Raise :class:`SceneError` for non-finite values, unknown type or fit, a bad clip range or a zero scale."""
        if not np.isfinite(self.matrix).all():
            raise SceneError(f"camera '{self.name}' has a NaN or infinite transform")
        vals = [self.matrix, self.lens, self.sensor_width, self.sensor_height, self.ortho_scale,
                self.shift_x, self.shift_y, self.clip_start, self.clip_end]
        if not all(np.isfinite(np.asarray(v, np.float64)).all() for v in vals):
            raise SceneError(f"camera '{self.name}' has NaN or infinite values")
        if (np.abs(self.matrix) >= MAX_COORD).any():
            raise SceneError(f"camera '{self.name}' has an infinite or absurd transform "
                             f"(a value beyond {MAX_COORD:.0e})")
        if self.type not in CAMERA_TYPES:
            raise SceneError(f"camera '{self.name}' has unsupported type {self.type!r} "
                             "(perspective or orthographic only)")
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
        left, right, bottom, top = self.viewplane(width, height)
        n, f = float(self.clip_start), float(self.clip_end)
        p = np.zeros((4, 4))
        if self.type == "ORTHO":
            p[0, 0] = 2 / (right - left)
            p[1, 1] = 2 / (top - bottom)
            p[2, 2] = -2 / (f - n)
            p[0, 3] = -(right + left) / (right - left)
            p[1, 3] = -(top + bottom) / (top - bottom)
            p[2, 3] = -(f + n) / (f - n)
            p[3, 3] = 1
        else:
            p[0, 0] = 2 * n / (right - left)
            p[1, 1] = 2 * n / (top - bottom)
            p[0, 2] = (right + left) / (right - left)
            p[1, 2] = (top + bottom) / (top - bottom)
            p[2, 2] = -(f + n) / (f - n)
            p[2, 3] = -2 * f * n / (f - n)
            p[3, 2] = -1
        return p

    def pixel_rays(self, width: int, height: int):
        """World-space primary rays through pixel centres, row 0 = top row of the image.

        Returns ``(origins, directions)``, each (H, W, 3) float64; directions are unit length.
        For an orthographic camera origins lie on the view plane at ``clip_start``.
        """
        left, right, bottom, top = self.viewplane(width, height)
        xs = left + (np.arange(width) + 0.5) * (right - left) / width
        ys = top - (np.arange(height) + 0.5) * (top - bottom) / height
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
