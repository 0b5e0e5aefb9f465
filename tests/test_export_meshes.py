"""Evaluated meshes: modifiers and Render ▸ Simplify applied, smooth-shading corner normals."""
import bpy
import numpy as np
import pytest

from tests.helpers.export_scenes import add_object as _add
from tests.helpers.export_scenes import cube_mesh as _cube_mesh
from tests.helpers.export_scenes import empty_scene
from tests.helpers.export_scenes import export_scene as _export

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
    sub = _add("Sub", _cube_mesh("a"))
    sub.modifiers.new("S", "SUBSURF").levels = 2
    arr = _add("Arr", _cube_mesh("b"), location=(0, 10, 0))
    arr.modifiers.new("A", "ARRAY").count = 4
    s = _export()
    assert _bpy_triangles("Sub") == 192 and _bpy_triangles("Arr") == 48
    assert s.triangle_count == 192 + 48
    assert sorted(m.triangle_count for m in s.models) == [48, 192]


def test_simplify_limits_subdivision(scene):
    """Render ▸ Simplify (shown for this engine) reaches the export through the evaluated mesh."""
    from hybrid_shadow_addon.blender import ui

    ob = _add("Sub", _cube_mesh())
    mod = ob.modifiers.new("sub", "SUBSURF")
    mod.levels = 2
    full = _export().triangle_count
    scene.render.use_simplify = True
    scene.render.simplify_subdivision = 0
    assert _export().triangle_count == 12 < full
    assert bpy.types.RENDER_PT_simplify in ui.get_panels()


def test_smooth_shading_normals_are_exported(scene):
    flat = _cube_mesh("flat")
    flat.polygons.foreach_set("use_smooth", np.zeros(len(flat.polygons), bool))
    smooth = _cube_mesh("smooth")
    smooth.polygons.foreach_set("use_smooth", np.ones(len(smooth.polygons), bool))
    smooth.update()
    _add("Flat", flat)
    _add("Smooth", smooth, location=(5, 0, 0))
    s = _export()
    by_name = {m.name: m for m in s.models}
    assert by_name["flat"].normals is None
    n = by_name["smooth"].normals
    assert n.shape == (12, 3, 3)
    # smooth cube corners: normals along the corner's diagonal, the vertex position direction
    corner = by_name["smooth"].vertices[by_name["smooth"].triangles]
    np.testing.assert_allclose(n, corner / np.linalg.norm(corner, axis=2, keepdims=True), atol=1e-5)
