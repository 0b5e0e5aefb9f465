"""Image pixels as stored, for the textures of the scene model."""
from __future__ import annotations

import numpy as np


def _is_srgb(image) -> bool:
    """Whether the stored (byte) colour values are sRGB-encoded. Float images are kept in scene
    linear by Blender whatever their file's colour space."""
    cs = image.colorspace_settings
    if image.is_float or getattr(cs, "is_data", False):
        return False
    name = cs.name.lower()
    return name.startswith("srgb") and "linear" not in name


def image_pixels(image) -> tuple | None:
    """``(pixels (H, W, C) uint8, srgb)`` of an image as stored (row 0 at the bottom), via
    ``pixels.foreach_get``; None when it has no pixels (a missing file)."""
    try:
        w, h = (int(x) for x in image.size)
        ch = int(image.channels)
        if w < 1 or h < 1 or ch not in (1, 3, 4):
            return None
        buf = np.empty(w * h * ch, np.float32)
        image.pixels.foreach_get(buf)
    except (RuntimeError, ReferenceError, ValueError, TypeError):
        return None
    buf = np.fmin(np.fmax(buf, 0.0), 1.0)  # NaN -> 0
    px = (buf * 255.0 + 0.5).astype(np.uint8).reshape(h, w, ch)
    if ch == 4 and getattr(image, "alpha_mode", "STRAIGHT") == "NONE":
        px[..., 3] = 255
    return px, _is_srgb(image)

