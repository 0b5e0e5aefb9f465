"""The world's ambient colour (the scene model's uniform ambient light): its Background node's
colour x strength, where the colour is an Environment Texture the image's mean over the sphere,
and where it is a Sky Texture the sky's average (:data:`SKY_MEAN`)."""
from __future__ import annotations

import numpy as np

from .common import warn_export
from .nodes import constant, resolve

#: Mean linear RGB over the sphere of Blender's Nishita sky (default air, dust and ozone, sun
#: intensity 1, the sun disc left out: a sun lamp stands for it) by sun elevation in degrees,
#: measured from 128x64 equirectangular Cycles renders (Blender 4.5, 16 samples); linear in
#: between. Every sky type reads this table.
SKY_MEAN = (
    (0.0, (0.30651, 0.24276, 0.20584)), (2.0, (0.83406, 0.61649, 0.43296)),
    (5.0, (1.47404, 1.22543, 0.90493)), (10.0, (1.98375, 1.84168, 1.58871)),
    (15.0, (2.10409, 2.08669, 2.00328)), (20.0, (2.06990, 2.15777, 2.23755)),
    (30.0, (1.89350, 2.12215, 2.44049)), (45.0, (1.66123, 1.98698, 2.49486)),
    (60.0, (1.50709, 1.86858, 2.46441)), (75.0, (1.41746, 1.79082, 2.42673)),
    (90.0, (1.38858, 1.76412, 2.41160)),
)
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


def sky_mean(elevation_rad: float) -> np.ndarray:
    """:data:`SKY_MEAN` at a sun elevation (radians; below the horizon: the horizon's)."""
    deg = float(np.clip(np.degrees(elevation_rad), 0.0, 90.0))
    xs = np.array([e for e, _ in SKY_MEAN])
    rgb = np.array([c for _, c in SKY_MEAN])
    return np.array([np.interp(deg, xs, rgb[:, k]) for k in range(3)], np.float32)


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
        elevation = float(getattr(node, "sun_elevation", np.radians(15.0)))
        mean = sky_mean(elevation) * np.float32(getattr(node, "sun_intensity", 1.0))
        warn_export(f"world '{world.name}': Sky Texture lights as the average sky at sun elevation "
                    f"{np.degrees(elevation):.0f}° {_fmt(mean)} (uniform ambient; air, dust and ozone at "
                    f"Blender's defaults, no sun disc)")
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
