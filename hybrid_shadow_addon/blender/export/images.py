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


class PixelCache:
    """The viewport's image pixels between exports: while :attr:`active`, :func:`image_pixels`
    reads an image once and again only after :meth:`forget` (the viewport forgets the images its
    depsgraph updates name) or when its size, channels, alpha mode, colour space or file differ.
    Final renders read every image afresh."""

    def __init__(self):
        self.active = False
        self._entries: dict = {}  # image pointer -> (key, image_pixels())
        self.reads = 0  # images read through foreach_get while active

    @staticmethod
    def key(image) -> tuple:
        cs = getattr(getattr(image, "colorspace_settings", None), "name", "")
        return (image.name_full, tuple(image.size), int(image.channels), getattr(image, "alpha_mode", ""), cs,
                getattr(image, "filepath_raw", ""), getattr(image, "source", ""))

    def get(self, image):
        hit = self._entries.get(image.as_pointer())
        return hit[1] if hit is not None and hit[0] == self.key(image) else None

    def put(self, image, value) -> None:
        self._entries[image.as_pointer()] = (self.key(image), value)
        self.reads += 1

    def forget(self, image=None) -> None:
        """Forget ``image`` (every image when None)."""
        if image is None:
            self._entries.clear()
        else:
            self._entries.pop(image.as_pointer(), None)


PIXELS = PixelCache()


def image_pixels(image) -> tuple | None:
    """``(pixels (H, W, C), srgb)`` of an image as stored (row 0 at the bottom): uint8 bytes, or
    float32 in [0, 1] for a float or 16-bit image (``Image.is_float``); via
    ``pixels.foreach_get``; None when it has no pixels (a missing file). Through :data:`PIXELS`
    while it is active."""
    if PIXELS.active:
        try:
            hit = PIXELS.get(image)
        except (ReferenceError, AttributeError):
            hit = None
        if hit is not None:
            return hit
        value = _read_pixels(image)
        if value is not None:
            PIXELS.put(image, value)
        return value
    return _read_pixels(image)


def _read_pixels(image) -> tuple | None:
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
    if image.is_float:  # (float and 16-bit files): kept as float, so an alpha keeps its threshold
        px = buf.reshape(h, w, ch)
        one = 1.0
    else:
        px = (buf * 255.0 + 0.5).astype(np.uint8).reshape(h, w, ch)
        one = 255
    if ch == 4 and getattr(image, "alpha_mode", "STRAIGHT") == "NONE":
        px[..., 3] = one
    return px, _is_srgb(image)

