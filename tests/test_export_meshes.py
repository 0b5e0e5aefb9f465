"""Evaluated meshes: modifiers and Render ▸ Simplify applied, smooth-shading corner normals."""
import bpy
import numpy as np
import pytest

from tests.helpers.export_scenes import add_object, cube_mesh, empty_scene, export_scene

pytestmark = [pytest.mark.blender]


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()
def _bpy_triangles(name):
    ob = bpy.data.objects[name].evaluated_get(bpy.context.evaluated_depsgraph_get())
    return len(ob.data.loop_triangles)


# --------------------------------------------------------------------------------------------
# meshes
# --------------------------------------------------------------------------------------------
def test_modifiers_are_applied(scene):
    sub = add_object("Sub", cube_mesh("a"))
    sub.modifiers.new("S", "SUBSURF").levels = 2
    arr = add_object("Arr", cube_mesh("b"), location=(0, 10, 0))
    arr.modifiers.new("A", "ARRAY").count = 4
    s = export_scene()
    assert _bpy_triangles("Sub") == 192 and _bpy_triangles("Arr") == 48
    assert s.triangle_count == 192 + 48
    assert sorted(m.triangle_count for m in s.models) == [48, 192]


def test_simplify_limits_subdivision(scene):
    """Render ▸ Simplify (shown for this engine) reaches the export through the evaluated mesh."""
    from hybrid_shadow_addon.blender import ui

    ob = add_object("Sub", cube_mesh())
    mod = ob.modifiers.new("sub", "SUBSURF")
    mod.levels = 2
    full = export_scene().triangle_count
    scene.render.use_simplify = True
    scene.render.simplify_subdivision = 0
    assert export_scene().triangle_count == 12 < full
    assert bpy.types.RENDER_PT_simplify in ui.get_panels()


def test_smooth_shading_normals_are_exported(scene):
    flat = cube_mesh("flat")
    flat.polygons.foreach_set("use_smooth", np.zeros(len(flat.polygons), bool))
    smooth = cube_mesh("smooth")
    smooth.polygons.foreach_set("use_smooth", np.ones(len(smooth.polygons), bool))
    smooth.update()
    add_object("Flat", flat)
    add_object("Smooth", smooth, location=(5, 0, 0))
    s = export_scene()
    by_name = {m.name: m for m in s.models}
    assert by_name["flat"].normals is None
    n = by_name["smooth"].normals
    assert n.shape == (12, 3, 3)
    # smooth cube corners: normals along the corner's diagonal, the vertex position direction
    corner = by_name["smooth"].vertices[by_name["smooth"].triangles]
    np.testing.assert_allclose(n, corner / np.linalg.norm(corner, axis=2, keepdims=True), atol=1e-5)
