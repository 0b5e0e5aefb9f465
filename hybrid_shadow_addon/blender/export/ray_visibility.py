"""Ray visibility as Cycles reads it (``blender/object.cpp``, ``sync_object``): which instances
the camera sees, which cast shadows, which are holdouts, and whether an emitter shows itself.

- An object's camera and shadow visibility (``visible_camera``, ``visible_shadow``) are ANDed
  with its instancer's (the depsgraph instance's top-level parent) for instances.
- Holdout (``Object.is_holdout`` or a holdout collection of the view layer:
  ``Object.holdout_get``) and indirect-only (``indirect_only_get``) come from the instancer alone,
  as Cycles takes them from ``b_parent``; indirect-only clears camera visibility only (a shadow ray
  still meets the object) and does not apply to a holdout. Where the view layer's setting cannot
  be read, the export says so (and uses the object's own holdout, and no indirect-only).
- An instancer (particles, instancing, geometry-nodes instances) whose Show Instancer is off
  shows no geometry of its own (``DepsgraphObjectInstance.show_self``; an export of what F12
  renders from a viewport depsgraph reads ``show_instancer_for_render`` instead).
"""
from __future__ import annotations

from dataclasses import dataclass

from .common import warn_export


@dataclass(frozen=True)
class RayFlags:
    """What an exported instance row gets: drawn (camera), casting (shadow), holdout."""

    camera: bool = True
    shadow: bool = True
    holdout: bool = False


DEFAULT = RayFlags()


def _own(ob) -> tuple:
    """``(camera, shadow)`` visibility of an object itself."""
    return bool(getattr(ob, "visible_camera", True)), bool(getattr(ob, "visible_shadow", True))


class RayVisibility:
    """The :class:`RayFlags` of a depsgraph's objects and instances, cached per (object,
    instancer). ``render_visibility``: the depsgraph is a viewport's exported as F12 renders it
    (:class:`~.visibility.RenderVisibility`'s ``check``)."""

    def __init__(self, depsgraph, render_visibility: bool = False):
        self.view_layer = getattr(depsgraph, "view_layer", None)
        self.render_visibility = bool(render_visibility)
        self.flags_of: dict = {}  # (object pointer, instancer pointer or 0) -> RayFlags
        self.layer_of: dict = {}  # original instancer pointer -> (holdout, indirect only)

    def _layer_flags(self, parent) -> tuple:
        """``(holdout, indirect only)`` of an (evaluated) top-level object in the view layer."""
        orig = parent.original
        key = orig.as_pointer()
        got = self.layer_of.get(key)
        if got is None:
            holdout = bool(getattr(orig, "is_holdout", False))
            indirect = False
            if self.view_layer is not None:
                try:
                    holdout = bool(orig.holdout_get(view_layer=self.view_layer))
                except (AttributeError, RuntimeError, TypeError) as exc:
                    warn_export(f"object '{orig.name}': its view layer's holdout could not be read ({exc}); "
                                f"the object's own Holdout ({'on' if holdout else 'off'}) is used")
                try:
                    indirect = bool(orig.indirect_only_get(view_layer=self.view_layer))
                except (AttributeError, RuntimeError, TypeError) as exc:
                    warn_export(f"object '{orig.name}': its view layer's Indirect Only could not be read ({exc}); "
                                f"the object is drawn as the camera sees it")
            got = self.layer_of[key] = (holdout, indirect and not holdout)
        return got

    def flags(self, ob, parent=None) -> RayFlags:
        """The flags of (evaluated) object ``ob``, instanced by top-level ``parent`` (None: ``ob``
        is top-level itself)."""
        key = (ob.as_pointer(), 0 if parent is None else parent.as_pointer())
        got = self.flags_of.get(key)
        if got is None:
            top = ob if parent is None else parent
            camera, shadow = _own(ob)
            if parent is not None and parent.original != ob.original:
                pc, ps = _own(parent)
                camera, shadow = camera and pc, shadow and ps
            holdout, indirect = self._layer_flags(top)
            got = RayFlags(camera and not indirect, shadow, holdout)
            got = self.flags_of[key] = DEFAULT if got == DEFAULT else got
        return got

    def shows_self(self, inst) -> bool:
        """Whether a non-instance depsgraph row shows the object's own geometry (Show Instancer
        of an emitter or instancer)."""
        if not inst.show_self:
            return False
        if not self.render_visibility:
            return True
        ob = inst.object
        if bool(getattr(ob.original, "show_instancer_for_render", True)):
            return True
        return not (bool(ob.is_instancer) or len(getattr(ob, "particle_systems", ())) > 0 or _has_instances(ob))


def _has_instances(ob) -> bool:
    """The evaluated object's geometry set holds instances (geometry-nodes instancing)."""
    if ob.type != "MESH" or not any(m.type == "NODES" for m in ob.modifiers):
        return False
    import bpy

    try:
        return bpy.types.GeometrySet.from_evaluated_object(ob).instances_pointcloud() is not None
    except (AttributeError, RuntimeError):
        return False
