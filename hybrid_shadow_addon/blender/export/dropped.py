"""What the export leaves out, named in its report: object kinds it does not draw (volumes,
Grease Pencil)."""
from __future__ import annotations

from .common import warn_export

#: Object types the export does not draw, and how the report names them
DROPPED_TYPES = {
    "VOLUME": "volume object",
    "GREASEPENCIL": "Grease Pencil object",
    "GPENCIL": "Grease Pencil object",
}


def report_dropped(ob, name: str, is_instance: bool) -> None:
    """Report ``ob`` (evaluated; ``name`` as exported) when the export does not draw it."""
    label = DROPPED_TYPES.get(ob.type)
    if label is not None:
        who = ob.name if not is_instance else name.split("/")[0] + " (instances)"
        warn_export(f"{label} '{who}': not drawn and casts no shadow")
