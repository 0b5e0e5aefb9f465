"""The stock panels shown for this engine: an allow-list of Blender's own panels whose settings
reach what the engine renders or what Blender writes from its result. Panels of features the
engine does not render (Freestyle, stereoscopy and multiview, light probes, volumes, Grease
Pencil, EEVEE's material and light settings) stay hidden, as do the stock panels the engine's
own panels replace (passes, light settings, spot shape, object shading).

:func:`stock_panels` returns the registered panel classes named here; names missing from a
Blender version are skipped.
"""
from __future__ import annotations

import bpy

#: stock panels by name, grouped by what the engine reads of them
ALLOWED_PANELS = frozenset({
    # Output tab: resolution, frame range and the file Blender writes from the render result
    "RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_time_stretching", "RENDER_PT_output",
    "RENDER_PT_output_color_management", "RENDER_PT_output_pixel_density", "RENDER_PT_encoding",
    "RENDER_PT_encoding_video", "RENDER_PT_encoding_audio", "RENDER_PT_post_processing", "RENDER_PT_stamp",
    "RENDER_PT_stamp_note", "RENDER_PT_stamp_burn",
    # Render tab: the view transform Blender applies to the engine's linear result; Simplify
    # (subdivision and child-particle levels of the evaluated geometry the export reads)
    "RENDER_PT_color_management", "RENDER_PT_color_management_display_settings",
    "RENDER_PT_color_management_white_balance", "RENDER_PT_simplify", "RENDER_PT_simplify_viewport",
    "RENDER_PT_simplify_render",
    # View Layer tab: which layers render
    "VIEWLAYER_PT_layer",
    # Object tab: visibility (render, camera and shadow rays), custom properties (hybrid_sphere)
    "OBJECT_PT_visibility", "OBJECT_PT_custom_props",
    # Camera: the engine's view (lens, clipping, sensor, shift) and its viewport overlays
    "DATA_PT_context_camera", "DATA_PT_lens", "DATA_PT_camera", "DATA_PT_camera_display",
    "DATA_PT_camera_display_composition_guides", "DATA_PT_camera_safe_areas",
    "DATA_PT_camera_safe_areas_center_cut", "DATA_PT_camera_background_image", "DATA_PT_camera_animation",
    "DATA_PT_custom_props_camera", "CAMERA_PT_presets", "CAMERA_PT_safe_areas_presets",
    # Light: its type (the engine's Light Settings and Shadow panels draw the rest)
    "DATA_PT_context_light", "DATA_PT_light", "NODE_DATA_PT_light", "DATA_PT_custom_props_light",
    # Mesh, hair curves and point clouds: the geometry the export reads (UV maps for textures,
    # attributes, shape keys and vertex groups that shape the evaluated mesh)
    "DATA_PT_context_mesh", "DATA_PT_texture_space", "DATA_PT_vertex_groups", "DATA_PT_shape_keys",
    "DATA_PT_uv_texture", "DATA_PT_remesh", "DATA_PT_customdata", "DATA_PT_mesh_animation",
    "DATA_PT_custom_props_mesh", "DATA_PT_mesh_attributes", "DATA_PT_vertex_colors",
    "DATA_PT_context_curves", "DATA_PT_curves_surface", "DATA_PT_CURVES_attributes", "DATA_PT_curves_animation",
    "DATA_PT_custom_props_curves", "DATA_PT_context_pointcloud", "DATA_PT_pointcloud_attributes",
    "DATA_PT_custom_props_pointcloud",
    # Speakers: the audio Blender muxes into a video output
    "DATA_PT_context_speaker", "DATA_PT_speaker", "DATA_PT_distance", "DATA_PT_cone", "DATA_PT_speaker_animation",
    "DATA_PT_custom_props_speaker",
    # Material and World data blocks; image-texture mapping in the node editor
    "MATERIAL_PT_custom_props", "MATERIAL_PT_animation", "WORLD_PT_context_world", "WORLD_PT_animation",
    "WORLD_PT_custom_props", "NODE_PT_texture_mapping", "SEQUENCER_PT_custom_props",
})

#: families allowed by prefix: particles (hair strands and instances the export reads), physics
#: (simulations that move the geometry), textures (displacement and particle textures)
ALLOWED_PREFIXES = ("PARTICLE_PT_", "PHYSICS_PT_", "TEXTURE_PT_")


def is_allowed(name: str) -> bool:
    """Whether the stock panel class ``name`` is shown for this engine."""
    return name in ALLOWED_PANELS or name.startswith(ALLOWED_PREFIXES)


def stock_panels() -> list:
    """The registered stock panel classes of the allow-list, among those marked for
    ``BLENDER_RENDER`` (Blender's mark of panels any engine may reuse)."""
    out = []
    for panel in bpy.types.Panel.__subclasses__():
        compat = getattr(panel, "COMPAT_ENGINES", None)
        if compat is not None and "BLENDER_RENDER" in compat and is_allowed(panel.__name__):
            out.append(panel)
    return out
