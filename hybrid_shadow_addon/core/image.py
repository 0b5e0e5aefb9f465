"""Image encoding: linear float to 8-bit sRGB, and a dependency-free PNG writer."""
from __future__ import annotations

import struct
import zlib

import numpy as np


def to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear float (H, W, 3|4) -> uint8 sRGB (standard piecewise OETF); alpha stays linear."""
    img = np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    rgb = np.clip(img[..., :3], 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    out = np.empty(img.shape, np.uint8)
    out[..., :3] = np.round(srgb * 255.0)
    if img.shape[-1] == 4:
        out[..., 3] = np.round(np.clip(img[..., 3], 0.0, 1.0) * 255.0)
    return out


def write_png(path, rgba8: np.ndarray) -> None:
    """Write uint8 (H, W, 3|4) (row 0 = top) as a PNG with zlib + struct only."""
    a = np.ascontiguousarray(rgba8, np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    h, w, c = a.shape
    color_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    raw = np.concatenate([np.zeros((h, 1), np.uint8), a.reshape(h, w * c)], axis=1).tobytes()

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)
