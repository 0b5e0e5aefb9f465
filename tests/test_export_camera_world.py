"""The scene camera, the world colour and the render resolution."""
import math

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


def _world_with(scene, node_type):
    world = bpy.data.worlds.new("Tex")
    world.use_nodes = True
    node = world.node_tree.nodes.new(node_type)
    bg = world.node_tree.nodes["Background"]
    world.node_tree.links.new(node.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 2.0
    scene.world = world
    return node


def test_environment_texture_world_is_its_mean(scene):
    from hybrid_shadow_addon.blender.export.world import equirect_mean

    node = _world_with(scene, "ShaderNodeTexEnvironment")
    img = bpy.data.images.new("env", 16, 8, float_buffer=True)
    px = np.zeros((8, 16, 4), np.float32)
    px[4:, :, :3] = (2.0, 1.0, 0.5)  # the upper half (rows from the bottom) bright
    px[..., 3] = 1
    img.pixels.foreach_set(px.ravel())
    node.image = img
    s = export_scene()
    np.testing.assert_allclose(s.world_color, 2.0 * 0.5 * np.float32([2.0, 1.0, 0.5]), rtol=1e-5)
    np.testing.assert_allclose(equirect_mean(px), [1.0, 0.5, 0.25], rtol=1e-6)
    # the solid angle: a band at the equator weighs more than one at a pole
    band = np.zeros((8, 16, 3), np.float32)
    band[3] = 1.0
    pole = np.zeros((8, 16, 3), np.float32)
    pole[7] = 1.0
    assert equirect_mean(band)[0] > 3 * equirect_mean(pole)[0]
    assert any("Environment Texture" in w for w in s.report), s.report


def test_sky_texture_world_is_its_average(scene):
    from hybrid_shadow_addon.blender.export.world import SKY_MEAN

    node = _world_with(scene, "ShaderNodeTexSky")
    node.sun_elevation = math.radians(15.0)
    s = export_scene()
    np.testing.assert_allclose(s.world_color, 2.0 * np.float32(dict(SKY_MEAN)[15.0]), rtol=1e-5)
    node.sun_elevation = math.radians(60.0)
    low_sun = s.world_color
    s2 = export_scene()
    assert s2.world_color[2] > low_sun[2]  # a high sun: a bluer, brighter sky on average
    assert any("Sky Texture" in w for w in s2.report), s2.report
