"""What the export leaves out, named in its report: object kinds it does not draw (hair and
Curves, point clouds, volumes, Grease Pencil) and particle hair."""
from __future__ import annotations

from .common import warn_export

#: Object types the export does not draw, and how the report names them
DROPPED_TYPES = {
    "CURVES": "Curves object",
    "POINTCLOUD": "point cloud",
    "VOLUME": "volume object",
    "GREASEPENCIL": "Grease Pencil object",
    "GPENCIL": "Grease Pencil object",
}


def report_dropped(ob, name: str, is_instance: bool) -> None:
    """Report ``ob`` (evaluated; ``name`` as exported) when the export does not draw it, or when
    it carries particle hair (an object's own particle systems: not for its instances)."""
    label = DROPPED_TYPES.get(ob.type)
    if label is not None:
        who = ob.name if not is_instance else name.split("/")[0] + " (instances)"
        warn_export(f"{label} '{who}': not drawn and casts no shadow")
    if is_instance:
        return
    for ps in getattr(ob, "particle_systems", ()):
        settings = ps.settings
        if settings.type == "HAIR" and settings.render_type == "PATH":
            warn_export(f"particle hair '{ps.name}' of object '{ob.name}': not drawn and casts no shadow")
