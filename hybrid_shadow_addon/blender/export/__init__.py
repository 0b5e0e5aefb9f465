"""Export an evaluated depsgraph to the bpy-free scene model.

:func:`export_depsgraph` reads what Blender renders: modifiers applied, every instance (linked
duplicates, collection instances, particles, geometry-nodes instances) placed as an instance of
one shared :class:`~hybrid_shadow_addon.core.scene.Model` per evaluated mesh and material slot.

Modules: :mod:`.objects` walks the depsgraph and its instances, :mod:`.meshes` reads mesh arrays,
normals and UVs and splits meshes by slot, :mod:`.materials` reads node graphs, :mod:`.images`
their images, :mod:`.shading` collects the per-instance attributes, :mod:`.lights`,
:mod:`.camera` and :mod:`.world` the rest of the scene; each module's names are imported from it.
"""
from __future__ import annotations

from ...core.scene import Scene
from .objects import SceneExporter


def export_depsgraph(depsgraph, *, resolution=None, render_visibility: bool | None = None,
                     should_stop=None) -> Scene:
    """The scene of an evaluated depsgraph at its current frame.

    ``render_visibility``: drop what is hidden from render (default: for a viewport depsgraph,
    so that it exports what F12 renders); False keeps what the viewport shows, as Cycles' and
    EEVEE's rendered viewports do.

    ``resolution``: ``(width, height)`` overriding the render settings (default: resolution x/y
    times the percentage). Raises :class:`SceneError` naming the object for a NaN or infinite
    transform (``Scene.check_transforms``); the remaining checks are ``Scene.validate``'s.
    ``should_stop()``: asked before each object; True raises :class:`Cancelled`.
    """
    return SceneExporter(depsgraph, render_visibility, should_stop).run(resolution)


__all__ = [
    "GEOMETRY_TYPES", "SPHERE_PROPERTY", "ExportWarning", "MaterialReading", "ModelTable", "RenderVisibility",
    "SceneExporter", "ShadingTable", "TextureLink", "blend_settings", "export_camera", "export_depsgraph",
    "export_light", "export_lights", "image_pixels", "is_sphere_primitive", "light_color", "light_power",
    "mapping_affine", "material_surface", "mesh_arrays", "mesh_uv_layer", "mesh_uvs", "principled_node",
    "read_material", "render_resolution", "slot_name", "slot_owner", "slot_triangles", "smooth_normals",
    "to_matrices", "to_matrix", "used_slots", "world_background", "world_color",
]
