"""Lights that reach no visible surface are left out of the ray-traced pass (passes/light_cull.py):
their masks are bit-identical to a trace's, a light with a pixel that needs a ray is never left
out, and the stats count the rays not traced."""
import math
from dataclasses import replace

import numpy as np
import pytest

from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Model, Scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import look_at, trs

pytestmark = [pytest.mark.gpu]

W, H = 96, 72
DOWN = trs((0, 0, 0))  # lights shine along their local -Z: down
UP = trs((0, 0, 0), rot_x=math.pi)


def at(m, pos):
    m = m.copy()
    m[:3, 3] = pos
    return m


def cull_scene(lights):
    quad = Model("ground", np.float32([[-6, -6, 0], [6, -6, 0], [6, 6, 0], [-6, 6, 0]]),
                 np.uint32([[0, 1, 2], [0, 2, 3]]))
    cube_v = np.float32([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 2)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube = Model("cube", cube_v, np.uint32([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]))
    inst = Instances(names=["ground", "cube"], model_ids=[0, 1],
                     matrices=np.array([trs((0, 0, 0)), trs((1.5, -1.0, 0), scale=(0.5, 0.5, 0.5))]))
    cam = Camera(matrix=look_at((0.0, -9.0, 9.0), (0, 0, 0)), lens=30.0)
    return Scene(models=[quad, cube], instances=inst, lights=lights, camera=cam, resolution=(W, H)).validate()


LIGHTS = [
    Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=0.7, rot_x=0.45)),
    Light("spot up", "SPOT", matrix=at(UP, (0, 0, 3)), spot_size=math.radians(60)),     # away from all
    Light("spot aside", "SPOT", matrix=at(DOWN, (20, 0, 3)), spot_size=math.radians(45)),  # off the ground
    Light("spot narrow", "SPOT", matrix=at(DOWN, (1, 1, 4)), spot_size=math.radians(6)),  # a few pixels
    Light("spot edge", "SPOT", matrix=at(DOWN, (8, 0, 2)), spot_size=math.radians(30), radius=1.5),
    Light("area up", "AREA", matrix=at(UP, (-2, 2, 2)), size=0.0),                       # hard, facing away
    Light("area sized", "AREA", matrix=at(UP, (-2, 2, 2)), size=1.0),                     # soft: never left out
    Light("point", "POINT", matrix=trs((0.5, 0.8, 5.0))),
]


def needs_rays(gbuffer, m, scene, li, origin) -> int:
    """Pixels of light ``li``'s mask ``m`` that its trace gives a ray (numpy mirror of
    shadow_ray_prelude over ``gbuffer``, the mask's frame's)."""
    from hybrid_shadow_addon.core.oracle.rays import shadow_rays
    rows, cols = np.nonzero(~np.isnan(m))
    facing = shadow_rays(gbuffer, (rows, cols), scene.lights[li], origin)[3]
    return int(facing.sum())


def render_both(pipeline, scene, settings):
    rp = pipeline.shadow_pass("raytrace")
    out = {}
    try:
        for on in (True, False):
            rp.options = replace(rp.options, cull_lights=on)
            f = pipeline.render(scene, settings, W, H)
            out[on] = (f, {li: f.mask_array(li) for li in f.lights}, list(rp.culled), pipeline.lighting.lights_drawn)
    finally:
        rp.options = replace(rp.options, cull_lights=None)
    return out


@pytest.mark.parametrize("hard, quality", [(True, "high"), (False, "high"), (True, "medium"), (False, "low")])
def test_left_out_lights_give_the_traced_masks(pipeline, hard, quality):
    scene = cull_scene(LIGHTS)
    pipeline.set_scene(scene)
    got = render_both(pipeline, scene, Settings(mode="raytrace", hard=hard, quality=quality))
    frame, masks, culled, drawn = got[True]
    ref_frame, ref, none, ref_drawn = got[False]
    assert none == []
    for li in ref:
        np.testing.assert_array_equal(masks[li], ref[li], err_msg=scene.lights[li].name)
    # the lighting leaves the left-out lights out (they add 0 at every pixel): the same image
    assert ref_drawn == len(scene.lights) and drawn == len(scene.lights) - len(culled)
    np.testing.assert_allclose(frame.image, ref_frame.image, rtol=1e-6, atol=1e-7)
    names = {scene.lights[li].name for li in culled}
    # (with hard lights the sized area light is a hard one too, and the edge spot's cone misses)
    want = {"spot up", "spot aside", "area up"} | ({"spot edge", "area sized"} if hard else set())
    assert names == want
    assert frame.stats["lights_culled"] == len(culled)
    if quality == "high":
        valid = int(frame.gbuffer.coverage().sum())
        assert frame.stats["rays_traced"] == valid * (len(frame.lights) - len(culled))
    else:
        assert frame.stats["rays_traced"] < got[False][0].stats["rays_traced"]


def test_a_light_with_a_ray_is_never_left_out(pipeline):
    """Narrow cones aimed over the whole view (and at its edges): every one with a pixel that
    needs a ray is traced."""
    rng = np.random.default_rng(2)
    lights = []
    for k in range(24):
        target = np.append(rng.uniform(-7, 7, 2), 0.0)
        pos = target + np.append(rng.uniform(-1, 1, 2), rng.uniform(1, 6))
        d = target - pos
        d /= np.linalg.norm(d)
        # a matrix whose -Z is d
        z = -d
        x = np.cross([0.0, 1.0, 0.3], z)
        x /= np.linalg.norm(x)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, pos
        lights.append(Light(f"spot {k}", "SPOT", matrix=m, spot_size=math.radians(rng.uniform(0.5, 4))))
    scene = cull_scene(lights)
    pipeline.set_scene(scene)
    got = render_both(pipeline, scene, Settings(mode="raytrace", hard=True))
    frame, masks, culled, _ = got[True]
    # (the G-buffer is the later frame's: the same scene, camera and size)
    rays = {li: needs_rays(frame.gbuffer, masks[li], scene, li, pipeline.baked.origin) for li in frame.lights}
    assert all(rays[li] == 0 for li in culled)
    assert sum(r == 0 for r in rays.values()) > len(culled) // 2 >= 1  # some left out, not all misses
    assert any(0 < r < 6 for r in rays.values())  # cones of a few pixels were among them
    for li in masks:
        np.testing.assert_array_equal(masks[li], got[False][1][li])


@pytest.mark.parametrize("settings", [
    Settings(mode="raytrace", hard=True, interlace=True),
    Settings(mode="raytrace", accumulate=True, frame_samples=4, samples=16),
    Settings(mode="raytrace", interlace=True, accumulate=True, frame_samples=4, samples=16)])
def test_interlaced_and_accumulated_frames_are_the_same(pipeline, settings):
    """The viewport's frames, one after another from a reset: the same masks in every frame."""
    scene = cull_scene(LIGHTS)
    pipeline.set_scene(scene)
    rp = pipeline.shadow_pass("raytrace")
    seqs = {}
    try:
        for on in (True, False):
            rp.options = replace(rp.options, cull_lights=on)
            pipeline.reset_history()
            rp.hard._phase = 0  # (interlacing's phase runs on across resets: start both at the same one)
            seqs[on] = []
            for _ in range(5):
                f = pipeline.render(scene, settings, W, H)
                seqs[on].append(({li: f.mask_array(li) for li in f.lights}, list(rp.culled)))
    finally:
        rp.options = replace(rp.options, cull_lights=None)
    for (got, culled), (ref, _) in zip(seqs[True], seqs[False]):
        assert {scene.lights[li].name for li in culled} >= {"spot up", "spot aside", "area up"}
        for li in ref:
            np.testing.assert_array_equal(got[li], ref[li], err_msg=scene.lights[li].name)


def test_max_distance_and_an_empty_view(pipeline):
    scene = cull_scene(LIGHTS)
    pipeline.set_scene(scene)
    got = render_both(pipeline, scene, Settings(mode="raytrace", hard=True, max_distance=11.5))
    for li in got[False][1]:
        np.testing.assert_array_equal(got[True][1][li], got[False][1][li])
    # (beyond the max distance a left-out light's mask is 1: the lighting keeps it)
    assert got[True][2] and got[True][3] == len(scene.lights)
    np.testing.assert_array_equal(got[True][0].image, got[False][0].image)
    # the camera looking at the sky: no pixel needs a ray of any light
    scene.camera = Camera(matrix=look_at((0.0, -9.0, 9.0), (0, -20, 30)), lens=30.0)
    got = render_both(pipeline, scene, Settings(mode="raytrace", hard=True))
    frame, masks, culled, _ = got[True]
    assert not frame.gbuffer.coverage().any()
    assert sorted(culled) == sorted(frame.lights)
    for li in masks:
        assert (masks[li] == got[False][1][li]).all() or np.isnan(masks[li]).all()
