"""numpy mirror of Cycles' shadow terminator (``light/sample.h``): the lift of a smooth-shaded
triangle's point towards the smooth surface its corner normals describe
(``shadow_ray_smooth_surface_offset``), computed from the triangles themselves in float64, so
tests can check what the G-buffer's ``TERMINATOR`` writes."""
from __future__ import annotations

import numpy as np


def world_corner_normals(normals: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    """(N, 3, 3) unit world corner normals: model corner normals ``normals`` (N, 3, 3) through
    the inverse transpose of world ``matrices`` (N, 4, 4)."""
    inv_t = np.transpose(np.linalg.inv(matrices[:, :3, :3]), (0, 2, 1))
    n = np.einsum("nij,nkj->nki", inv_t, normals.astype(np.float64))
    length = np.linalg.norm(n, axis=2, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)


def smooth_surface_offset(v: np.ndarray, n: np.ndarray, bary: np.ndarray, ng: np.ndarray) -> np.ndarray:
    """(N, 3) lift of points with barycentrics ``bary`` (N, 3: the weights of corners 0, 1, 2)
    on triangles of corners ``v`` (N, 3, 3) and unit corner normals ``n`` (N, 3, 3), whose
    geometric normal turned towards the viewer is ``ng`` (N, 3): Cycles' parabolic fit of the
    smooth surface, bounded by the corners' tangent planes, along the interpolated normal."""
    v = np.asarray(v, np.float64)
    n = np.asarray(n, np.float64)
    u, w1, w2 = (np.asarray(bary, np.float64)[:, k] for k in range(3))

    def dot(a, b):
        return (a * b).sum(axis=-1)

    p = v[:, 0] * u[:, None] + v[:, 1] * w1[:, None] + v[:, 2] * w2[:, None]
    ni = n[:, 0] * u[:, None] + n[:, 1] * w1[:, None] + n[:, 2] * w2[:, None]
    a = dot(n[:, 2] - n[:, 0], v[:, 0] - v[:, 2])
    b = dot(n[:, 2] - n[:, 1], v[:, 1] - v[:, 2])
    c = dot(n[:, 1] - n[:, 0], v[:, 1] - v[:, 0])
    h = a * u * (u - 1) + (a + b + c) * u * w1 + b * w1 * (w1 - 1)
    others = ((1, 2), (0, 2), (0, 1))
    outward = dot(ni, np.asarray(ng, np.float64)) > 0
    # the same side as the interpolated normal: the lowest of the corners' tangent-plane heights
    up = [np.maximum(dot(v[:, k] - p, n[:, k]) + np.maximum(np.maximum(
        dot(v[:, i] - v[:, k], n[:, k]), dot(v[:, j] - v[:, k], n[:, k])), 0), 0)
        for k, (i, j) in enumerate(others)]
    down = [np.maximum(dot(p - v[:, k], n[:, k]) + np.maximum(np.maximum(
        dot(v[:, k] - v[:, i], n[:, k]), dot(v[:, k] - v[:, j], n[:, k])), 0), 0)
        for k, (i, j) in enumerate(others)]
    h = np.where(outward, np.maximum(np.minimum.reduce(up), h * 0.5), np.minimum(-np.minimum.reduce(down), h * 0.5))
    return ni * h[:, None]
