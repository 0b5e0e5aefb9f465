"""What every export module shares: the warning category, mathutils matrices as numpy arrays,
and the object kinds and properties the export reads."""
from __future__ import annotations

import contextlib
import itertools
import warnings

import numpy as np

#: Object types whose evaluated geometry can be a mesh.
GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
#: Custom object property marking an analytic sphere primitive.
SPHERE_PROPERTY = "hybrid_sphere"


class ExportWarning(UserWarning):
    """Part of the scene the export cannot read as Blender renders it (a material's node set-up,
    an image without pixels, a textured mesh without UVs): it falls back and says so, once per
    material, image or mesh."""


#: The export reports being collected (:func:`collect_report`), innermost last.
_REPORTS: list = []


def warn_export(message: str) -> None:
    """Issue an :class:`ExportWarning` attributed to the caller of the function that warns, and
    add the message to the export report being collected (once per export)."""
    if _REPORTS and message not in _REPORTS[-1]:
        _REPORTS[-1].append(message)
    warnings.warn(message, ExportWarning, stacklevel=3)


@contextlib.contextmanager
def collect_report():
    """Collect the messages of :func:`warn_export` made inside the block into a list (each
    once, in order): the export report of one export."""
    report: list = []
    _REPORTS.append(report)
    try:
        yield report
    finally:
        _REPORTS.remove(report)


def to_matrix(m) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 numpy array (rows as in Blender)."""
    return np.array([tuple(row) for row in m], np.float64)


def to_matrices(ms: list) -> np.ndarray:
    """A list of mathutils 4x4 matrices as an (N, 4, 4) float64 array."""
    flat = itertools.chain.from_iterable(itertools.chain.from_iterable(ms))
    return np.fromiter(flat, np.float64, count=16 * len(ms)).reshape(-1, 4, 4)


def is_sphere_primitive(ob) -> bool:
    """The object's "Sphere Primitive" setting: the add-on's property when registered, else the
    ``hybrid_sphere`` custom property (scene scripts set that one)."""
    value = getattr(ob, SPHERE_PROPERTY, None)
    if value is None:
        value = ob.get(SPHERE_PROPERTY, False)
    return bool(value)


def terminator_offset(ob) -> float:
    """The object's Shadow Terminator Geometry Offset (Cycles' object setting, 0..1), which moves
    the shadow rays of its smooth-shaded triangles near the terminator as Cycles does. Its Shading
    Offset, which only softens Cycles' shading there, is reported once per object when set: the
    preview's lighting does not apply it."""
    shading = float(getattr(ob, "shadow_terminator_shading_offset", 0.0))
    if shading > 0.0:
        warn_export(f"object '{ob.name}': Shadow Terminator Shading Offset {shading:g} is not applied "
                    f"(the shading near its terminator is Cycles' without the offset)")
    return float(getattr(ob, "shadow_terminator_geometry_offset", 0.1))
