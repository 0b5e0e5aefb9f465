"""Image textures and the materials that read them: colour and the alpha of cut-out surfaces."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError
from .arrays import as_f32

IMAGE_EXTENSIONS = ("REPEAT", "EXTEND", "CLIP", "MIRROR")
IMAGE_INTERPOLATIONS = ("Linear", "Closest", "Cubic")
ALPHA_MODES = ("BLEND", "CLIP")
ALPHA_CHANNELS = ("A", "LUMA")
#: Rec. 709 luminance (Blender's default scene-linear space): a Color socket linked to a float one
LUMA = (0.2126, 0.7152, 0.0722)


@dataclass
class Image:
    """An image texture as Blender stores it: ``pixels`` (H, W, 4) RGBA, row 0 at the bottom
    (v = 0), uint8 bytes or, for a float or 16-bit image, float32 in [0, 1]; the stored values
    (``srgb``: the colour channels are sRGB-encoded and are decoded for the albedo; alpha is
    always linear).

    Sampling rule (the GPU and the numpy oracle both follow it): texel (i, j) has its centre at
    ``((i + 0.5) / W, (j + 0.5) / H)``; ``"Linear"`` blends the 4 nearest texels bilinearly,
    ``"Closest"`` takes ``floor(u W), floor(v H)``, ``"Cubic"`` weighs the 4x4 nearest with
    Cycles' cubic B-spline (its Cubic and Smart); outside [0, 1) ``"REPEAT"`` wraps, ``"EXTEND"``
    clamps to the edge texel, ``"MIRROR"`` reflects, ``"CLIP"`` reads transparent black. Alpha
    is read so, at level 0 (Cycles reads the image itself at a hit); the albedo is mip mapped,
    bilinear in place of cubic.
    """

    name: str
    pixels: np.ndarray
    srgb: bool = True
    extension: str = "REPEAT"
    interpolation: str = "Linear"

    def __post_init__(self):
        px = np.asarray(self.pixels)
        if px.dtype != np.uint8:  # float values in [0, 1] (NaN: 0), kept unquantised
            with np.errstate(invalid="ignore"):
                px = np.clip(np.nan_to_num(px.astype(np.float32)), 0.0, 1.0).astype(np.float32)
        if px.ndim == 2:
            px = px[:, :, None]
        if px.ndim != 3 or px.shape[2] not in (1, 3, 4):
            raise SceneError(f"image '{self.name}' has pixels of shape {px.shape}; expected (H, W, 4)")
        one = 255 if px.dtype == np.uint8 else 1.0
        if px.shape[2] == 1:
            px = np.concatenate([np.repeat(px, 3, axis=2), np.full(px.shape[:2] + (1,), one, px.dtype)], axis=2)
        elif px.shape[2] == 3:
            px = np.concatenate([px, np.full(px.shape[:2] + (1,), one, px.dtype)], axis=2)
        self.pixels = np.ascontiguousarray(px)
        self.extension = str(self.extension).upper()
        self.interpolation = str(self.interpolation).capitalize()

    @property
    def is_float(self) -> bool:
        """Whether the pixels are float32 (a float or 16-bit image: kept so, so that an alpha
        compared with a threshold is not shifted by a quantisation), else uint8 bytes."""
        return self.pixels.dtype != np.uint8

    def values(self) -> np.ndarray:
        """(H, W, 4) float64 stored values in [0, 1] (bytes / 255, or the floats)."""
        px = self.pixels.astype(np.float64)
        return px if self.is_float else px / 255.0

    @property
    def size(self) -> tuple:
        """``(width, height)`` in texels."""
        return int(self.pixels.shape[1]), int(self.pixels.shape[0])

    def validate(self) -> None:
        """Raise :class:`SceneError` for an empty image or an unsupported extension or interpolation."""
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
                             else as_f32(self.uv_transform).reshape(2, 3))
        self.alpha_mode = str(self.alpha_mode).upper()
        self.alpha_channel = str(self.alpha_channel).upper()
        self.alpha = float(self.alpha)
        self.alpha_threshold = float(self.alpha_threshold)

    @property
    def has_alpha(self) -> bool:
        """Whether the alpha can be below 1 somewhere (the material cuts)."""
        return self.alpha_image >= 0 or self.alpha < 1.0

    @property
    def textured(self) -> bool:
        """Whether the material reads an image (its mesh then needs UVs)."""
        return self.color_image >= 0 or self.alpha_image >= 0

    def validate(self, n_images: int) -> None:
        """Raise :class:`SceneError` for unknown modes, missing images or non-finite values."""
        if self.alpha_mode not in ALPHA_MODES:
            raise SceneError(f"material '{self.name}' has unsupported alpha mode {self.alpha_mode!r}")
        if self.alpha_channel not in ALPHA_CHANNELS:
            raise SceneError(f"material '{self.name}' has unsupported alpha channel {self.alpha_channel!r}")
        for label, i in (("colour", self.color_image), ("alpha", self.alpha_image)):
            if not -1 <= int(i) < n_images:
                raise SceneError(f"material '{self.name}' refers to a missing {label} image ({i})")
        if not (np.isfinite(self.uv_transform).all() and np.isfinite([self.alpha, self.alpha_threshold]).all()):
            raise SceneError(f"material '{self.name}' has a NaN or infinite alpha or UV mapping")
