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

from ..core.bake.structures import DEFAULT_STRUCTURE, STRUCTURES
from ..core.settings import Settings

MODE_ITEMS = (
    ("RAYTRACE", "Ray Traced", "Shadow rays through the baked scene: soft shadows from the lights' sizes "
                               "(Soft Shadows on), else one ray per pixel towards each light's centre",
     "SHADING_RENDERED", 0),
    ("SHADOWMAP", "Shadow Map", "Rasterised shadow maps filtered with PCF, softened by the lights' sizes "
                                "(PCSS) with Soft Shadows on (fast, may alias or leak)", "LIGHT_SUN", 1),
    ("NONE", "None", "No shadows: every light reaches every surface", "LIGHT", 2),
)
QUALITY_ITEMS = (
    ("HIGH", "High", "Shadow rays at every pixel, for each light", 0),
    ("MEDIUM", "Medium", "Ray-traced: rays at every 2nd pixel per side, and a ray of its own for each pixel they "
                         "cannot stand for (shadow edges, creases, thin or grazing surfaces): nearly High's masks. "
                         "On a software rasteriser it costs more than High. Shadow maps: half-resolution masks", 1),
    ("LOW", "Low", "Ray-traced: rays at every 4th pixel per side, refined as Medium. On a software rasteriser it "
                   "costs more than High. Shadow maps: quarter-resolution masks", 2),
)
NAVIGATION_ITEMS = (
    ("AUTO", "Automatic", "Low on a GPU; on a software rasteriser (such as Mesa's llvmpipe), where Medium and Low "
                          "cost more than High, the viewport quality", 3),
) + QUALITY_ITEMS
SHADOWMAP_SIZE_ITEMS = tuple(
    (str(s), f"{s} px", f"Shadow maps of {s}x{s} texels (per cube face for point lights)", i)
    for i, s in enumerate((512, 1024, 2048, 4096, 8192))
)
UPSAMPLE_ITEMS = (
    ("BILATERAL", "Bilateral", "Depth and normal aware upsampling of reduced-resolution masks", 0),
    ("NEAREST", "Nearest", "Blocky nearest-texel upsampling (the thesis' look)", 1),
)
TRACE_PATH_ITEMS = (
    ("AUTO", "Automatic", "Compute shaders where the GPU offers OpenGL 4.3, fragment shaders elsewhere", 0),
    ("COMPUTE", "Compute", "Compute shaders over compact queues of the shadow rays: the time follows the rays "
                           "traced (OpenGL 4.3)", 1),
    ("FRAGMENT", "Fragment", "Full-screen fragment shaders, one ray per pixel (what OpenGL 4.1, macOS, offers)", 2),
)
CONSERVATIVE_ITEMS = (
    ("OFF", "Off", "Trace every shadow ray in full", 0),
    ("SUN", "Suns", "Conservative occupancy maps for suns: receivers no caster can reach take no ray, "
                    "the others stop at the first possible caster (the masks do not change)", 1),
    ("ALL", "All Lights", "Conservative occupancy maps for every light (a cube of six maps around point, "
                          "spot and area lights)", 2),
)
STRUCTURE_ITEMS = tuple((name.upper(), cls.label, cls.description, i)
                        for i, (name, cls) in enumerate(STRUCTURES.items()))
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
    mode: EnumProperty(name="Shadow Mode", items=MODE_ITEMS, default="RAYTRACE",
                       description="How shadows are made: ray traced, shadow maps or none",
                       update=_tag_viewport)
    quality: EnumProperty(name="Quality", items=QUALITY_ITEMS, default="HIGH",
                          description="Resolution of the ray-traced shadow masks in final renders",
                          update=_tag_viewport)
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
    max_distance: FloatProperty(name="Max Distance", default=0.0, min=0.0, soft_max=1000.0, subtype="DISTANCE",
                                unit="LENGTH", description="Shadows only within this distance of the camera "
                                                           "(0 = no limit)", update=_tag_viewport)
    max_shadowed_lights: IntProperty(name="Max Shadowed Lights", default=0, min=0, soft_max=64,
                                     description="Final and batch renders: shadow only the N nearest shadow-"
                                                 "casting lights, suns first (0 = every shadow-casting light)")
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
    shadowmap_size: EnumProperty(name="Shadow Map Resolution", items=SHADOWMAP_SIZE_ITEMS, default="2048",
                                 description="Texels per side of each shadow map (cube face for point lights)",
                                 update=_tag_viewport)
    pcf: IntProperty(name="PCF Radius", default=1, min=0, max=8,
                     description="Shadow-map filter kernel radius in texels (0 = one tap, hard and aliased)",
                     update=_tag_viewport)
    shadow_bias: FloatProperty(name="Bias", default=1.0, min=0.0, soft_max=10.0,
                               description="Constant shadow-map depth bias in texels", update=_tag_viewport)
    slope_bias: FloatProperty(name="Slope Bias", default=2.0, min=0.0, soft_max=10.0,
                              description="Slope-scaled shadow-map depth bias", update=_tag_viewport)
    normal_offset: FloatProperty(name="Normal Offset", default=1.5, min=0.0, soft_max=10.0,
                                 description="Offset of the receiver along its normal, in shadow-map texels",
                                 update=_tag_viewport)
    # Render ▸ Shadows ▸ Advanced (ui.py): choices for comparisons and research
    upsample: EnumProperty(name="Upsampling", items=UPSAMPLE_ITEMS, default="BILATERAL",
                           description="How reduced-resolution shadow masks are brought to full resolution",
                           update=_tag_viewport)
    conservative_maps: EnumProperty(name="Conservative Maps", items=CONSERVATIVE_ITEMS, default="OFF",
                                    description="Ray traced: skip or shorten shadow rays with conservative "
                                                "light-space occupancy maps; exact, it only changes the work",
                                    update=_tag_viewport)
    structure: EnumProperty(name="Structure", items=STRUCTURE_ITEMS, default=DEFAULT_STRUCTURE.upper(),
                            description="Ray traced: acceleration structure the shadow rays walk (the masks "
                                        "are the same; changing it re-bakes the scene)",
                            update=_tag_viewport)
    trace_path: EnumProperty(name="Trace Path", items=TRACE_PATH_ITEMS, default="AUTO",
                             description="Ray traced: how the hard shadow masks are traced (the masks are the "
                                         "same)", update=_tag_viewport)
    use_light_grid: BoolProperty(name="Light Grids", default=True,
                                 description="Ray traced, BVH: a hard light's shadow rays look up a grid of the "
                                             "casters laid out around that light instead of walking the tree "
                                             "(faster; rebuilt when the light moves; scenes with alpha-cut "
                                             "casters keep the tree)",
                                 update=_tag_viewport)
    pcss_samples: IntProperty(name="Soft Filter Taps", default=32, min=1, max=1024, soft_max=128,
                              description="Shadow maps of lights with a size: percentage-closer soft shadow "
                                          "filter taps (the blocker search takes half as many)")
    use_soft_shadows: BoolProperty(name="Soft Shadows", default=True,
                                   description="Honour the lights' sizes (sun angle, point and spot radius, area "
                                               "light size) with several shadow rays per pixel; off: every light "
                                               "is hard, one ray to its centre")
    samples: IntProperty(name="Shadow Samples", default=64, min=1, max=4096, soft_max=256,
                         description="Final render: shadow rays per pixel towards each light with a size "
                                     "(pixels away from any penumbra take 1)")
    noise_target: FloatProperty(name="Noise Target", default=Settings.noise_target, min=0.0, soft_max=0.02,
                                precision=4, step=0.01,
                                description="Final render: a light whose shadow mask's noise is estimated above this "
                                            "(mean error of its shares) gives its penumbrae as many samples again "
                                            "(0: never)")
    viewport_samples: IntProperty(name="Viewport Samples", default=64, min=1, max=4096, soft_max=256,
                                  description="Viewport: shadow rays per pixel a still view accumulates towards each "
                                              "light with a size, a few per redraw (the first redraws filtered)")
    viewport_frame_samples: IntProperty(name="Samples per Redraw", default=4, min=1, max=64,
                                        description="Viewport: shadow rays per pixel and soft light each redraw adds "
                                                    "(the first redraw after a change: four times as many in the "
                                                    "penumbrae)")
    transparency_samples: IntProperty(name="See-Through Samples", default=Settings.transparency_samples, min=1,
                                      max=4096, soft_max=64,
                                      description="Where the camera sees see-through surfaces (blended materials "
                                                  "with an alpha between 0 and 1): frames of stochastic "
                                                  "transparency averaged, so that each shows alpha x itself + "
                                                  "(1 - alpha) x what lies behind, as in Cycles. A final render "
                                                  "renders them all, a still viewport one per redraw; scenes "
                                                  "without such surfaces render one frame. 1: a surface shows "
                                                  "where its alpha is at least 0.5")
    use_specular: BoolProperty(name="Specular", default=True,
                               description="Add the specular lobe of the materials to the lighting",
                               update=_tag_viewport)
    debug_view: EnumProperty(name="Debug View", items=DEBUG_ITEMS, default="NONE",
                             description="Viewport: show an intermediate buffer instead of the lit image",
                             update=_tag_viewport)
    debug_light: PointerProperty(name="Debug Light", type=bpy.types.Object, poll=_light_object_poll,
                                 description="Light whose shadow mask the Light Mask debug view shows "
                                             "(empty: the first shadowed light)", update=_tag_viewport)

    # -- mapping onto the core -------------------------------------------------------------------
    def to_settings(self, *, viewport: bool = False, navigating: bool = False) -> Settings:
        """The core :class:`Settings` for a final render, or for the viewport (``navigating``:
        the fast pass while the view or scene changes)."""
        if viewport:
            quality = self.navigation_quality if navigating else self.viewport_quality
            if quality == "AUTO":  # (the render worker keeps the viewport quality on a software rasteriser)
                quality = "LOW"
            limit = self.viewport_max_shadowed_lights
            interlace = bool(self.use_interlace)
            samples, frame_samples = int(self.viewport_samples), int(self.viewport_frame_samples)
            if navigating and self.use_soft_shadows:  # the fast pass: a few rays, no probe pass
                samples = frame_samples                  # (its accumulation starts after)
        else:
            quality, limit, interlace = self.quality, self.max_shadowed_lights, False
            samples, frame_samples = int(self.samples), 4
        return Settings(
            noise_target=float(self.noise_target),
            mode=self.mode.lower(), quality=quality.lower(), max_distance=float(self.max_distance),
            max_shadowed_lights=int(limit) if limit > 0 else None, interlace=interlace,
            shadowmap_size=int(self.shadowmap_size), pcf=int(self.pcf), shadow_bias=float(self.shadow_bias),
            slope_bias=float(self.slope_bias), normal_offset=float(self.normal_offset),
            upsample=self.upsample.lower(), specular=bool(self.use_specular),
            conservative=self.conservative_maps.lower(), structure=self.structure.lower(),
            light_grid=bool(self.use_light_grid), samples=samples, hard=not self.use_soft_shadows,
            pcss_samples=int(self.pcss_samples), accumulate=viewport, frame_samples=frame_samples,
            transparency_samples=int(self.transparency_samples), trace_path=self.trace_path.lower(),
        )


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
