"""The scene camera, the world colour and the render resolution."""
import bpy
import numpy as np
import pytest

from tests.helpers.export_scenes import empty_scene, export_scene

pytestmark = [pytest.mark.blender]


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()


# --------------------------------------------------------------------------------------------
# camera, world, resolution
# --------------------------------------------------------------------------------------------
def test_camera_world_and_resolution(scene):
    cam = scene.camera.data
    cam.type, cam.ortho_scale, cam.sensor_fit = "ORTHO", 12.0, "VERTICAL"
    cam.shift_x, cam.clip_start, cam.clip_end = 0.1, 0.5, 300.0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 1001, 500, 50
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.2, 0.4, 0.6, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.5
    scene.world = world
    s = export_scene()
    c = s.camera
    assert (c.type, c.ortho_scale, c.sensor_fit, c.shift_x) == ("ORTHO", 12.0, "VERTICAL", pytest.approx(0.1))
    assert (c.clip_start, c.clip_end) == (0.5, 300.0)
    np.testing.assert_allclose(c.matrix, np.array(scene.camera.matrix_world))
    assert s.resolution == (500, 250)
    assert export_scene(resolution=(64, 32)).resolution == (64, 32)
    np.testing.assert_allclose(s.world_color, (0.1, 0.2, 0.3), rtol=1e-6)
