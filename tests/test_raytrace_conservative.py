"""The conservative occupancy maps (passes/conservative.py) only save work: the ray-traced masks
with the maps equal, pixel for pixel, those traced without them, on every test scene, every
light kind, reduced mask resolutions and with point lights right next to caster surfaces."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.scene import Light
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.blender_env import TEST_SCENES

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.slow]

W, H = 160, 120


def masks_with_and_without(pipeline, scene, settings):
    out = []
    for cons in (False, True):
        frame = pipeline.render(scene, settings.replace(conservative="all" if cons else "off"), W, H)
        out.append({li: frame.mask_array(li) for li in frame.lights})
        if cons:
            assert any(d == "HS_CONSERVATIVE=1" for d in frame.stats["defines"])
    return out


@pytest.mark.parametrize("structure", ["grid", "bvh"])
@pytest.mark.parametrize("name", list(TEST_SCENES))
def test_conservative_maps_change_no_pixel(name, structure, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene, structure)
    plain, culled = masks_with_and_without(pipeline, scene, Settings(hard=True, mode="raytrace", structure=structure))
    assert plain.keys() == culled.keys() and plain
    for li in plain:
        np.testing.assert_array_equal(culled[li], plain[li], err_msg=f"{name} light {scene.lights[li].name}")


@pytest.mark.parametrize("quality", ["medium", "low"])
def test_conservative_maps_at_reduced_mask_resolution(quality, pipeline, loaded):
    scene = loaded("forest")
    pipeline.set_scene(scene)
    plain, culled = masks_with_and_without(pipeline, scene, Settings(hard=True, mode="raytrace", quality=quality,
                                                                     max_distance=60.0))
    for li in plain:
        np.testing.assert_array_equal(culled[li], plain[li])


@pytest.mark.parametrize("height", [1e-3, 0.05, 0.5])
def test_point_light_touching_the_casters(height, pipeline, loaded):
    """A point light just above the cube's top face and the ground (the near plane and the
    tiny texels next to the light are where a careless map would lose casters)."""
    base = loaded("cube_on_plane")
    from copy import copy

    scene = copy(base)
    top = float(scene.world_bounds()[1][2])
    lights = []
    for k, (x, y, z) in enumerate([(0.0, 0.0, top + height), (3.0, 2.0, height), (0.0, 0.0, top - height)]):
        m = np.eye(4)
        m[:3, 3] = (x, y, z)
        lights.append(Light(name=f"P{k}", type="POINT", matrix=m))
    scene.lights = lights
    pipeline.set_scene(scene)
    plain, culled = masks_with_and_without(pipeline, scene, Settings(hard=True, mode="raytrace"))
    for li in plain:
        np.testing.assert_array_equal(culled[li], plain[li], err_msg=f"light {li} at height {height}")
    pipeline.set_scene(base)


def test_maps_skip_most_rays_on_the_forest(pipeline, loaded):
    """The point of it: most receivers are decided or cut short (map statistics sanity)."""
    scene = loaded("forest")
    pipeline.set_scene(scene)
    pipeline.render(scene, Settings(hard=True, mode="raytrace", conservative="all"), W, H)
    stats = pipeline.shadow_pass("raytrace").maps.stats
    assert stats and all(s["views"] >= 1 for s in stats.values())
    # the sun's casters are culled against the receivers' window
    sun = [li for li in stats if scene.lights[li].type == "SUN"]
    assert sun and stats[sun[0]]["casters"] < len(scene.instances)


def test_conservative_maps_leave_soft_lights_alone(pipeline, loaded):
    """Lights with a size trace their samples without a map (a map bounds only the rays to a
    light's centre): their masks equal those rendered without maps, the hard lights' too."""
    scene = loaded("soft_lights")
    pipeline.set_scene(scene)
    out = []
    for cons in ("off", "all"):
        frame = pipeline.render(scene, Settings(mode="raytrace", samples=8, conservative=cons), W, H)
        out.append({li: frame.mask_array(li) for li in frame.lights})
    plain, culled = out
    assert plain.keys() == culled.keys() and plain
    for li in plain:
        np.testing.assert_array_equal(culled[li], plain[li], err_msg=scene.lights[li].name)
