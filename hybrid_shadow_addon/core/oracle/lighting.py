"""The lighting model in numpy: the oracle the GPU lighting pass (``shaders/lighting.glsl``,
``shaders/common/lights.glsl``) is tested against, reading the same light table.

BRDF: Lambert albedo / pi plus normalised Blinn-Phong, F0 = 0.08 * specular (Principled's 0.5 ->
0.04), exponent s = clamp(2 / a^2 - 2, 1, 2048), a = max(roughness^2, 0.03):
f_spec = F0 (s + 8) / (8 pi) (n.h)^s. Ambient: albedo * world colour (a uniform world of
radiance W gives irradiance pi W). Each light's contribution is multiplied by its shadow mask
when it has one. Light units: :mod:`..gpu.lights`.
"""
from __future__ import annotations

import math

import numpy as np

from ..gpu.lights import area_of, light_table, spread_attenuation
from ..scene.linking import receivers


def _smoothstep01(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def light_incident(row: np.ndarray, p: np.ndarray):
    """Irradiance (..., 3) on a surface facing the light and unit directions to it (..., 3)
    (an area light: its far field from its centre)."""
    t0, t1, t2, t3 = row[:4]
    code = int(round(t0[3]))
    if code == 0:
        to_light = np.broadcast_to(-t1[:3], p.shape)
        return np.broadcast_to(t2[:3], p.shape), to_light
    d = t0[:3] - p
    r2 = np.maximum((d * d).sum(-1), 1e-12)
    to_light = d / np.sqrt(r2)[..., None]
    k = 1.0 / r2
    t = -(to_light @ t1[:3])
    if code == 2:
        ch, blend = t1[3], t3[0]
        k = k * (_smoothstep01((t - ch) / ((1 - ch) * blend)) if blend > 0 else (t > ch).astype(np.float64))
    elif code == 3:
        k = k * np.maximum(t, 0.0)
    return t2[:3] * k[..., None], to_light


def area_irradiance(row: np.ndarray, p: np.ndarray, n: np.ndarray, order: int = 16) -> np.ndarray:
    """Irradiance (..., 3) at points ``p`` (normals ``n``) from the area light of table ``row``,
    by Gauss-Legendre quadrature over its surface (``order`` nodes per axis; an ellipse in polar
    coordinates): the integral of L cos(receiver)+ cos(emitter)+ spread(emitter) / d^2 over the
    light (``spread``: Cycles' soft-box factor when the light's spread is below 180 degrees)."""
    t0, t1, t2, t3, t4 = row
    c, axis, ux, hx, hy = t0[:3], t1[:3], t4[:3], t4[3], t3[1]
    uy = np.cross(axis, ux)
    uy = uy / np.linalg.norm(uy)
    g, w = np.polynomial.legendre.leggauss(order)
    if t3[2] < 0.5:  # rectangle: [-1, 1]^2
        a, b = np.meshgrid(g, g, indexing="ij")
        wt = np.outer(w, w).ravel() * hx * hy
    else:  # ellipse: radius (0, 1] by Gauss-Legendre, angle by 4 * order equal steps
        r = (g + 1) / 2
        phi = (np.arange(4 * order) + 0.5) / (4 * order) * 2 * np.pi
        rr, pp = np.meshgrid(r, phi, indexing="ij")
        a, b = rr * np.cos(pp), rr * np.sin(pp)
        wt = (np.outer(w / 2 * r, np.full(len(phi), 2 * np.pi / len(phi)))).ravel() * hx * hy
    q = c + (a.ravel() * hx)[:, None] * ux + (b.ravel() * hy)[:, None] * uy  # (S, 3)
    flat_p = p.reshape(-1, 3)
    flat_n = n.reshape(-1, 3)
    out = np.zeros(len(flat_p))
    for s0 in range(0, len(flat_p), 8192):
        pp_, nn = flat_p[s0:s0 + 8192], flat_n[s0:s0 + 8192]
        d = q[None] - pp_[:, None]  # (P, S, 3) from the receiver to the light
        r2 = np.maximum((d * d).sum(-1), 1e-12)
        cos_r = np.maximum((d * nn[:, None]).sum(-1), 0.0) / np.sqrt(r2)
        cos_l = np.maximum(-(d @ axis), 0.0) / np.sqrt(r2)
        f = spread_attenuation(cos_l, float(t3[3]), float(t2[3])) if t3[3] >= 0 else 1.0
        out[s0:s0 + 8192] = (cos_r * cos_l * f / r2) @ wt
    return t2[:3] * out.reshape(p.shape[:-1])[..., None]


def brdf_cos(n, to_light, v, albedo, specular, roughness, use_specular=True):
    c = (n * to_light).sum(-1)
    f = albedo / math.pi
    if use_specular:
        a = np.maximum(roughness * roughness, 0.03)
        s = np.clip(2 / (a * a) - 2, 1.0, 2048.0)
        h = to_light + v
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        nh = np.maximum((n * h).sum(-1), 0.0)
        f = f + (0.08 * specular * (s + 8) / (8 * math.pi) * nh ** s)[..., None]
    return np.where((c > 0)[..., None], f * np.maximum(c, 0)[..., None], 0.0)


def view_vectors(position: np.ndarray, camera) -> np.ndarray:
    cw = camera.world_matrix_normalized()
    if camera.type == "ORTHO":
        return np.broadcast_to(cw[:3, 2], position.shape)
    v = cw[:3, 3] - position
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pixel_receives(scene, light, instance, coverage) -> np.ndarray:
    """(H, W) float 1 where the pixel's instance (``instance``: the G-buffer's index, float) is lit
    by ``light`` under light linking, else 0 (0 where ``coverage`` is off)."""
    lit = receivers(scene, light)
    if not len(lit):
        return np.zeros(np.shape(coverage))
    idx = np.where(coverage, np.round(np.nan_to_num(instance)).astype(np.int64), 0)
    ok = coverage & (idx >= 0) & (idx < len(lit))
    return (ok & lit[np.clip(idx, 0, len(lit) - 1)]).astype(np.float64)


def shade(scene, gbuffer: dict, masks: dict | None = None, use_specular: bool = True,
          film_transparent: bool = False) -> np.ndarray:
    """(H, W, 4) float64 linear RGBA from G-buffer arrays (``read_gbuffer_arrays``: keys
    position, shading_normal, albedo, material; row 0 = top) and masks ``{light: (H, W)}``
    (NaN treated as 1). An emitter's pixel (specular below 0) is its albedo, its emission. A light
    with a receiver set (light linking) lights only its receivers: the instance of each pixel is
    the material's third channel."""
    pos = gbuffer["position"].astype(np.float64)
    cov = pos[..., 3] > 0.5
    p = pos[..., :3]
    n = gbuffer["shading_normal"][..., :3].astype(np.float64)
    albedo = gbuffer["albedo"][..., :3].astype(np.float64)
    mat = gbuffer["material"].astype(np.float64)
    v = view_vectors(p, scene.camera)
    world = np.asarray(scene.world_color, np.float64)
    c = albedo * world
    table = light_table(scene.lights)
    masks = masks or {}
    for i in range(len(scene.lights)):
        e, to_light = light_incident(table[i], p)
        if int(round(table[i][0][3])) == 3 and table[i][4][3] > 0:  # an area light with a size
            contrib = albedo / math.pi * area_irradiance(table[i], p, n)
            if use_specular:
                contrib = contrib + e * area_of(scene.lights[i]) * (
                    brdf_cos(n, to_light, v, np.zeros_like(albedo), mat[..., 0], mat[..., 1], True))
        else:
            contrib = e * brdf_cos(n, to_light, v, albedo, mat[..., 0], mat[..., 1], use_specular)
        if i in masks:
            m = np.nan_to_num(np.asarray(masks[i], np.float64), nan=1.0)
            contrib = contrib * m[..., None]
        if scene.lights[i].receiver_set >= 0:
            contrib = contrib * pixel_receives(scene, i, mat[..., 2], cov)[..., None]
        c = c + contrib
    emits = mat[..., 0] < 0.0  # an emitter (the G-buffer's specular -1): its emission, unlit
    c[emits] = albedo[emits]
    out = np.zeros(pos.shape[:2] + (4,))
    out[cov, :3] = c[cov]
    out[cov, 3] = 1.0
    if not film_transparent:
        out[~cov, :3] = world
        out[~cov, 3] = 1.0
    return out
