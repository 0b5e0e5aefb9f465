"""The scene camera, the world colour and the render resolution."""
import math
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

from tests.helpers.export_scenes import empty_scene, export_scene

REPO = Path(__file__).resolve().parents[1]

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
    from hybrid_shadow_addon.blender.export.world import sky_table

    node = _world_with(scene, "ShaderNodeTexSky")
    node.sun_elevation = math.radians(15.0)
    table, stand_in = sky_table(node.sky_type, bpy.app.version[0])
    assert stand_in is None  # the node's default sky type has a table in this Blender
    s = export_scene()
    measured = {row[0]: row[1:] for row in table["mean"]}
    np.testing.assert_allclose(s.world_color, 2.0 * np.float32(measured[15.0]), rtol=1e-5)
    node.sun_intensity = 4.0  # Cycles' Sun Intensity scales the sun disc only: not the sky
    np.testing.assert_allclose(export_scene().world_color, s.world_color, rtol=1e-6)
    node.sun_elevation = math.radians(60.0)
    low_sun = s.world_color
    s2 = export_scene()
    assert s2.world_color[2] > low_sun[2]  # a high sun: a bluer, brighter sky on average
    assert any("Sky Texture" in w for w in s2.report), s2.report
    assert not any("approximate" in w for w in s2.report), s2.report  # the defaults: as measured


# --------------------------------------------------------------------------------------------
# the Sky Texture's average against Cycles
# --------------------------------------------------------------------------------------------
#: every sky type of Blender 4.5 and 5.x (a test of a type the running Blender lacks skips)
SKY_TYPES = ("NISHITA", "SINGLE_SCATTERING", "MULTIPLE_SCATTERING", "PREETHAM", "HOSEK_WILKIE")
#: the export's sky average against Cycles' panorama at an elevation between the table's (and a
#: sun rotation other than the table's): measured within 0.4 % (of the brightest channel) on
#: Blender 4.5 and 5.2, the table's interpolation and the panoramas' sampling together
SKY_TOLERANCE = 0.015


def _sky_node(scene, sky_type):
    """A Sky Texture world of ``sky_type``, skipped where the running Blender has no such sky."""
    have = [i.identifier for i in bpy.types.ShaderNodeTexSky.bl_rna.properties["sky_type"].enum_items]
    if sky_type not in have:
        pytest.skip(f"Blender {bpy.app.version_string} has no {sky_type} sky (it has {', '.join(have)})")
    node = _world_with(scene, "ShaderNodeTexSky")
    node.sky_type = sky_type
    return node


def _cycles_world_mean(scene):
    """Cycles' (CPU) view of the world: the solid-angle-weighted mean of an equirectangular
    panorama (``tools/measure_sky.py``'s, as the tables are measured)."""
    from tools import measure_sky

    measure_sky.panorama(scene)
    return measure_sky.render_mean(scene)


@pytest.mark.cycles
@pytest.mark.parametrize("sky_type", SKY_TYPES)
def test_sky_world_colour_is_cycles_average(scene, sky_type):
    from hybrid_shadow_addon.blender.export.world import set_sun_elevation

    node = _sky_node(scene, sky_type)
    set_sun_elevation(node, math.radians(25.0))  # between the table's elevations
    node.sun_rotation = 1.0
    node.sun_intensity = 3.0  # scales the sun disc only (off here, as the export leaves it out)
    node.sun_disc = False
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.7
    s = export_scene()
    cycles = _cycles_world_mean(scene)
    err = np.abs(s.world_color - cycles).max() / cycles.max()
    assert err < SKY_TOLERANCE, (s.world_color, cycles, err)
    assert not any("approximate" in w for w in s.report), s.report
    if sky_type not in ("PREETHAM", "HOSEK_WILKIE"):
        node.sun_disc = True  # the disc is left out (a Sun lamp stands for it), and said so
        s2 = export_scene()
        np.testing.assert_allclose(s2.world_color, s.world_color, rtol=1e-6)
        assert any("sun disc left out" in w for w in s2.report), s2.report


@pytest.mark.parametrize("sky_type", SKY_TYPES)
def test_sky_settings_other_than_measured_are_reported(scene, sky_type):
    node = _sky_node(scene, sky_type)
    assert not any("approximate" in w for w in export_scene().report)
    if sky_type in ("PREETHAM", "HOSEK_WILKIE"):
        node.turbidity, what = 5.0, "turbidity 5"
    else:
        node.air_density, what = 2.0, "air density 2"
    report = export_scene().report
    assert any(what in w and "approximate" in w for w in report), report


def test_sky_without_a_table_or_outside_it_is_reported(scene, monkeypatch):
    from hybrid_shadow_addon.blender.export import world

    node = _world_with(scene, "ShaderNodeTexSky")
    node.sun_elevation = math.radians(100.0)  # past the zenith: Cycles' sun at 80°, turned
    past = export_scene().world_color
    node.sun_elevation = math.radians(80.0)
    np.testing.assert_allclose(past, export_scene().world_color, rtol=1e-6)
    node.sun_elevation = math.radians(-40.0)  # below the table's lowest elevation
    report = export_scene().report
    assert any("outside the measured" in w and "approximate" in w for w in report), report
    node.sun_elevation = math.radians(15.0)
    major = str(bpy.app.version[0])
    tables = {m: dict(t) for m, t in world.sky_tables().items()}
    del tables[major][node.sky_type]
    monkeypatch.setattr(world, "sky_tables", lambda: tables)
    s = export_scene()
    assert any(f"no measured average for a {node.sky_type} Sky Texture" in w and "approximate" in w
               for w in s.report), s.report
    assert np.all(s.world_color > 0)
    monkeypatch.setattr(world, "sky_tables", dict)
    s = export_scene()  # no table at all: the Background's own colour
    bg_colour = scene.world.node_tree.nodes["Background"].inputs["Color"].default_value[:3]
    np.testing.assert_allclose(s.world_color, 2.0 * np.float32(bg_colour), rtol=1e-6)
    assert any("no measured Sky Texture average" in w for w in s.report), s.report


@pytest.mark.cycles
def test_measure_sky_checks_the_table(scene, tmp_path):
    """tools/measure_sky.py --check: the table holds for this Blender's default sky (at one table
    elevation and one between), and an entry off is one line and a non-zero exit."""
    import json
    import shutil
    import subprocess

    from hybrid_shadow_addon.blender.export.world import SKY_TABLE_PATH

    sky_type = _world_with(scene, "ShaderNodeTexSky").sky_type  # a new node's
    table = tmp_path / "sky.json"
    shutil.copy(SKY_TABLE_PATH, table)
    cmd = [sys.executable, "-m", "tools.measure_sky", "--check", "--quiet", "--table", str(table),
           "--types", sky_type, "--elevations", "30,12.5"]  # (12.5°'s cubic does not reach to 30°)
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads(table.read_text())
    row = next(row for row in doc["tables"][str(bpy.app.version[0])][sky_type]["mean"] if row[0] == 30.0)
    row[1:] = [1.1 * c for c in row[1:]]
    table.write_text(json.dumps(doc))
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stdout + r.stderr
    lines = [line for line in r.stdout.splitlines() if line.startswith("Blender ")]  # (not Blender's own log)
    assert len(lines) == 1 and "30°" in lines[0] and sky_type in lines[0], r.stdout
