"""The numpy reference of soft shadows: the weighted share of an extended light a surface point
sees, by many stratified samples of the same light distributions as
``shaders/common/soft_light.glsl`` (a sun's disk of directions, a sphere light's cone, an area
light's rectangle or ellipse) with the same weights, each traced by ``visibility_brute`` (alpha
included). Independent of the GPU's sample sequence: it converges to the exact fraction."""
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


def light_samples(light, o: np.ndarray, n: np.ndarray, xi: np.ndarray):
    """Rays ``(d, tmax, w)`` from points ``o`` (normals ``n``) through sample points ``xi``
    (one (2,) point per row) of the extended light; the hard light's one ray when it has none."""
    soft = soft_shape(light)
    o = np.asarray(o, np.float64)
    n = np.asarray(n, np.float64)
    if light.type == "SUN":
        base = np.broadcast_to(-np.asarray(light.direction, np.float64), o.shape)
    else:
        base = np.broadcast_to(np.asarray(light.position, np.float64), o.shape)
    if soft is None:
        d = base if light.type == "SUN" else base - o
        tmax = np.full(len(o), np.inf if light.type == "SUN" else 1.0)
        return d, tmax, np.maximum((n * d).sum(1), 0.0)
    u, v = np.asarray(soft["u_light_u"]), np.asarray(soft["u_light_v"])
    shape = soft["shape"]
    if shape == 0:
        c = concentric(xi)
        d = base + c[:, :1] * u + c[:, 1:] * v
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d, np.full(len(o), np.inf), np.maximum((n * d).sum(1), 0.0)
    if shape == 1:
        r = soft["u_light_radius"]
        w0 = base - o
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
        b = (dr * w0).sum(1)
        th = b - np.sqrt(np.maximum(0.0, r * r - (dist ** 2 - b * b)))
        d = dr * np.maximum(th, 0.0)[:, None]
        inside = dist <= r
        d[inside] = w0[inside]
        w = np.where(inside, 1.0, np.maximum((n * dr).sum(1), 0.0))
        return d, np.ones(len(o)), w
    c = 2.0 * xi - 1.0 if shape == 2 else concentric(xi)
    d = base + c[:, :1] * u + c[:, 1:] * v - o
    l2 = (d * d).sum(1)
    axis = np.asarray(light.direction, np.float64)
    w = np.maximum((n * d).sum(1), 0.0) * np.maximum(-(d @ axis), 0.0) / np.maximum(l2 * l2, 1e-30)
    tan_h, norm = soft["u_light_spread"]
    w = w * spread_attenuation(-(d @ axis) / np.sqrt(np.maximum(l2, 1e-30)), tan_h, norm)
    return d, np.ones(len(o)), w


def soft_visibility(scene, light_index: int, origins, normals, samples: int = 256, seed: int = 0) -> np.ndarray:
    """(N,) weighted share of light ``light_index`` that each origin sees (origins already off
    the surface): jittered stratified samples on a g x g grid of the light's unit square,
    g = ceil(sqrt(samples)), each point its own jitter; 0 where no sample has weight."""
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
    return np.where(sw > 0, sv / np.where(sw > 0, sw, 1.0), 0.0)
