"""Light-space projections shared by the shadow-map and conservative-map passes."""
from __future__ import annotations

import numpy as np

CUBE_AXES = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))


def ortho(left, right, bottom, top, n, f) -> np.ndarray:
    p = np.zeros((4, 4))
    p[0, 0], p[1, 1], p[2, 2] = 2 / (right - left), 2 / (top - bottom), -2 / (f - n)
    p[0, 3], p[1, 3], p[2, 3], p[3, 3] = (-(right + left) / (right - left), -(top + bottom) / (top - bottom),
                                          -(f + n) / (f - n), 1)
    return p


def perspective(tan_half, n, f) -> np.ndarray:
    p = np.zeros((4, 4))
    p[0, 0] = p[1, 1] = 1.0 / tan_half
    p[2, 2], p[2, 3], p[3, 2] = -(f + n) / (f - n), -2 * f * n / (f - n), -1
    return p


def look_basis(forward, up_hint) -> np.ndarray:
    """3x3 with columns right, up, back (camera convention: looks down -Z) for ``forward``."""
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    up = np.asarray(up_hint, np.float64)
    up = up - f * (up @ f)
    if np.linalg.norm(up) < 1e-6:
        alt = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        up = alt - f * (alt @ f)
    up /= np.linalg.norm(up)
    back = -f
    right = np.cross(up, back)
    return np.stack([right, up, back], axis=1)


def view_from_rel(basis, origin_rel) -> np.ndarray:
    v = np.eye(4)
    v[:3, :3] = basis.T
    v[:3, 3] = -basis.T @ origin_rel
    return v
