"""Panels of the Hybrid Shadows engine (Render, View Layer, Object, Light, Material and World
tabs), the shadow mode in the 3D viewport header, and the standard panels shown for this engine.

Every panel polls on the engine (Cycles' ``COMPAT_ENGINES`` pattern). :func:`get_panels` lists
the stock panels whose settings the engine reads (:mod:`.stock_panels`); :func:`register` adds the engine to their
``COMPAT_ENGINES`` and :func:`unregister` removes it again.
"""
from __future__ import annotations

import bpy

from ..core.bake.structures import STRUCTURES
from .compare_operator import draw_compare_button
from .engine import ENGINE_ID
from .export.materials import principled_node
from .export.world import world_background
from .stock_panels import stock_panels


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
        sub = col.column()
        sub.active = STRUCTURES[props.structure.lower()].supports_light_grids
        sub.prop(props, "use_light_grid")
        col = layout.column()
        col.active = props.mode == "RAYTRACE"
        col.prop(props, "use_soft_shadows")
        sub = col.column()
        sub.active = props.use_soft_shadows
        sub.prop(props, "samples", text="Render Samples")
        sub.prop(props, "noise_target")
        layout.prop(props, "transparency_samples")
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
        casting = sum(1 for ob in context.view_layer.objects if ob.type == "LIGHT" and ob.data.use_shadow)
        limit = props.viewport_max_shadowed_lights
        if 0 < limit < casting:
            layout.label(text=f"Viewport: {casting - limit} of {casting} shadow-casting lights unshadowed "
                              "(0 shadows all)", icon="ERROR")
        layout.prop(props, "max_distance")
        layout.prop(context.scene.render, "use_persistent_data", text="Persistent Data")
        row = layout.row()
        row.active = context.scene.render.use_persistent_data
        row.prop(props, "use_reuse_animation")


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
        col.prop(props, "use_reuse_visibility")
        sub = col.column(align=True)
        sub.active = props.use_soft_shadows
        sub.prop(props, "viewport_samples", text="Soft Samples")
        sub.prop(props, "viewport_frame_samples")


class RENDER_PT_hybrid_shadows_shadowmap(RenderSubPanel, bpy.types.Panel):
    bl_label = "Shadow Maps"

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        layout.active = props.mode == "SHADOWMAP"
        layout.prop(props, "shadowmap_size", text="Resolution")
        layout.prop(props, "pcf")
        sub = layout.column()
        sub.active = props.use_soft_shadows
        sub.prop(props, "pcss_samples")
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


class RENDER_PT_hybrid_shadows_advanced(RenderSubPanel, bpy.types.Panel):
    """Choices for comparisons and research, not for the artist's everyday render."""

    bl_label = "Advanced"

    def draw(self, context):
        layout = self.split_layout()
        props = context.scene.hybrid_shadows
        col = layout.column()
        col.active = props.mode == "RAYTRACE"
        col.prop(props, "upsample")
        col.prop(props, "structure")
        col.prop(props, "conservative_maps")
        col.prop(props, "trace_path")


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


class OBJECT_PT_hybrid_shadows_terminator(HybridShadowsPanel, bpy.types.Panel):
    """Cycles' object settings that move the shadow rays of smooth-shaded triangles near the
    terminator, as Cycles' Shading > Shadow Terminator panel shows them: the Geometry Offset
    decides the shadows (read by the export); the Shading Offset only softens Cycles' shading,
    which the preview's lighting does not apply (the export reports it when set)."""

    bl_label = "Shadow Terminator"
    bl_context = "object"
    bl_parent_id = "OBJECT_PT_hybrid_shadows"

    @classmethod
    def poll(cls, context):
        return OBJECT_PT_hybrid_shadows.poll(context)

    def draw(self, context):
        layout = self.split_layout()
        ob = context.object
        layout.prop(ob, "shadow_terminator_geometry_offset", text="Geometry Offset")
        layout.prop(ob, "shadow_terminator_shading_offset", text="Shading Offset")


class LightPanel(HybridShadowsPanel):
    """A panel of the Light tab (Object Data of a light)."""

    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.light is not None


class DATA_PT_hybrid_shadows_light_settings(LightPanel, bpy.types.Panel):
    """What the engine reads of a light, below the stock Light panel (which draws its type)."""

    bl_label = "Light Settings"

    def draw(self, context):
        layout = self.split_layout()
        light = context.light
        col = layout.column()
        if getattr(light, "use_temperature", None) is not None:  # Blender 4.5+
            row = col.row(align=True)
            row.prop(light, "use_temperature", text="Temperature", expand=False)
            sub = row.row(align=True)
            sub.active = light.use_temperature
            sub.prop(light, "temperature", text="")
        col.prop(light, "color")
        col.prop(light, "energy", text="Strength" if light.type == "SUN" else "Power")
        if hasattr(light, "exposure"):
            col.prop(light, "exposure")
        if light.type == "AREA" and hasattr(light, "normalize"):
            col.prop(light, "normalize")
        col.separator()
        if light.type == "SUN":
            col.prop(light, "angle")
        elif light.type in ("POINT", "SPOT"):
            col.prop(light, "shadow_soft_size", text="Radius")
        elif light.type == "AREA":
            col.prop(light, "shape")
            sub = col.column(align=True)
            if light.shape in ("SQUARE", "DISK"):
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
            if hasattr(light, "spread"):
                col.prop(light, "spread")
        if light.type == "SPOT":
            col.separator()
            col.prop(light, "spot_size", text="Spot Size")
            col.prop(light, "spot_blend", text="Blend")
            col.prop(light, "show_cone")


#: the property that gives each light type its size, and its label
LIGHT_SIZE = {"SUN": ("angle", "angle"), "POINT": ("shadow_soft_size", "radius"),
              "SPOT": ("shadow_soft_size", "radius"), "AREA": ("size", "size")}


def shadow_note(light, props) -> str:
    """What the engine makes of ``light``'s shadow under the scene settings ``props``, in words
    (the Light ▸ Shadow panel's line): soft from the light's size unless Soft Shadows is off
    or the size is 0, hard otherwise."""
    if props.mode == "NONE":
        return "No shadows: the shadow mode is None (Render ▸ Shadows)"
    if not light.use_shadow:
        return "Casts no shadow"
    name, what = LIGHT_SIZE.get(light.type, (None, "size"))
    hard = "Hard (PCF shadow map)" if props.mode == "SHADOWMAP" else "Hard (one ray towards the light's centre)"
    if not props.use_soft_shadows:
        return f"{hard}: Soft Shadows is off (Render ▸ Shadows)"
    if name is None or not getattr(light, name, 0.0) > 0.0:
        return f"{hard}: the light's {what} is 0"
    if props.mode == "SHADOWMAP":
        return f"Soft: shadow maps filtered by the light's {what} (PCSS)"
    return f"Soft: up to {props.samples} shadow rays per pixel over the light's {what}"


class DATA_PT_hybrid_shadows_light(LightPanel, bpy.types.Panel):
    """The light's shadow switch and what the engine makes of it (soft from the light's size
    while Render ▸ Shadows ▸ Soft Shadows is on, which is the default)."""

    bl_label = "Shadow"

    def draw_header(self, context):
        self.layout.prop(context.light, "use_shadow", text="")

    def draw(self, context):
        layout = self.split_layout()
        light = context.light
        props = context.scene.hybrid_shadows
        layout.active = light.use_shadow
        layout.prop(props, "use_soft_shadows")  # (the size: Light Settings above)
        layout.label(text=shadow_note(light, props), icon="INFO")


def _draw_input(layout, node, name, text=None):
    sock = node.inputs[name]
    if sock.is_linked:
        row = layout.row()
        row.label(text=text or name)
        row.label(text=f"linked to {sock.links[0].from_node.name}: not read", icon="ERROR")
    else:
        layout.prop(sock, "default_value", text=text or name)


class MATERIAL_PT_hybrid_shadows_context(HybridShadowsPanel, bpy.types.Panel):
    """Material slots of the active object, as Cycles and EEVEE show them."""

    bl_label = ""
    bl_context = "material"
    bl_options = {"HIDE_HEADER"}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and (context.material is not None or context.object is not None)

    def draw(self, context):
        layout = self.layout
        ob = context.object
        slot = context.material_slot
        if ob is not None:
            is_sortable = len(ob.material_slots) > 1
            rows = 5 if is_sortable else 3
            row = layout.row()
            row.template_list("MATERIAL_UL_matslots", "", ob, "material_slots", ob, "active_material_index",
                              rows=rows)
            col = row.column(align=True)
            col.operator("object.material_slot_add", icon="ADD", text="")
            col.operator("object.material_slot_remove", icon="REMOVE", text="")
        row = layout.row()
        if ob is not None:
            row.template_ID(ob, "active_material", new="material.new")
            if slot is not None:
                row.prop(slot, "link", icon_only=True)
        elif context.material is not None:
            row.template_ID(context.space_data, "pin_id")


class MaterialPanel(HybridShadowsPanel):
    """A panel of the Material tab about the shown material."""

    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.material is not None


class MATERIAL_PT_hybrid_shadows_surface(MaterialPanel, bpy.types.Panel):
    """The surface values the engine reads: the Principled BSDF's base colour, alpha, specular
    and roughness (or the material's viewport values without one)."""

    bl_label = "Surface"

    def draw(self, context):
        layout = self.split_layout()
        mat = context.material
        node = principled_node(mat.node_tree) if mat.use_nodes and mat.node_tree else None
        if node is None:
            if not mat.use_nodes:
                layout.prop(mat, "use_nodes", icon="NODETREE")
            layout.prop(mat, "diffuse_color", text="Base Color")
            layout.prop(mat, "specular_intensity", text="Specular")
            layout.prop(mat, "roughness")
            return
        layout.label(text=node.name, icon="NODE_MATERIAL")
        for name, text in (("Base Color", None), ("Alpha", None), ("Specular IOR Level", "Specular"),
                           ("Roughness", None)):
            _draw_input(layout, node, name, text)


class MATERIAL_PT_hybrid_shadows_settings(MaterialPanel, bpy.types.Panel):
    """The material settings the export reads for shadows: Transparent Shadows (an alpha-cut or
    see-through material lets light through in its shadow; off, it casts a full shadow) and
    the Alpha Clip method of Blender before 4.2."""

    bl_label = "Settings"

    def draw(self, context):
        layout = self.split_layout()
        mat = context.material
        if hasattr(mat, "use_transparent_shadow"):
            layout.prop(mat, "use_transparent_shadow", text="Transparent Shadows")
        elif hasattr(mat, "shadow_method"):
            layout.prop(mat, "shadow_method", text="Shadow Mode")
        if getattr(mat, "blend_method", None) == "CLIP" and hasattr(mat, "alpha_threshold"):
            layout.prop(mat, "alpha_threshold", text="Clip Threshold")


class WORLD_PT_hybrid_shadows(HybridShadowsPanel, bpy.types.Panel):
    """The world colour the engine uses as ambient light: the Background node's colour and
    strength, else the world's viewport colour."""

    bl_label = "Surface"
    bl_context = "world"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.world is not None

    def draw(self, context):
        layout = self.split_layout()
        world = context.world
        bg = world_background(world)
        if bg is None:
            if not world.use_nodes:
                layout.prop(world, "use_nodes", icon="NODETREE")
            layout.prop(world, "color")
            return
        _draw_input(layout, bg, "Color")
        _draw_input(layout, bg, "Strength")


def draw_viewport_header(self, context):
    """Shadow mode in the 3D viewport header while the engine is active."""
    if context.engine != ENGINE_ID:
        return
    props = context.scene.hybrid_shadows
    row = self.layout.row(align=True)
    row.prop(props, "mode", text="")


CLASSES = (
    RENDER_PT_hybrid_shadows, RENDER_PT_hybrid_shadows_limits, RENDER_PT_hybrid_shadows_viewport,
    RENDER_PT_hybrid_shadows_shadowmap, RENDER_PT_hybrid_shadows_lighting, RENDER_PT_hybrid_shadows_advanced,
    RENDER_PT_hybrid_shadows_debug,
    VIEWLAYER_PT_hybrid_shadows_passes, OBJECT_PT_hybrid_shadows, OBJECT_PT_hybrid_shadows_terminator,
    DATA_PT_hybrid_shadows_light_settings,
    DATA_PT_hybrid_shadows_light, MATERIAL_PT_hybrid_shadows_context, MATERIAL_PT_hybrid_shadows_surface,
    MATERIAL_PT_hybrid_shadows_settings, WORLD_PT_hybrid_shadows,
)

def get_panels() -> list:
    """The stock panels shown for this engine: the allow-list of :mod:`.stock_panels` (those
    whose settings the engine reads or Blender writes from its result)."""
    return stock_panels()


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
