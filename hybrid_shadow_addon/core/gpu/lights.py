"""Lights as the passes see them: which lights get a shadow mask, the light table of the lighting
pass (``shaders/common/lights.glsl``) and the ray pass's light uniforms.

Units as Cycles/EEVEE use them (delta lights, no soft size): a sun of strength S gives
irradiance S * colour on a surface facing it; a point of power P (W) radiant intensity
P / (4 pi) * colour, inverse-square falloff; a spot the intensity of a point of equal power times
Blender's cone mask; an area light (rectangle or ellipse, scaled by its object) a one-sided
Lambertian emitter of power P and area A: radiance P / (pi A) * colour towards its -Z side, whose
irradiance is integrated over the light's polygon clipped to the receiver's horizon.
"""
from __future__ import annotations

import math

import numpy as np

LIGHT_CODES = {"SUN": 0, "POINT": 1, "SPOT": 2, "AREA": 3}
AREA_SHAPES = {"SQUARE": 0, "RECTANGLE": 0, "DISK": 1, "ELLIPSE": 1}  # 0 rectangle, 1 ellipse
LIGHT_TEXELS = 5  # RGBA32F texels per light in the light table (``shaders/common/lights.glsl``)


def area_extent(light) -> tuple:
    """``(x axis, half width, half height)`` of an area light in world units: Blender's
    ``size``/``size_y`` scaled by the light object's X and Y axes (unit x axis, float64)."""
    x = np.asarray(light.matrix[:3, 0], np.float64)
    y = np.asarray(light.matrix[:3, 1], np.float64)
    sx, sy = float(np.linalg.norm(x)), float(np.linalg.norm(y))
    size_y = light.size_y if light.area_shape in ("RECTANGLE", "ELLIPSE") else light.size
    ux = x / sx if sx > 0 else np.array([1.0, 0.0, 0.0])
    return ux, 0.5 * float(light.size) * sx, 0.5 * float(size_y) * sy


def area_of(light) -> float:
    """Emitting area (m^2) of an area light."""
    _, hx, hy = area_extent(light)
    return 4.0 * hx * hy * (math.pi / 4 if AREA_SHAPES.get(light.area_shape, 0) == 1 else 1.0)


MIN_HALF_SPREAD = 1e-3  # narrower spreads are clamped (Cycles' collimated limit is a delta)


def spread_params(light) -> tuple:
    """``(tan(h), N)`` of an area light's spread (half angle h): Cycles' soft-box attenuation of
    the radiance leaving at angle a from the axis is ``max((tan h - tan a) N, 0)``, with
    ``N = 1 / (tan h - h)`` (``3 / h^3`` for h <= 0.05) keeping its power; ``(-1, 0)`` for no
    attenuation (spread pi, or not an area light)."""
    if light.type != "AREA" or not float(light.spread) < math.pi - 1e-6:
        return -1.0, 0.0
    h = max(0.5 * float(light.spread), MIN_HALF_SPREAD)
    t = math.tan(h)
    return t, (1.0 / (t - h) if h > 0.05 else 3.0 / h ** 3)


def spread_attenuation(cos_a, tan_h: float, norm: float):
    """Cycles' spread factor for emission cosines ``cos_a`` (numpy); 1 without a spread."""
    cos_a = np.asarray(cos_a, np.float64)
    if tan_h < 0:
        return np.ones_like(cos_a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0)) / cos_a
    return np.where(cos_a > 0, np.maximum((tan_h - tan_a) * norm, 0.0), 0.0)


def light_table(lights) -> np.ndarray:
    """(N, LIGHT_TEXELS, 4) float64 rows as ``shaders/common/lights.glsl`` reads them."""
    out = np.zeros((len(lights), LIGHT_TEXELS, 4))
    for i, light in enumerate(lights):
        color = np.asarray(light.color, np.float64)
        if light.type == "SUN":
            rad = light.power * color
        elif light.type == "AREA":
            area = area_of(light)
            # radiance of a one-sided Lambertian emitter of power P and area A: P / (pi A);
            # a zero-size area light keeps its far field, intensity P / pi on its axis
            rad = light.power / (math.pi * area) * color if area > 0 else light.power / math.pi * color
            ux, hx, hy = area_extent(light)
            out[i, 3, 1] = hy if area > 0 else 0.0
            out[i, 3, 2] = AREA_SHAPES.get(light.area_shape, 0)
            out[i, 4, :3] = ux
            out[i, 4, 3] = hx if area > 0 else 0.0
            out[i, 3, 3], out[i, 2, 3] = spread_params(light)
        else:
            rad = light.power / (4 * math.pi) * color
        out[i, 0, :3] = light.position
        out[i, 0, 3] = LIGHT_CODES[light.type]
        out[i, 1, :3] = light.direction
        out[i, 1, 3] = math.cos(light.spot_size / 2)
        out[i, 2, :3] = rad
        out[i, 3, 0] = max(float(light.spot_blend), 0.0)
    return out


def sized_area(table: np.ndarray) -> np.ndarray:
    """Which rows of a light table are sized area lights (``area_contribution`` in
    ``shaders/common/lights.glsl``; the others take ``point_contribution``), with the shader's
    own tests on the float32 table."""
    t = np.asarray(table, np.float32).reshape(-1, LIGHT_TEXELS, 4)
    code = (t[:, 0, 3] + np.float32(0.5)).astype(np.int64)
    return (code == LIGHT_CODES["AREA"]) & (t[:, 4, 3] > 0)


def lighting_defines(table: np.ndarray) -> dict:
    """The kinds of light in a light table, as the defines of ``shaders/common/lights.glsl``
    (the kinds absent are compiled out of the lighting pass). Read from the table as the GPU
    gets it (float32), with the shader's own tests: type code, half width > 0 (a sized area
    light), tan of the half spread >= 0 (a spread), shape >= 0.5 (an ellipse)."""
    t = np.asarray(table, np.float32).reshape(-1, LIGHT_TEXELS, 4)
    code = (t[:, 0, 3] + np.float32(0.5)).astype(np.int64)
    area = code == LIGHT_CODES["AREA"]
    sized = sized_area(t)
    spread = sized & (t[:, 3, 3] >= 0)
    poly = sized & ~spread
    kinds = {"HS_LIT_SUN": code == LIGHT_CODES["SUN"], "HS_LIT_POINT": code == LIGHT_CODES["POINT"],
             "HS_LIT_SPOT": code == LIGHT_CODES["SPOT"], "HS_LIT_AREA_POINT": area & ~sized,
             "HS_LIT_AREA_RECT": poly & (t[:, 3, 2] < 0.5), "HS_LIT_AREA_ELLIPSE": poly & (t[:, 3, 2] >= 0.5),
             "HS_LIT_AREA_SPREAD": spread}
    return {k: 1 for k, rows in kinds.items() if rows.any()}


def select_shadowed_lights(scene, settings=None) -> list:
    """Indices of the lights that get a mask: ``use_shadow`` lights; with
    ``settings.max_shadowed_lights`` = N only N of them: suns first (always kept, thesis 3.2),
    then the others nearest to the camera."""
    idx = [i for i, light in enumerate(scene.lights) if light.use_shadow]
    limit = None if settings is None else settings.max_shadowed_lights
    if settings is not None and settings.mode == "none":
        return idx
    if limit is None or len(idx) <= limit:
        return idx
    cam = np.zeros(3) if scene.camera is None else scene.camera.matrix[:3, 3]

    def key(i):
        light = scene.lights[i]
        if light.type == "SUN":
            return (0, 0.0, i)
        return (1, float(np.linalg.norm(light.position - cam)), i)

    return sorted(sorted(idx, key=key)[:limit])


def light_ray_uniforms(light, origin=(0.0, 0.0, 0.0)) -> tuple[bool, tuple]:
    """(local, u_light_vec): a sun gives the unit direction towards it, other lights their
    position (area lights are points for now) relative to ``origin`` (the bake's)."""
    if light.type == "SUN":
        return False, tuple(float(v) for v in -light.direction)
    return True, tuple(float(v) for v in light.position - np.asarray(origin, np.float64))


SOFT_SHAPES = {"SUN": 0, "SPHERE": 1, "RECTANGLE": 2, "ELLIPSE": 3}


def soft_shape(light, hard: bool = False) -> dict | None:
    """The extended light ``shaders/common/soft_light.glsl`` samples, or None for a hard one
    (``hard``, or size 0): ``{"shape": HS_SOFT_SHAPE, "u_light_u", "u_light_v",
    "u_light_radius"}`` (world axes, float tuples; a sphere light adds ``u_light_blend``, a spot's
    blend, and an area light ``u_light_spread``)."""
    if hard:
        return None
    zero = (0.0, 0.0, 0.0)
    if light.type == "SUN":
        if not light.angle > 0:
            return None
        d = -np.asarray(light.direction, np.float64)
        a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(d, a)
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        t = math.tan(0.5 * min(float(light.angle), math.radians(179.0)))
        return {"shape": SOFT_SHAPES["SUN"], "u_light_u": tuple(u * t), "u_light_v": tuple(v * t),
                "u_light_radius": 0.0}
    if light.type in ("POINT", "SPOT"):
        if not light.radius > 0:
            return None
        return {"shape": SOFT_SHAPES["SPHERE"], "u_light_u": zero, "u_light_v": zero,
                "u_light_radius": float(light.radius),
                "u_light_blend": max(float(light.spot_blend), 0.0) if light.type == "SPOT" else 0.0}
    ux, hx, hy = area_extent(light)
    if not (hx > 0 and hy > 0):
        return None
    y = np.asarray(light.matrix[:3, 1], np.float64)
    ny = np.linalg.norm(y)
    uy = y / ny if ny > 0 else np.cross(np.asarray(light.direction, np.float64), ux)
    shape = "ELLIPSE" if AREA_SHAPES.get(light.area_shape, 0) == 1 else "RECTANGLE"
    return {"shape": SOFT_SHAPES[shape], "u_light_u": tuple(ux * hx), "u_light_v": tuple(uy * hy),
            "u_light_radius": 0.0, "u_light_spread": spread_params(light)}


def light_cone(light) -> tuple[tuple, float]:
    """(u_light_axis, u_light_cone) of a local light: where ``dot(light -> p, axis)`` is at most
    the cone value the light does not shine (as ``shaders/common/lights.glsl`` evaluates it)."""
    axis = tuple(float(v) for v in light.direction)
    if light.type == "SPOT":
        return axis, float(np.cos(light.spot_size / 2))
    if light.type == "AREA":
        return axis, 0.0
    return axis, -2.0
