"""Light objects as the scene model's lights, with the colour and power Cycles emits."""
from __future__ import annotations

import numpy as np

from ...core.scene import Light
from .common import to_matrix, warn_export
from .visibility import RenderVisibility


def light_color(d) -> tuple:
    """Linear RGB of a light datablock: its colour, times its blackbody colour when Blender has
    ``use_temperature`` (4.5+) and it is on (as Cycles and EEVEE multiply them)."""
    rgb = np.array(d.color[:3], np.float64)
    if getattr(d, "use_temperature", False):
        rgb = rgb * np.array(d.temperature_color[:3], np.float64)
    return tuple(float(c) for c in rgb)


def light_power(d) -> float:
    """Power (W) or sun strength (W/m²) as Cycles emits it: ``energy * 2^exposure`` (Blender
    4.0+), and for an area light whose ``normalize`` is off (4.2+), times its area (the power is
    then per square metre)."""
    power = float(d.energy) * 2.0 ** float(getattr(d, "exposure", 0.0))
    if d.type == "AREA" and not getattr(d, "normalize", True):
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        area = float(d.size) * float(size_y) * (np.pi / 4 if d.shape in ("DISK", "ELLIPSE") else 1.0)
        power *= area
    return power


def is_portal(ob) -> bool:
    """Whether a light object is a Cycles light portal (``cycles.is_portal`` before Blender 5,
    the light's ``is_portal`` after): it guides the world's sampling and emits nothing itself.
    Reported once per export."""
    d = ob.data
    if getattr(d, "type", None) != "AREA":
        return False
    portal = getattr(d, "is_portal", None)
    if portal is None:
        portal = getattr(getattr(d, "cycles", None), "is_portal", False)
    if portal:
        warn_export(f"light '{ob.name}': a light portal, not a light (it only guides Cycles' world sampling)")
    return bool(portal)


def export_light(ob, matrix: np.ndarray, name: str) -> Light:
    """A light object (evaluated) at world ``matrix``. An area light's ``size_y`` is its actual
    extent: ``size`` for square and disk shapes."""
    d = ob.data
    kw = dict(name=name, type=d.type, color=light_color(d), power=light_power(d), matrix=matrix,
              use_shadow=bool(d.use_shadow))
    if d.type == "SUN":
        kw["angle"] = float(d.angle)
    elif d.type in ("POINT", "SPOT"):
        kw["radius"] = float(d.shadow_soft_size)
    if d.type == "SPOT":
        kw.update(spot_size=float(d.spot_size), spot_blend=float(d.spot_blend))
    elif d.type == "AREA":
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        kw.update(size=float(d.size), size_y=float(size_y), area_shape=d.shape,
                  spread=float(getattr(d, "spread", np.pi)))
    return Light(**kw)


def export_lights(depsgraph, render_visibility: bool | None = None) -> list:
    """The lights of a depsgraph that ``export_depsgraph`` would list, without reading any
    geometry."""
    renderable = RenderVisibility(depsgraph, render_visibility)
    lights = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type != "LIGHT" or is_portal(ob):
            continue
        if inst.is_instance:
            parent = inst.parent
            if not renderable(parent.original):
                continue
            name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
        else:
            if not renderable(ob.original):
                continue
            name = ob.name
        lights.append(export_light(ob, to_matrix(inst.matrix_world), name))
    return lights
