"""Float32 ray primitives shared by every oracle walk, in the order the GLSL evaluates them.

Ray preparation and the per-instance transform, the watertight triangle test (plain and with
barycentrics), the analytic sphere test and its conservative pre-test, and the robust slab test.
"""
from __future__ import annotations

import numpy as np

from ...bake.textures import FLT_BIG

F = np.float32
SLAB_BIG = F(1e30)  # 1/d for d == 0 in the slab test
TFAR_SCALE = F(1.0 + 2.0 ** -20)
PRETEST_EPS = F(2.0 ** -18)


def prepare_rays(origins, dirs, tmax):
    """Float32 rays ``(o, d, tmax, valid)``: tmax clamped to FLT_BIG, NaN tmax as 0; ``valid``
    is False for a zero direction, tmax <= 0 or a non-finite origin or direction."""
    o = np.ascontiguousarray(np.asarray(origins, np.float64).reshape(-1, 3), F)
    d = np.ascontiguousarray(np.asarray(dirs, np.float64).reshape(-1, 3), F)
    t = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),)).astype(np.float64)
    t = np.where(np.isnan(t), 0.0, np.minimum(t, float(FLT_BIG))).astype(F)
    valid = (d != 0).any(axis=1) & (t > 0) & np.isfinite(o).all(axis=1) & np.isfinite(d).all(axis=1)
    return o, d, t, valid


def bake_space(baked, points) -> np.ndarray:
    """World points (N, 3) in the baked scene's space (float64)."""
    return np.asarray(points, np.float64).reshape(-1, 3) - baked.origin


def transform_rays(rows: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Model-space rays: ``rows`` (P, 12) float32 = rows 0..2 of the inverse world matrix."""
    r = rows.reshape(-1, 3, 4)
    om = ((r[:, :, 0] * o[:, None, 0] + r[:, :, 1] * o[:, None, 1]) + r[:, :, 2] * o[:, None, 2]) + r[:, :, 3]
    dm = (r[:, :, 0] * d[:, None, 0] + r[:, :, 1] * d[:, None, 1]) + r[:, :, 2] * d[:, None, 2]
    return om.astype(F), dm.astype(F)


def woop_setup(d: np.ndarray):
    """Watertight test set-up per ray: axis permutation (kx, ky, kz) and shear (Sx, Sy, Sz)."""
    a = np.abs(d)
    kz = np.where(a[:, 0] > a[:, 1], np.where(a[:, 0] > a[:, 2], 0, 2), np.where(a[:, 1] > a[:, 2], 1, 2))
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    n = np.arange(len(d))
    dz = d[n, kz]
    swap = dz < 0
    kx, ky = np.where(swap, ky, kx), np.where(swap, kx, ky)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = d[n, kx] / dz
        sy = d[n, ky] / dz
        sz = F(1.0) / dz
    return kx, ky, kz, sx.astype(F), sy.astype(F), sz.astype(F)


TFLOOR = F(2.0 ** -19)  # the BVH walk's nearest hit, x the vertices' reach along the ray axis


def _woop(o, setup, v0, v1, v2, tmax, floor: bool):
    """The watertight test's float32 values: ``(hit, U, V, W, T, det)``."""
    kx, ky, kz, sx, sy, sz = setup
    n = np.arange(len(o))
    A = (v0 - o).astype(F)
    B = (v1 - o).astype(F)
    C = (v2 - o).astype(F)
    Akz, Bkz, Ckz = A[n, kz], B[n, kz], C[n, kz]
    Ax = A[n, kx] - sx * Akz
    Ay = A[n, ky] - sy * Akz
    Bx = B[n, kx] - sx * Bkz
    By = B[n, ky] - sy * Bkz
    Cx = C[n, kx] - sx * Ckz
    Cy = C[n, ky] - sy * Ckz
    U = Cx * By - Cy * Bx
    V = Ax * Cy - Ay * Cx
    W = Bx * Ay - By * Ax
    inside = ~(((U < 0) | (V < 0) | (W < 0)) & ((U > 0) | (V > 0) | (W > 0)))
    det = U + V + W
    T = (U * (sz * Akz) + V * (sz * Bkz)) + W * (sz * Ckz)
    with np.errstate(over="ignore", invalid="ignore"):
        td = tmax * det
        lo = np.zeros_like(det)
        if floor:
            lo = (TFLOOR * np.maximum(np.maximum(np.abs(Akz), np.abs(Bkz)), np.abs(Ckz)) * np.abs(sz)).astype(F)
            lo = (lo * det).astype(F)
        pos = (det > 0) & (T > lo) & (T < td)
        neg = (det < 0) & (T < lo) & (T > td)
    return inside & (pos | neg), U, V, W, T, det


def woop_hit(o, setup, v0, v1, v2, tmax, floor: bool = False) -> np.ndarray:
    """Watertight ray/triangle (Woop, Benthin, Wald 2013), double-sided, hit iff t in (0, tmax);
    with ``floor`` (the BVH walk, ``scene_bvh.glsl``) only beyond ``TFLOOR * max|v_kz - o_kz| *
    |Sz|``, the float32 error of t, so that a huge triangle never shadows its own surface.
    All arguments broadcast per pair: o (P,3), setup arrays (P,), v* (P,3), tmax (P,)."""
    return _woop(o, setup, v0, v1, v2, tmax, floor)[0]


def woop_hit_bary(o, setup, v0, v1, v2, tmax, floor: bool = False):
    """:func:`woop_hit` (same float32 operations, same ``floor`` semantics, the same hits) that
    also returns the hit's barycentric weights and distance.

    Returns ``(hit (P,) bool, bary (P, 3) float64, t (P,) float64)``: ``bary`` = (U, V, W) / det,
    the weights of v0, v1, v2 (U = Cx By - Cy Bx, ...), non-negative and summing to 1; ``t`` =
    T / det in units of |d| (U, V, W, T are the test's float32 values; det = U + V + W is summed
    in float64 so the weights sum to 1). Both are 0 where there is no hit."""
    hit, U, V, W, T, _ = _woop(o, setup, v0, v1, v2, tmax, floor)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        uvw = np.stack([U, V, W], axis=1).astype(np.float64)
        dd = np.where(hit, uvw.sum(axis=1), 1.0)  # det in float64: the weights sum to 1
        bary = uvw / dd[:, None]
        t = T.astype(np.float64) / dd
    bary = np.where(hit[:, None], bary, 0.0)
    t = np.where(hit, t, 0.0)
    return hit, bary, t


def sphere_hit(o, d, c, r, tmax) -> np.ndarray:
    """Ray/sphere surface hit with t in (0, tmax) (Ray Tracing Gems ch. 7, unnormalised d)."""
    f = (o - c).astype(F)
    a = (d * d).sum(axis=1, dtype=F)
    b = -(f * d).sum(axis=1, dtype=F)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        perp = f + (b / a)[:, None] * d
        rr = r * r
        disc = rr - (perp * perp).sum(axis=1, dtype=F)
        cc = (f * f).sum(axis=1, dtype=F) - rr
        sq = np.sqrt(np.maximum(a * disc, F(0)))
        q = b + np.where(b >= 0, sq, -sq)
        t0 = cc / q
        t1 = q / a
        ok = (disc >= 0) & (q != 0)
        hit = ((t0 > 0) & (t0 < tmax)) | ((t1 > 0) & (t1 < tmax))
    return ok & hit


def sphere_pretest(o, d, c, r, tmax) -> np.ndarray:
    """Conservative: does segment o + t d, t in [0, tmax], come within r of c?"""
    f = (o - c).astype(F)
    a = (d * d).sum(axis=1, dtype=F)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tc = np.clip(-(f * d).sum(axis=1, dtype=F) / a, F(0), tmax)
        p = f + tc[:, None] * d
        e = PRETEST_EPS * (np.abs(f).sum(axis=1, dtype=F) + tc * np.abs(d).sum(axis=1, dtype=F))
        re = r + e
        return (p * p).sum(axis=1, dtype=F) <= re * re


def slab_inv(d: np.ndarray) -> np.ndarray:
    """1/d per component for the slab test, ``SLAB_BIG`` where d == 0."""
    with np.errstate(divide="ignore"):
        return np.where(d != 0, F(1.0) / np.where(d != 0, d, F(1)), SLAB_BIG).astype(F)


def slab_span_hit(t1, t2, tmax) -> np.ndarray:
    """Whether the ray's span between the slabs' entry and exit ``t1``/``t2`` (N, 3) meets
    [0, tmax] (conservative: far t scaled by 1 + 2^-20)."""
    with np.errstate(invalid="ignore"):
        tn = np.minimum(t1, t2).max(axis=1)
        tf = np.maximum(t1, t2).min(axis=1) * TFAR_SCALE
    return np.maximum(tn, F(0)) <= np.minimum(tf, tmax)


def slab_hit(o, inv, bmin, bmax, tmax) -> np.ndarray:
    """Robust slab test of rays ``o`` (reciprocal directions ``inv``) against boxes."""
    with np.errstate(over="ignore", invalid="ignore"):
        return slab_span_hit((bmin - o) * inv, (bmax - o) * inv, tmax)


def ragged_pairs(starts, counts):
    """Flatten runs ``starts[i] .. starts[i] + counts[i]``: ``(owner, index)``, one row per element."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    owner = np.repeat(np.arange(len(counts)), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return owner, np.asarray(starts, np.int64)[owner] + np.arange(total) - first[owner]

