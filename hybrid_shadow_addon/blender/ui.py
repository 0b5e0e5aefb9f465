"""Panels of the Hybrid Shadows engine (Render, View Layer, Object and Light tabs), the shadow
mode in the 3D viewport header, and the standard panels shown for this engine.

Every panel polls on the engine (Cycles' ``COMPAT_ENGINES`` pattern). :func:`get_panels` lists
the standard panels that make sense for this engine; :func:`register` adds the engine to their
``COMPAT_ENGINES`` and :func:`unregister` removes it again.
"""
from __future__ import annotations

import bpy

from .compare_operator import draw_compare_button
from .engine import ENGINE_ID


class HybridShadowsPanel:
    """Properties-editor panels of this engine: shown only while it is the render engine."""

    COMPAT_ENGINES = {ENGINE_ID}
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def split_layout(self):
        """The panel's layout with Blender's label-beside-value style."""
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        return layout


class RenderSubPanel(HybridShadowsPanel):
    """A folded sub-panel of Render ▸ Shadows."""

    bl_context = "render"
    bl_parent_id = "RENDER_PT_hybrid_shadows"
    bl_options = {"DEFAULT_CLOSED"}


class RENDER_PT_hybrid_shadows(HybridShadowsPanel, bpy.types.Panel):
    bl_label = "Shadows"
    bl_context = "render"

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        layout.row().prop(props, "mode", expand=True)
        col = layout.column()
        col.active = props.mode == "RAYTRACE"
        col.prop(props, "quality", text="Render Quality")
        col.prop(props, "upsample")
        col.prop(props, "conservative_maps")
        draw_compare_button(layout)


class RENDER_PT_hybrid_shadows_limits(RenderSubPanel, bpy.types.Panel):
    bl_label = "Limits"
    bl_options = set()  # open

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        col = layout.column(align=True)
        col.prop(props, "viewport_max_shadowed_lights", text="Shadowed Lights Viewport")
        col.prop(props, "max_shadowed_lights", text="Render")
        layout.prop(props, "max_distance")


class RENDER_PT_hybrid_shadows_viewport(RenderSubPanel, bpy.types.Panel):
    bl_label = "Viewport"
    bl_options = set()  # open

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        col = layout.column()
        col.active = props.mode == "RAYTRACE"
        col.prop(props, "viewport_quality", text="Quality")
        col.prop(props, "navigation_quality")
        col.prop(props, "use_interlace")


class RENDER_PT_hybrid_shadows_shadowmap(RenderSubPanel, bpy.types.Panel):
    bl_label = "Shadow Maps"

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        layout.active = props.mode == "SHADOWMAP"
        layout.prop(props, "shadowmap_size", text="Resolution")
        layout.prop(props, "pcf")
        col = layout.column(align=True)
        col.prop(props, "shadow_bias")
        col.prop(props, "slope_bias")
        col.prop(props, "normal_offset")


class RENDER_PT_hybrid_shadows_lighting(RenderSubPanel, bpy.types.Panel):
    bl_label = "Lighting"

    def draw(self, context):
        layout = self.split_layout()
        layout.prop(context.scene.hybrid_shadows, "use_specular")
        layout.prop(context.scene.render, "film_transparent")


class RENDER_PT_hybrid_shadows_debug(RenderSubPanel, bpy.types.Panel):
    bl_label = "Debug"

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        layout.prop(props, "debug_view", text="View")
        row = layout.row()
        row.active = props.debug_view == "LIGHT_MASK"
        row.prop(props, "debug_light", text="Light")


class VIEWLAYER_PT_hybrid_shadows_passes(HybridShadowsPanel, bpy.types.Panel):
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = self.split_layout()
        vl = context.view_layer
        col = layout.column(heading="Data", align=True)
        col.prop(vl, "use_pass_combined")
        col.prop(vl, "use_pass_z")
        col.prop(vl, "use_pass_normal")
        col.prop(vl.hybrid_shadows, "use_pass_albedo")
        col = layout.column(heading="Light", align=True)
        col.prop(vl.hybrid_shadows, "use_pass_shadow", text="Shadow per Light")


class OBJECT_PT_hybrid_shadows(HybridShadowsPanel, bpy.types.Panel):
    bl_label = "Hybrid Shadows"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        ob = context.object
        return super().poll(context) and ob is not None and ob.type in {"MESH", "CURVE", "SURFACE", "FONT", "META"}

    def draw(self, context):
        layout = self.split_layout()
        ob = context.object
        layout.prop(ob, "visible_shadow", text="Cast Shadow")
        layout.prop(ob, "hybrid_sphere")


class DATA_PT_hybrid_shadows_light(HybridShadowsPanel, bpy.types.Panel):
    bl_label = "Shadow"
    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.light is not None

    def draw_header(self, context):
        self.layout.prop(context.light, "use_shadow", text="")

    def draw(self, context):
        layout = self.split_layout()
        light = context.light
        layout.active = light.use_shadow
        if light.type == "SUN":
            layout.prop(light, "angle")
        else:
            layout.prop(light, "shadow_soft_size", text="Radius")
        layout.label(text="Hybrid shadows are hard: the size only affects shading", icon="INFO")


def draw_viewport_header(self, context):
    """Shadow mode in the 3D viewport header while the engine is active."""
    if context.engine != ENGINE_ID:
        return
    props = context.scene.hybrid_shadows
    row = self.layout.row(align=True)
    row.prop(props, "mode", text="")


CLASSES = (
    RENDER_PT_hybrid_shadows, RENDER_PT_hybrid_shadows_limits, RENDER_PT_hybrid_shadows_viewport,
    RENDER_PT_hybrid_shadows_shadowmap, RENDER_PT_hybrid_shadows_lighting, RENDER_PT_hybrid_shadows_debug,
    VIEWLAYER_PT_hybrid_shadows_passes, OBJECT_PT_hybrid_shadows, DATA_PT_hybrid_shadows_light,
)

#: standard panels (carrying the legacy 'BLENDER_RENDER' marker) that do not fit this engine
EXCLUDED_PANELS = {
    "VIEWLAYER_PT_filter", "VIEWLAYER_PT_layer_passes", "RENDER_PT_simplify", "RENDER_PT_freestyle",
    "RENDER_PT_color_management_curves", "DATA_PT_light_animation", "DATA_PT_preview",
}


def get_panels() -> list:
    """The standard panels shown for this engine: those marked for ``BLENDER_RENDER`` (Blender's
    convention for panels any engine may reuse: Light, Spot Shape, Object, Output, Color
    Management, ...) minus :data:`EXCLUDED_PANELS`."""
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        compat = getattr(panel, "COMPAT_ENGINES", None)
        if compat is not None and "BLENDER_RENDER" in compat and panel.__name__ not in EXCLUDED_PANELS:
            panels.append(panel)
    return panels


_added_to: list = []


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for panel in get_panels():
        if ENGINE_ID not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add(ENGINE_ID)
            _added_to.append(panel)
    bpy.types.VIEW3D_HT_header.append(draw_viewport_header)


def unregister() -> None:
    bpy.types.VIEW3D_HT_header.remove(draw_viewport_header)
    for panel in _added_to:
        panel.COMPAT_ENGINES.discard(ENGINE_ID)
    _added_to.clear()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
