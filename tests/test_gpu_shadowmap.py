"""Shadow-map masks against exact numpy shadow rays; the none mode; the mask helpers."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.frame import read_mask
from hybrid_shadow_addon.core.gpu.lights import select_shadowed_lights
from hybrid_shadow_addon.core.scene import Light
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import interior, ray_cast
from tests.helpers.scenes import all_lights, basic_scene, trs

pytestmark = [pytest.mark.gpu]

W, H = 160, 120


def reference_mask(scene, pos, nrm, light):
    p = pos[..., :3].astype(np.float64)
    if light.type == "SUN":
        d = np.broadcast_to(-light.direction, p.shape)
        tmax = None
    else:
        v = light.position - p
        tmax = np.linalg.norm(v, axis=-1)
        d = v / tmax[..., None]
    t, _, _ = ray_cast(scene, p + nrm[..., :3] * 1e-4, d, casters_only=True, tmax=tmax)
    lit = np.where(np.isfinite(t), 0.0, 1.0)
    facing = (nrm[..., :3] * d).sum(-1) > 0.05
    if light.type == "SPOT":
        facing &= (-(d @ light.direction)) > np.cos(light.spot_size / 2) + 0.02
    return lit, facing


@pytest.mark.parametrize("light_index", [0, 1, 2, 3])
def test_shadow_map_matches_ray_cast(pass_rig, light_index):
    rig = pass_rig
    scene = basic_scene(lights=all_lights(), with_sphere=True)
    gb = rig.gbuffer(scene, W, H)
    masks = rig.shadowmap(scene, gb, Settings(mode="shadowmap", shadowmap_size=1024), lights=[light_index])
    assert set(masks) == {light_index}
    m = read_mask(masks[light_index], gb)
    pos, nrm = gb.read("position"), gb.read("normal")
    cov = pos[..., 3] > 0.5
    assert np.isnan(m[~cov]).all() and np.isfinite(m[cov]).all()
    ref, facing = reference_mask(scene, pos, nrm, scene.lights[light_index])
    # away from shadow edges and silhouettes (2 px), where the surface faces the light
    ok = cov & facing & interior(np.where(cov, ref, -1)) & interior(np.where(cov, (pos[..., 3] > 0) * 1, -1))
    ok &= interior(np.where(ok, 1, 0))
    assert ok.sum() > 3000
    shadowed = ref[ok] < 0.5
    assert 0.02 < shadowed.mean() < 0.9, shadowed.mean()  # the test sees real shadows
    agree = (m[ok] > 0.5) == (ref[ok] > 0.5)
    assert agree.mean() > 0.995, agree.mean()


@pytest.mark.parametrize("light_index", [0, 1, 2])
def test_shadow_map_is_dark_where_the_shading_normal_faces_away(pass_rig, light_index):
    """As the ray-traced masks: 0 wherever the shading normal turns from a hard light."""
    scene = basic_scene(lights=all_lights())
    gb = pass_rig.gbuffer(scene, W, H)
    m = read_mask(pass_rig.shadowmap(scene, gb, Settings(mode="shadowmap", shadowmap_size=1024),
                                   lights=[light_index])[light_index], gb)
    light = scene.lights[light_index]
    p = gb.read("position")[..., :3].astype(np.float64)
    to_light = np.broadcast_to(-light.direction, p.shape) if light.type == "SUN" else light.position - p
    away = (gb.read("shading_normal")[..., :3] * to_light).sum(-1) <= 0
    away &= gb.coverage()
    assert away.sum() > 200
    assert (m[away] == 0).all()


def test_cube_on_plane_under_sun_is_shadowed_behind(pass_rig):
    rig = pass_rig
    scene = basic_scene(lights=all_lights()[:1])
    gb = rig.gbuffer(scene, W, H)
    m = read_mask(rig.shadowmap(scene, gb, Settings(mode="shadowmap", shadowmap_size=1024, pcf=0))[0], gb)
    pos = gb.read("position")
    # ground points right behind the cube (away from the sun) are 0; points in front are 1
    d = scene.lights[0].direction
    ground = (np.abs(pos[..., 2]) < 1e-3) & (pos[..., 3] > 0.5)
    rel = pos[..., :2] - 0.0
    along = rel @ (d[:2] / np.linalg.norm(d[:2]))
    side = np.abs(rel @ np.array([-d[1], d[0]]) / np.linalg.norm(d[:2]))
    behind = ground & (along > 1.3) & (along < 2.0) & (side < 0.6)
    front = ground & (np.abs(along) < 1.0) & (side > 1.6) & (side < 3.0)  # beside the cube
    assert behind.sum() > 20 and front.sum() > 20
    assert (m[behind] == 0).all() and (m[front] == 1).all()


def test_max_distance_and_none_mode(pass_rig):
    rig = pass_rig
    scene = basic_scene(lights=all_lights())
    gb = rig.gbuffer(scene, W, H)
    depth = gb.read("depth")
    pos = gb.read("position")
    cam = scene.camera.matrix[:3, 3]
    dist = np.linalg.norm(pos[..., :3] - cam, axis=-1)
    m = read_mask(rig.shadowmap(scene, gb, Settings(mode="shadowmap", max_distance=6.0), lights=[0])[0], gb)
    far = (depth > 0) & (dist > 6.01)
    assert far.sum() > 100 and (m[far] == 1).all()
    masks = rig.none(scene, gb, Settings(mode="none"))
    assert sorted(masks) == [0, 1, 2, 3]
    for tex in masks.values():
        mm = read_mask(tex, gb)
        assert (mm[depth > 0] == 1).all()


def test_select_shadowed_lights_keeps_suns_and_nearest():
    lights = all_lights() + [Light("far", "POINT", matrix=trs((100, 0, 0)))]
    lights[1].use_shadow = False
    scene = basic_scene(lights=lights)
    assert select_shadowed_lights(scene, Settings()) == [0, 2, 3, 4]
    assert select_shadowed_lights(scene, Settings(max_shadowed_lights=2)) == [0, 3]
    assert select_shadowed_lights(scene, Settings(max_shadowed_lights=0)) == []
