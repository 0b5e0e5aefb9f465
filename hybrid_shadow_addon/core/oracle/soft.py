"""The numpy reference of soft shadows: the weighted share of an extended light a surface point
sees, by many stratified samples of the same light distributions as
``shaders/common/soft_light.glsl`` (a sun's disk of directions, a sphere light's cone, an area
light's rectangle or ellipse) with the same weights (a spot's cone seen from each point of it),
each traced by ``visibility_brute`` (alpha included). Independent of the GPU's sample sequence: it
converges to the exact fraction."""
from __future__ import annotations

import numpy as np

from ..gpu.lights import soft_shape, spread_attenuation
from .tracer import visibility_brute


def concentric(u: np.ndarray) -> np.ndarray:
    a = 2.0 * u - 1.0
    out = np.zeros_like(a)
    nz = (a[:, 0] != 0) | (a[:, 1] != 0)
    x, y = a[nz, 0], a[nz, 1]
    big = np.abs(x) > np.abs(y)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(big, x, y)
        phi = np.where(big, np.pi / 4 * (y / x), np.pi / 2 - np.pi / 4 * (x / y))
    out[nz] = r[:, None] * np.stack([np.cos(phi), np.sin(phi)], 1)
    return out


def spot_weight(light, light_to_p: np.ndarray) -> np.ndarray:
    """A spot's cone and blend for the directions ``light_to_p`` (rows), as
    ``shaders/common/soft_light.glsl``'s ``hs_spot_weight``; 1 for any other light."""
    if light.type != "SPOT":
        return np.ones(len(light_to_p))
    t = (light_to_p @ np.asarray(light.direction, np.float64)) / np.linalg.norm(light_to_p, axis=1)
    ch, blend = np.cos(light.spot_size / 2), max(float(light.spot_blend), 0.0)
    if blend > 0:
        x = np.clip((t - ch) / ((1.0 - ch) * blend), 0.0, 1.0)
        return x * x * (3.0 - 2.0 * x)
    return (t > ch).astype(np.float64)


def _sphere_rays(light, r: float, o, n, w0, dr):
    """Rays from ``o`` along unit directions ``dr`` (within the cone the sphere light subtends;
    ``w0`` towards its centre) to its nearest point, and their weights."""
    dist = np.linalg.norm(w0, axis=1)
    b = (dr * w0).sum(1)
    th = b - np.sqrt(np.maximum(0.0, r * r - (dist ** 2 - b * b)))
    d = dr * np.maximum(th, 0.0)[:, None]
    w = np.maximum((n * dr).sum(1), 0.0) * spot_weight(light, -dr)
    inside = dist <= r
    d[inside] = w0[inside]
    w[inside] = 1.0
    return d, np.ones(len(o)), w


def _point_rays(light, soft, o, n, c):
    """Rays from ``o`` towards the light's points ``c`` (shape 0: the sun's unit disk of
    directions; 2: the rectangle's [-1, 1]^2; 3: the ellipse's unit disk) and their weights."""
    u, v = np.asarray(soft["u_light_u"]), np.asarray(soft["u_light_v"])
    if soft["shape"] == 0:
        d = -np.asarray(light.direction, np.float64) + c[:, :1] * u + c[:, 1:] * v
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d, np.full(len(o), np.inf), np.maximum((n * d).sum(1), 0.0)
    d = np.asarray(light.position, np.float64) + c[:, :1] * u + c[:, 1:] * v - o
    l2 = (d * d).sum(1)
    axis = np.asarray(light.direction, np.float64)
    w = np.maximum((n * d).sum(1), 0.0) * np.maximum(-(d @ axis), 0.0) / np.maximum(l2 * l2, 1e-30)
    tan_h, norm = soft["u_light_spread"]
    w = w * spread_attenuation(-(d @ axis) / np.sqrt(np.maximum(l2, 1e-30)), tan_h, norm)
    return d, np.ones(len(o)), w


def light_samples(light, o: np.ndarray, n: np.ndarray, xi: np.ndarray):
    """Rays ``(d, tmax, w)`` from points ``o`` (normals ``n``) through sample points ``xi``
    (one (2,) point per row) of the extended light; the hard light's one ray when it has none."""
    soft = soft_shape(light)
    o = np.asarray(o, np.float64)
    n = np.asarray(n, np.float64)
    if soft is None:
        if light.type == "SUN":
            d = np.broadcast_to(-np.asarray(light.direction, np.float64), o.shape)
            tmax = np.full(len(o), np.inf)
        else:
            d = np.asarray(light.position, np.float64) - o
            tmax = np.ones(len(o))
        return d, tmax, np.maximum((n * d).sum(1), 0.0)
    shape = soft["shape"]
    if shape == 1:
        r = soft["u_light_radius"]
        w0 = np.asarray(light.position, np.float64) - o
        dist = np.linalg.norm(w0, axis=1)
        ax = w0 / dist[:, None]
        cos_max = np.sqrt(np.maximum(0.0, 1.0 - (r / dist) ** 2))
        ct = 1.0 - xi[:, 0] * (1.0 - cos_max)
        st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
        phi = 2 * np.pi * xi[:, 1]
        ref = np.where((np.abs(ax[:, 0]) > 0.5)[:, None], [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        t1 = np.cross(ax, ref)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(ax, t1)
        dr = ct[:, None] * ax + st[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
        return _sphere_rays(light, r, o, n, w0, dr)
    return _point_rays(light, soft, o, n, 2.0 * xi - 1.0 if shape == 2 else concentric(xi))


#: how far inside the light ``light_top`` stays (as ``hs_light_top``)
TOP_INSIDE = 0.999


def light_top(light, o: np.ndarray, n: np.ndarray):
    """The ray ``(d, tmax, w)`` from each ``o`` to the extended light's point highest above its
    horizon (``shaders/common/soft_light.glsl``'s ``hs_light_top``): what decides a pixel none of
    whose samples had a weight."""
    soft = soft_shape(light)
    o = np.asarray(o, np.float64)
    n = np.asarray(n, np.float64)
    if soft["shape"] == 1:
        r = soft["u_light_radius"]
        w0 = np.asarray(light.position, np.float64) - o
        dist2 = (w0 * w0).sum(1)
        ax = w0 / np.sqrt(dist2)[:, None]
        q = n - ax * (n * ax).sum(1, keepdims=True)
        lq = np.linalg.norm(q, axis=1)
        sb = TOP_INSIDE * np.sqrt(np.minimum(r * r / dist2, 1.0))
        side = np.where((lq > 1e-12)[:, None], q / np.where(lq > 1e-12, lq, 1.0)[:, None], 0.0)
        dr = np.where((lq > 1e-12)[:, None], np.sqrt(1.0 - sb * sb)[:, None] * ax + sb[:, None] * side, ax)
        return _sphere_rays(light, r, o, n, w0, dr)
    g = np.stack([n @ np.asarray(soft["u_light_u"]), n @ np.asarray(soft["u_light_v"])], 1)
    if soft["shape"] == 2:
        c = TOP_INSIDE * np.sign(g)
    else:
        lg = np.linalg.norm(g, axis=1, keepdims=True)
        c = np.where(lg > 0, TOP_INSIDE * g / np.where(lg > 0, lg, 1.0), 0.0)
    return _point_rays(light, soft, o, n, c)


def soft_visibility(scene, light_index: int, origins, normals, samples: int = 256, seed: int = 0) -> np.ndarray:
    """(N,) weighted share of light ``light_index`` that each origin sees (origins already off
    the surface): jittered stratified samples on a g x g grid of the light's unit square,
    g = ceil(sqrt(samples)), each point its own jitter. Where no sample has a weight, the ray to
    the light's highest point (:func:`light_top`) decides; 0 where that has none either."""
    light = scene.lights[light_index]
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    g = max(1, int(np.ceil(np.sqrt(samples))))
    sv = np.zeros(len(o))
    sw = np.zeros(len(o))
    for k in range(g * g):
        cell = np.array([k // g, k % g], np.float64)
        xi = (cell + rng.random((len(o), 2))) / g
        d, tmax, w = light_samples(light, o, n, xi)
        live = w > 0
        if live.any():
            v = visibility_brute(scene, o[live], d[live], tmax[live])
            sv[live] += w[live] * v
            sw[live] += w[live]
    none = sw == 0  # no sample above the horizon: the light's highest point decides
    if none.any():
        d, tmax, w = light_top(light, o[none], n[none])
        idx = np.flatnonzero(none)[w > 0]
        if len(idx):
            sv[idx] = visibility_brute(scene, o[idx], d[w > 0], tmax[w > 0])
            sw[idx] = 1.0
    return np.where(sw > 0, sv / np.where(sw > 0, sw, 1.0), 0.0)
