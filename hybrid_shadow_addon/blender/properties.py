"""Blender properties of the Hybrid Shadows engine and their mapping to the core ``Settings``.

- ``Scene.hybrid_shadows`` (:class:`HybridShadowsSceneSettings`): shadow mode, quality, limits,
  shadow-map options, viewport options and the debug view.
- ``ViewLayer.hybrid_shadows`` (:class:`HybridShadowsViewLayerSettings`): the engine's own
  render passes (Depth and Normal follow Blender's ``use_pass_z`` / ``use_pass_normal``).
- ``Object.hybrid_sphere``: the object is traced as an analytic sphere. Blender 4.x stores a
  ``bpy.props`` property of an ID in the same ID-property group as custom properties, so this is
  the very ``ob["hybrid_sphere"]`` custom property the exporter reads (scene scripts may set
  either). "Casts hybrid shadow" is Blender's own ``Object.visible_shadow`` (what the exporter
  reads), and a light's shadow switch is Blender's own ``Light.use_shadow``.
"""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from ..core.settings import FIELDS, Settings, kind


def enum_items(name: str) -> tuple:
    """The items of the enum property of setting ``name``: each declared :class:`Choice` with
    its value upper-cased as the identifier (integer choices as text)."""
    f = FIELDS[name]
    b = f.metadata["blender"] or {}
    if "choices" in b:  # (an integer setting offered at a few values)
        return tuple((str(v), f"{v} px", f"{f.metadata['help']}: {v}", "NONE", i) for i, v in enumerate(b["choices"]))
    return tuple((str(c.value).upper(), c.label, c.help, c.icon, i) for i, c in enumerate(f.metadata["choices"]))


QUALITY_ITEMS = enum_items("quality")
NAVIGATION_ITEMS = (
    ("AUTO", "Automatic", "Low on a GPU; on a software rasteriser (such as Mesa's llvmpipe), where Medium and Low "
                          "cost more than High, the viewport quality", "NONE", 3),
) + QUALITY_ITEMS
DEBUG_ITEMS = (
    ("NONE", "None", "Show the lit image", 0),
    ("LIGHT_MASK", "Light Mask", "Show the shadow mask of one light (white lit, black shadowed, blue no geometry)", 1),
    ("GRID_HEAT", "Grid Occupancy", "Heat map of how many shadow casters the acceleration structure holds "
                                     "above each pixel (grid nodes or instance boxes)", 2),
    ("NORMAL", "G-Buffer Normal", "Show the G-buffer's world-space shading normal", 3),
    ("ALBEDO", "G-Buffer Albedo", "Show the G-buffer's base colour", 4),
    ("DEPTH", "G-Buffer Depth", "Show the G-buffer's camera distance, near bright, far dark", 5),
    ("POSITION", "G-Buffer Position", "Show the G-buffer's world position (fractional part per metre)", 6),
)


def _tag_object(ob, _context) -> None:
    """A bpy.props property set on an object tags nothing by itself: tag the object so the
    viewport's ``view_update`` sees the change (measured: no depsgraph update otherwise)."""
    ob.update_tag(refresh={"OBJECT"})


def _light_object_poll(_self, ob) -> bool:
    return ob.type == "LIGHT"


def _tag_viewport(_self, context) -> None:
    """Setting changes redraw rendered viewports (view_update does not see all of them)."""
    screen = getattr(context, "screen", None)
    if screen is None:
        return
    for area in screen.areas:
        if area.type == "VIEW_3D":
            area.tag_redraw()


class HybridShadowsSceneSettings(bpy.types.PropertyGroup):
    """The scene's shadow settings: one property per setting declared with a Blender property
    (``core/settings.py``, made by :func:`scene_properties`), and the viewport's own below."""

    viewport_quality: EnumProperty(name="Viewport Quality", items=QUALITY_ITEMS, default="HIGH",
                                   description="Resolution of the ray-traced shadow masks in the viewport once "
                                               "the view is still", update=_tag_viewport)
    navigation_quality: EnumProperty(name="While Navigating", items=NAVIGATION_ITEMS, default="AUTO",
                                     description="Resolution of the ray-traced shadow masks in the viewport "
                                                 "while the view or the scene changes (refined when still)",
                                     update=_tag_viewport)
    use_reuse_visibility: BoolProperty(
        name="Reuse Visibility", default=True,
        description="Viewport: after a camera move or an edit, pixels whose surface and shadow rays stay the "
                    "same keep the last frame's visibility instead of tracing it again (hard masks within "
                    "0.02% of fresh ones, exact again once the view rests; soft lights keep adding samples "
                    "while the view moves). Each hard light reuses only where that is timed cheaper than "
                    "tracing it again",
        update=_tag_viewport)
    use_reuse_animation: BoolProperty(
        name="Reuse Between Frames", default=False,
        description="Animation renders with Persistent Data: a hard light's pixels whose surface and shadow "
                    "ray stay the same keep the last frame's visibility (within 0.02% of fresh masks; soft "
                    "lights take their own samples). The masks stay in GPU memory between frames. Saves "
                    "time where rays are dear; with light grids it costs more than it saves on a software "
                    "rasteriser")
    viewport_max_shadowed_lights: IntProperty(name="Viewport Max Shadowed Lights", default=4, min=0, soft_max=64,
                                              description="Viewport: shadow only the N nearest shadow-casting "
                                                          "lights, suns first (0 = all; 4 is the real-time budget)",
                                              update=_tag_viewport)
    use_interlace: BoolProperty(name="Interlacing", default=False,
                                description="Viewport: trace a quarter of the shadow rays per redraw and keep "
                                            "the rest from the redraws before; after a change the pixels without "
                                            "an up-to-date ray are refined, and a still view is exact after four "
                                            "redraws (each about 0.4 of a full trace's time)",
                                update=_tag_viewport)
    viewport_samples: IntProperty(name="Viewport Samples", default=64, min=1, max=4096, soft_max=256,
                                  description="Viewport: shadow rays per pixel a still view accumulates towards each "
                                              "light with a size, a few per redraw (the first redraws filtered)")
    viewport_frame_samples: IntProperty(name="Samples per Redraw", default=4, min=1, max=64,
                                        description="Viewport: shadow rays per pixel and soft light each redraw adds "
                                                    "(the first redraw after a change: four times as many in the "
                                                    "penumbrae)")
    debug_view: EnumProperty(name="Debug View", items=DEBUG_ITEMS, default="NONE",
                             description="Viewport: show an intermediate buffer instead of the lit image",
                             update=_tag_viewport)
    debug_light: PointerProperty(name="Debug Light", type=bpy.types.Object, poll=_light_object_poll,
                                 description="Light whose shadow mask the Light Mask debug view shows "
                                             "(empty: the first shadowed light)", update=_tag_viewport)

    # -- mapping onto the core -------------------------------------------------------------------
    def to_settings(self, *, viewport: bool = False, navigating: bool = False) -> Settings:
        """The core :class:`Settings` for a final render, or for the viewport (``navigating``:
        the fast pass while the view or scene changes): each setting from its property, then the
        viewport's own (quality, light limit, interlacing, samples, accumulation)."""
        values = {name: from_property(FIELDS[name], getattr(self, prop)) for name, prop in PROPERTY_NAMES.items()}
        if viewport:
            quality = self.navigation_quality if navigating else self.viewport_quality
            if quality == "AUTO":  # (the render worker keeps the viewport quality on a software rasteriser)
                quality = "LOW"
            samples, frame_samples = int(self.viewport_samples), int(self.viewport_frame_samples)
            if navigating and self.use_soft_shadows:  # the fast pass: a few rays, no probe pass
                samples = frame_samples                  # (its accumulation starts after)
            limit = self.viewport_max_shadowed_lights
            values.update(quality=quality.lower(), max_shadowed_lights=int(limit) if limit > 0 else None,
                          interlace=bool(self.use_interlace), samples=samples, frame_samples=frame_samples,
                          accumulate=True)
        return Settings(**values)


def property_name(f) -> str:
    return (f.metadata["blender"] or {}).get("name", f.name)


#: setting name -> the scene property it comes from
PROPERTY_NAMES = {f.name: property_name(f) for f in FIELDS.values() if f.metadata["blender"] is not None}


def scene_property(f):
    """The ``bpy.props`` property of setting field ``f`` (its declaration in ``core/settings.py``)."""
    m, b = f.metadata, f.metadata["blender"]
    common = {"name": b.get("label", m["label"]), "description": b.get("help", m["help"])}
    if b.get("redraw"):
        common["update"] = _tag_viewport
    k = kind(f)
    if m["choices"] or "choices" in b:
        return EnumProperty(items=enum_items(f.name), default=str(f.default).upper(), **common)
    if k == "bool":
        return BoolProperty(default=(not f.default) if b.get("invert") else f.default, **common)
    limits = {key: v for key, v in (("min", m["low"]), ("max", m["high"]), ("soft_max", m["soft_max"]))
              if v is not None}
    extra = {key: b[key] for key in ("subtype", "unit", "precision", "step") if key in b}
    if k == "int":
        return IntProperty(default=0 if f.default is None else f.default, **limits, **extra, **common)
    return FloatProperty(default=f.default, **limits, **extra, **common)


def from_property(f, value):
    """Setting ``f``'s value from its property's ``value``."""
    b = f.metadata["blender"]
    k = kind(f)
    if k == "bool":
        return (not value) if b.get("invert") else bool(value)
    if k == "str":
        return str(value).lower()
    if k == "int":
        value = int(value)
        return None if f.metadata["optional"] and value <= 0 else value
    return float(value)


for _f in FIELDS.values():
    if _f.metadata["blender"] is not None:
        HybridShadowsSceneSettings.__annotations__[property_name(_f)] = scene_property(_f)


def owning_view_layer(settings):
    """The view layer whose ``hybrid_shadows`` is ``settings`` (None when not found)."""
    scene = settings.id_data
    for view_layer in getattr(scene, "view_layers", ()):
        if view_layer.hybrid_shadows.as_pointer() == settings.as_pointer():
            return view_layer
    return None


def _update_render_passes(self, _context) -> None:
    """A pass toggle re-registers the engine's passes (``RenderEngine.update_render_passes``),
    so the compositor's Render Layers sockets follow, as Cycles' pass toggles do."""
    view_layer = owning_view_layer(self)
    if view_layer is not None:
        view_layer.update_render_passes()


class HybridShadowsViewLayerSettings(bpy.types.PropertyGroup):
    use_pass_shadow: BoolProperty(name="Shadow", default=False, update=_update_render_passes,
                                  description="One pass per shadow-casting light, named 'Shadow <light>': 1 lit, "
                                              "0 shadowed (1 where there is no geometry)")
    use_pass_albedo: BoolProperty(name="Albedo", default=False, update=_update_render_passes,
                                  description="The base colour of the surfaces (Principled BSDF Base Color)")


CLASSES = (HybridShadowsSceneSettings, HybridShadowsViewLayerSettings)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.hybrid_shadows = PointerProperty(
        type=HybridShadowsSceneSettings, name="Hybrid Shadows", description="Hybrid Shadows render settings")
    bpy.types.ViewLayer.hybrid_shadows = PointerProperty(
        type=HybridShadowsViewLayerSettings, name="Hybrid Shadows", description="Hybrid Shadows render passes")
    bpy.types.Object.hybrid_sphere = BoolProperty(
        name="Sphere Primitive", default=False, update=_tag_object,
        description="Trace this object as an analytic sphere (its mesh's bounding sphere) instead of its triangles")


def unregister() -> None:
    for owner, name in ((bpy.types.Object, "hybrid_sphere"), (bpy.types.ViewLayer, "hybrid_shadows"),
                        (bpy.types.Scene, "hybrid_shadows")):
        if hasattr(owner, name):
            delattr(owner, name)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
