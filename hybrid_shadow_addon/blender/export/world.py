"""The world's ambient colour (the scene model's uniform ambient light): its Background node's
colour x strength, where the colour is an Environment Texture the image's mean over the sphere,
and where it is a Sky Texture the sky's average (:func:`sky_table`)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .common import warn_export
from .nodes import constant, resolve

#: The Sky Texture's mean linear RGB over the sphere, the sun disc left out (a Sun lamp stands for
#: it), by Blender major version, sky type and sun elevation: ``{"tables": {major: {sky type:
#: {"settings": the node settings it holds for, "mean": [[elevation°, r, g, b], ...]}}}}``, measured
#: from equirectangular Cycles renders by ``tools/measure_sky.py`` (which also checks it); a
#: shape-preserving cubic in between. Cycles' Sun Intensity scales the sun disc only (Cycles'
#: ``src/kernel/svm/sky.h``, ``sky_radiance_nishita``): the sky's average does not depend on it.
SKY_TABLE_PATH = Path(__file__).with_name("sky_mean.json")
#: The node settings a sky type's average depends on besides the sun's elevation: Preetham and
#: Hosek-Wilkie read these; the Nishita skies (4.x Nishita, 5.x single and multiple scattering) read
#: :data:`NISHITA_SETTINGS` (dust density is 5.x's aerosol density; a setting the running Blender
#: lacks is skipped). Sun Size, Sun Disc and Sun Intensity change only the disc.
SKY_SETTINGS = {"PREETHAM": ("turbidity",), "HOSEK_WILKIE": ("turbidity", "ground_albedo")}
NISHITA_SETTINGS = ("altitude", "air_density", "dust_density", "aerosol_density", "ozone_density")
#: A sky type without a table of its own in any Blender takes the first of these the nearest
#: Blender version has
_STAND_INS = ("MULTIPLE_SCATTERING", "NISHITA", "SINGLE_SCATTERING")
#: Sky types whose sun is the node's Sun Direction (the others': Sun Elevation)
_DIRECTION_TYPES = ("PREETHAM", "HOSEK_WILKIE")
_SKY_TABLES: dict = {}
#: Environment images averaged once per (image, its pixels' update): pointer -> (key, mean RGB)
_ENV_CACHE: dict = {}


def world_background(world):
    """The Background node the world's output uses (else the tree's first), or None."""
    if world is None or not world.use_nodes or not world.node_tree:
        return None
    out = world.node_tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BACKGROUND":
            return node
    return next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)


def sky_tables() -> dict:
    """The measured sky averages (:data:`SKY_TABLE_PATH`'s ``tables``: Blender major version ->
    sky type -> table), read once; empty where the file cannot be read."""
    if not _SKY_TABLES:
        try:
            _SKY_TABLES.update(json.loads(SKY_TABLE_PATH.read_text(encoding="utf-8"))["tables"])
        except (OSError, ValueError, KeyError):
            return {}
    return _SKY_TABLES


def sky_table(sky_type: str, major: int) -> tuple:
    """``(table, stand_in)``: the table measured for ``sky_type`` in Blender ``major`` and None;
    without one, the same type's table of the nearest Blender version that has it, else the
    nearest :data:`_STAND_INS` table, else any, and words saying which; ``(None, None)`` without
    any table."""
    tables = sky_tables()
    entry = tables.get(str(major), {}).get(sky_type)
    if entry is not None:
        return entry, None
    nearest = sorted(tables, key=lambda m: (abs(int(m) - major), -int(m)))  # ties: the newer
    for types in ((sky_type,), _STAND_INS, None):
        for m in nearest:
            t = next((t for t in (types or tables[m]) if t in tables[m]), None)
            if t is not None:
                return tables[m][t], f"the {t} sky of Blender {m}"
    return None, None


def _pchip(x: np.ndarray, y: np.ndarray, xe: float) -> float:
    """Shape-preserving piecewise cubic (Fritsch-Carlson) through (x, y) at ``xe`` (inside x): no
    overshoot at a peak or a flat run. Between the table's elevations above the horizon it is within
    0.5 % of the measured Nishita skies and 1.3 % of Preetham's, where straight lines are off by up
    to 4 % and 7 %."""
    h, d = np.diff(x), np.diff(y) / np.diff(x)
    m = np.zeros_like(y)
    for i in range(1, len(x) - 1):
        if d[i - 1] * d[i] > 0:
            w1, w2 = 2 * h[i] + h[i - 1], h[i] + 2 * h[i - 1]
            m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i])
    for i, (h0, h1, d0, d1) in ((0, (h[0], h[1], d[0], d[1])), (-1, (h[-1], h[-2], d[-1], d[-2]))):
        s = ((2 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
        if np.sign(s) != np.sign(d0):
            s = 0.0
        elif np.sign(d0) != np.sign(d1) and abs(s) > abs(3 * d0):
            s = 3 * d0
        m[i] = s
    i = int(np.clip(np.searchsorted(x, xe) - 1, 0, len(x) - 2))
    t = (xe - x[i]) / h[i]
    return float((1 + 2 * t) * (1 - t) ** 2 * y[i] + t * (1 - t) ** 2 * h[i] * m[i]
                 + t * t * (3 - 2 * t) * y[i + 1] + t * t * (t - 1) * h[i] * m[i + 1])


def sky_mean(elevation_deg: float, table: dict) -> np.ndarray:
    """A table's mean RGB at a sun elevation in degrees (:func:`_pchip` in between; outside the
    measured elevations: the nearest end's)."""
    rows = np.array(table["mean"], np.float64)
    e = float(np.clip(elevation_deg, rows[0, 0], rows[-1, 0]))
    if len(rows) < 3:
        return np.array([np.interp(e, rows[:, 0], rows[:, k]) for k in (1, 2, 3)], np.float32)
    return np.array([_pchip(rows[:, 0], rows[:, k], e) for k in (1, 2, 3)], np.float32)


def sky_settings(node) -> dict:
    """The node's settings that its sky type's average depends on besides the sun's elevation
    (:data:`SKY_SETTINGS`), rounded to 6 significant digits."""
    names = SKY_SETTINGS.get(node.sky_type, NISHITA_SETTINGS)
    return {n: float(f"{float(getattr(node, n)):.6g}") for n in names if hasattr(node, n)}


def sun_elevation(node) -> float:
    """The Sky Texture's sun elevation in degrees, in [-90, 90], as Cycles reads it: Preetham's and
    Hosek-Wilkie's from the (normalised) Sun Direction, the others' Sun Elevation folded into
    [-90°, 90°] (the sun past the zenith is the sun at the supplementary elevation, turned)."""
    if node.sky_type in _DIRECTION_TYPES:
        d = np.array(node.sun_direction, np.float64)
        n = float(np.linalg.norm(d))
        return 90.0 if n < 1e-12 else math.degrees(math.asin(float(np.clip(d[2] / n, -1.0, 1.0))))
    e = math.fmod(float(node.sun_elevation), 2 * math.pi)
    if abs(e) >= math.pi:
        e -= math.copysign(2 * math.pi, e)
    if abs(e) >= math.pi / 2:
        e = math.copysign(math.pi, e) - e
    return math.degrees(e)


def set_sun_elevation(node, elevation_rad: float) -> None:
    """Put the Sky Texture's sun at an elevation (radians), for every sky type: Sun Elevation and a
    Sun Direction in the y-z plane."""
    node.sun_elevation = elevation_rad
    node.sun_direction = (0.0, math.cos(elevation_rad), math.sin(elevation_rad))


def _sky_rgb(world, node) -> np.ndarray | None:
    """The Sky Texture's average over the sphere (:func:`sky_table`), and what it approximates
    reported: a table of another sky type or Blender version, a sun elevation outside the measured
    ones, settings other than those measured. None without any table."""
    import bpy

    name, sky_type, major = f"world '{world.name}'", node.sky_type, int(bpy.app.version[0])
    table, stand_in = sky_table(sky_type, major)
    if table is None:
        warn_export(f"{name}: no measured Sky Texture average ({SKY_TABLE_PATH.name} unreadable): "
                    f"its default colour is used")
        return None
    deg = sun_elevation(node)
    lo, hi = table["mean"][0][0], table["mean"][-1][0]
    used = min(max(deg, lo), hi)
    mean = sky_mean(used, table)
    has_disc = sky_type not in _DIRECTION_TYPES and getattr(node, "sun_disc", False)
    disc = "; the sun disc left out: a Sun lamp stands for it" if has_disc else ""
    warn_export(f"{name}: Sky Texture lights as its average sky {_fmt(mean)} ({sky_type}, sun elevation "
                f"{deg:.0f}°; uniform ambient, no directions{disc})")
    if stand_in:
        warn_export(f"{name}: no measured average for a {sky_type} Sky Texture in Blender {major}: "
                    f"{stand_in} stands in (approximate)")
    if used != deg:
        warn_export(f"{name}: the Sky Texture's sun elevation {deg:.1f}° lies outside the measured "
                    f"{lo:g}°..{hi:g}°: the sky at {used:g}° stands in (approximate)")
    measured = table.get("settings", {})
    differ = {k: v for k, v in sky_settings(node).items()
              if k in measured and not math.isclose(v, measured[k], rel_tol=1e-4, abs_tol=1e-6)}
    if differ:
        ours = ", ".join(f"{k.replace('_', ' ')} {v:g}" for k, v in differ.items())
        theirs = ", ".join(f"{k.replace('_', ' ')} {measured[k]:g}" for k in differ)
        warn_export(f"{name}: the Sky Texture's {ours} differ from the settings its average was measured at "
                    f"({theirs}): the average of the sky at those stands in (approximate)")
    vector = next((i for i in node.inputs if i.identifier == "Vector"), None)  # (4.5: not found by name)
    if vector is not None and vector.is_linked:
        warn_export(f"{name}: the Sky Texture's Vector is linked: the average is the unmapped sky's")
    return mean


def equirect_mean(pixels: np.ndarray) -> np.ndarray:
    """Mean linear RGB over the sphere of an equirectangular image (H, W, >=3), row 0 at the
    bottom: each row weighed by the solid angle it covers (cos of its latitude)."""
    h = pixels.shape[0]
    lat = ((np.arange(h) + 0.5) / h - 0.5) * np.pi
    w = np.cos(lat)
    rows = pixels[..., :3].astype(np.float64).mean(axis=1)  # (H, 3)
    return (rows * w[:, None]).sum(axis=0) / w.sum()


def _environment_mean(node) -> np.ndarray | None:
    """The Environment Texture's image mean over the sphere (linear: Blender's float pixels are
    scene linear), cached per image and pixel update; None without pixels."""
    image = node.image
    if image is None:
        return None
    key = (image.name, tuple(image.size), getattr(image, "is_dirty", False), image.filepath, node.projection)
    hit = _ENV_CACHE.get(image.as_pointer())
    if hit is not None and hit[0] == key:
        return hit[1]
    try:
        w, h = (int(x) for x in image.size)
        ch = int(image.channels)
        buf = np.empty(w * h * ch, np.float32)
        image.pixels.foreach_get(buf)
    except (RuntimeError, ReferenceError, ValueError, TypeError):
        return None
    if w < 1 or h < 1 or ch < 3:
        return None
    px = np.nan_to_num(buf.reshape(h, w, ch))
    mean = equirect_mean(px) if node.projection == "EQUIRECTANGULAR" else px[..., :3].reshape(-1, 3).mean(axis=0)
    _ENV_CACHE[image.as_pointer()] = (key, mean.astype(np.float32))
    return mean.astype(np.float32)


def _background_rgb(world, bg) -> np.ndarray:
    """The Background's colour: a constant, an Environment Texture's mean, a Sky Texture's
    average; anything else its default value (reported)."""
    value = constant(bg.inputs["Color"])
    if value is not None:
        return np.array(value[:3], np.float32)
    src = resolve(bg.inputs["Color"])
    node = src.node
    if node.type == "TEX_ENVIRONMENT" and not node.mute:
        mean = _environment_mean(node)
        if mean is not None:
            if node.projection != "EQUIRECTANGULAR":
                warn_export(f"world '{world.name}': its {node.projection.lower()} environment is averaged "
                            f"over the image's pixels")
            warn_export(f"world '{world.name}': Environment Texture lights as its mean colour "
                        f"{_fmt(mean)} (uniform ambient, no directions)")
            return mean
        warn_export(f"world '{world.name}': the Environment Texture has no pixels: its default colour is used")
    elif node.type == "TEX_SKY" and not node.mute:
        mean = _sky_rgb(world, node)
        if mean is not None:
            return mean
    else:
        warn_export(f"world '{world.name}': the Background colour is linked from '{node.name}' "
                    f"({node.bl_idname}): its default colour is used")
    return np.array(bg.inputs["Color"].default_value[:3], np.float32)


def _fmt(rgb) -> str:
    return "(" + ", ".join(f"{float(c):.3g}" for c in rgb) + ")"


def world_color(world) -> np.ndarray:
    """Linear RGB of the world: its Background node's colour (an Environment Texture's mean, a
    Sky Texture's average) × strength, else ``world.color``."""
    if world is None:
        return np.zeros(3, np.float32)
    bg = world_background(world)
    if bg is not None:
        rgb = _background_rgb(world, bg)
        strength = constant(bg.inputs["Strength"])
        strength = float(bg.inputs["Strength"].default_value) if strength is None else float(strength)
        return (rgb * np.float32(strength)).astype(np.float32)
    return np.array(world.color[:3], np.float32)
