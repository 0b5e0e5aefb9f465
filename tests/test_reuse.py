"""Shadow visibility reused across camera moves and edits (core/gpu/passes/reproject.py): the
reused masks against fresh ``high`` masks of the same frames, the rays saved, edits that retrace
only what they can touch, no drift over a long path, and the rejection of a disocclusion."""
import dataclasses

import numpy as np
import pytest
from helpers.scenes import all_lights, basic_scene, cube_model, look_at, plane_model, trs

from hybrid_shadow_addon.core.gpu.passes.reproject import ReuseChoice
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.scene import Instances, Light, Scene
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import frame_mismatch

pytestmark = pytest.mark.gpu

HARD = Settings(mode="raytrace", quality="high", hard=True)
BOUND = 0.0002  # the share of valid pixels a reused mask may differ on (issue 40)


@pytest.fixture
def pipes():
    """(pipeline that always reuses, a view of it that never reuses)."""
    p = Pipeline()
    p.reuse = True
    p.reuse_choice = "always"
    fresh = p.view()
    fresh.reuse = False
    yield p, fresh
    fresh.release()
    p.release()


def orbit(scene, k, step=0.04, target=(0.3, 0.6, 0.3), radius=6.8, height=3.5, climb=0.03):
    """``scene`` with its camera ``k`` steps along an orbit (and a slow climb)."""
    a = -0.94 + step * k
    eye = (radius * np.cos(a), radius * np.sin(a), height + climb * k)
    return dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, matrix=look_at(eye, target)))


mismatch = frame_mismatch  # (pixels whose masks differ over all lights, valid pixels over all lights)


def crowd(n_side=12, mover_at=(0.0, 0.0)):
    """A ground and ``n_side``^2 small cubes under a sun, a camera looking down at them."""
    names, mats, mids = ["ground"], [trs(scale=(12, 12, 1))], [0]
    xs = np.linspace(-9, 9, n_side)
    for i, x in enumerate(xs):
        for j, y in enumerate(xs):
            names.append(f"c{i}_{j}")
            mats.append(trs((x, y, 0.4), scale=(0.4, 0.4, 0.4)))
            mids.append(1)
    inst = Instances(names=names, model_ids=mids, matrices=np.array(mats))
    cam = dataclasses.replace(basic_scene().camera, matrix=look_at((2, -16, 16), (0, 0, 0)))
    sun = Light("sun", "SUN", power=3.0, matrix=look_at((-3, 4, 8), (0, 0, 0)))
    return Scene(models=[plane_model(), cube_model()], instances=inst, lights=[sun], camera=cam,
                 world_color=(0.05, 0.06, 0.08), resolution=(240, 135))


@pytest.mark.parametrize("group", [True, False])  # (the group rule: llvmpipe's default; a GPU's)
def test_reused_masks_match_fresh_along_an_orbit(pipes, group):
    p, fresh = pipes
    refiner = p.shadow_pass("raytrace").refiner
    if group and not refiner.can_vote:
        pytest.skip("the renderer offers no GL_ARB_shader_group_vote")
    refiner.rules["group"] = group
    scene = basic_scene(lights=all_lights(), with_sphere=True)
    traced = fresh_rays = 0
    for k in range(10):
        s = orbit(scene, k)
        a, b = p.render(s, HARD, 240, 135), fresh.render(s, HARD, 240, 135)
        bad, valid = mismatch(a, b)
        assert bad <= BOUND * valid + 1, (k, bad, valid)  # (one pixel at these small sizes)
        assert b.stats["pixels_reused"] == 0
        if k:
            assert a.stats["pixels_reused"] > 0
            # (every pixel of a reusing light is either traced or settled without a ray)
            assert a.stats["lights_culled"] == 0
            assert a.stats["rays_traced"] + a.stats["pixels_reused"] == a.stats["pixels"], a.stats
            traced += a.stats["rays_traced"]
            fresh_rays += b.stats["rays_traced"]
    assert traced <= 0.3 * fresh_rays, (traced, fresh_rays)


def turned(scene, a):
    """``scene`` with its camera turned ``a`` radians about the vertical through its bounds' centre."""
    lo, hi = scene.world_bounds()
    c = (np.asarray(lo) + np.asarray(hi)) * 0.5
    rot = np.eye(4)
    rot[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    t, ti = np.eye(4), np.eye(4)
    t[:3, 3], ti[:3, 3] = c, -c
    cam = dataclasses.replace(scene.camera, matrix=t @ rot @ ti @ scene.camera.matrix)
    return dataclasses.replace(scene, camera=cam)


def orbit_within_bound(pipes, scene, n, size=(320, 180)):
    """Turn the camera ``n`` frames of 0.02 rad: every reused mask within BOUND of the fresh
    one. The reusing pipeline's frames and their valid pixels (over all lights)."""
    p, fresh = pipes
    out = []
    for k in range(n):
        s = turned(scene, 0.02 * k)
        a, b = p.render(s, HARD, *size), fresh.render(s, HARD, *size)
        bad, valid = mismatch(a, b)
        assert bad <= BOUND * valid + 1, (k, bad, valid)
        out.append((a, valid))
    return out


def test_reused_masks_match_fresh_on_smooth_shading(pipes, loaded):
    """Smooth-shaded models (the shading normal decides what faces the light, the terminator
    moves the rays' origins): reused masks as close to fresh ones as on flat ones."""
    frames = orbit_within_bound(pipes, loaded("smooth_shapes"), 4)
    assert all(a.stats["pixels_reused"] > 0.5 * valid for a, valid in frames[1:])


@pytest.mark.parametrize("group", [True, False])
def test_reused_masks_match_fresh_on_many_small_shadows(pipes, loaded, group):
    """clusters (many small casters: shadow edges everywhere) orbited with and without the
    group rule: the neighbourhood the mark reads is wide enough either way."""
    p, _ = pipes
    refiner = p.shadow_pass("raytrace").refiner
    if group and not refiner.can_vote:
        pytest.skip("the renderer offers no GL_ARB_shader_group_vote")
    refiner.rules["group"] = group
    orbit_within_bound(pipes, loaded("clusters"), 5)


def test_every_block_is_traced_again_within_refresh_moving_frames(pipes):
    """On each moving frame the refresh's 4x2 blocks (one in ``refresh``, a phase a frame) are
    traced whatever their history; over ``refresh`` frames the phases cover every block."""
    p, _ = pipes
    scene = crowd()
    rp = p.shadow_pass("raytrace").reuse
    n = rp.rules["refresh"]
    w, h = 240, 136
    by, bx = np.mgrid[0:h, 0:w] // np.array([2, 4])[:, None, None]
    phases = []
    for k in range(n + 1):
        s = dataclasses.replace(scene, camera=dataclasses.replace(
            scene.camera, matrix=look_at((2 + 0.05 * k, -16, 16), (0, 0, 0))))
        p.render(s, HARD, w, h)
        if not k:
            continue
        marked = p.shadow_pass("raytrace").refiner.marked()[::-1]  # (window rows: row 0 the bottom)
        traced = np.abs(rp.codes(0)[::-1]) >= 3.0  # (this frame's samples: neither known nor background)
        found = [q for q in range(n) if marked[((bx + 3 * by + q) % n == 0) & traced].all()]
        assert len(found) == 1, (k, found)
        assert not marked[traced].all()  # (the rest kept their history)
        phases.append(found[0])
    assert sorted(phases) == list(range(n))


def test_retrace_once_traces_whole_and_keeps_the_history(pipes):
    """A frame after ``retrace_once`` (a viewport come to rest) equals the fresh mask exactly,
    and the frame after it reuses again."""
    p, fresh = pipes
    scene = basic_scene(lights=all_lights()[:2], with_sphere=True)
    for k in range(3):
        p.render(orbit(scene, k), HARD, 160, 90)
    p.retrace_once()
    a, b = p.render(orbit(scene, 3), HARD, 160, 90), fresh.render(orbit(scene, 3), HARD, 160, 90)
    assert a.stats["pixels_reused"] == 0 and mismatch(a, b)[0] == 0
    assert p.render(orbit(scene, 4), HARD, 160, 90).stats["pixels_reused"] > 0


def test_the_retraced_pixels_trace_is_timed_alone_when_asked(pipes):
    """``time_retrace`` (benchmarks) times the trace of a reused frame's retraced pixels: none
    on a frame without history, some on a reused one, none when not asked."""
    p, _ = pipes
    rp = p.shadow_pass("raytrace").reuse
    scene = basic_scene(lights=all_lights()[:2], with_sphere=True)
    rp.time_retrace = True
    p.render(orbit(scene, 0), HARD, 160, 90)
    assert rp.retrace_ms == 0.0
    p.render(orbit(scene, 1), HARD, 160, 90)
    assert rp.retrace_ms > 0.0
    rp.time_retrace = False
    p.render(orbit(scene, 2), HARD, 160, 90)
    assert rp.retrace_ms == 0.0


def test_the_choice_keeps_the_cheaper_way_and_tries_the_other_again():
    c = ReuseChoice()
    assert c.way(0, "k") == "reuse"          # (nothing timed: reuse, which primes, then is timed)
    c.note(0, "reuse", 100.0)                # (a way's first timing holds its compiles: left out)
    assert c.way(0, "k") == "reuse"
    c.note(0, "reuse", 10.0)
    assert c.way(0, "k") == "plain"          # (the plain trace, to compare)
    c.note(0, "plain", 50.0)
    assert c.way(0, "k") == "plain"
    c.note(0, "plain", 5.0)
    ways = []
    for _ in range(2 * ReuseChoice.PROBE + 2):
        w = c.way(0, "k")
        ways.append(w)
        c.note(0, w, 10.0 if w == "reuse" else 5.0)
    assert ways.count("reuse") == 2 and ways[0] == "plain"  # (the dearer way, once every PROBE frames)
    assert c.way(0, "other key") == "reuse"  # (a changed light is timed anew)
    for way, ms in (("reuse", 1.0), ("reuse", 1.0), ("plain", 5.0), ("plain", 5.0)):
        c.note(0, way, ms)
    assert c.way(0, "other key") == "reuse"
    c.auto = False
    c.note(1, "plain", 1.0)
    assert c.way(1, "k") == "reuse"  # (auto off: always reuse)


def test_auto_reuse_traces_plainly_where_reuse_costs_more(pipes):
    """``reuse_choice`` 'auto': a light whose reuse is timed dearer than its plain trace is traced
    plainly (exact, no pixel reused), and the masks stay within the bound either way."""
    p, fresh = pipes
    p.reuse_choice = "auto"
    scene = basic_scene(lights=all_lights()[:2], with_sphere=True)
    choice = p.shadow_pass("raytrace").reuse.choice
    for k in range(4):
        a, b = p.render(orbit(scene, k), HARD, 160, 90), fresh.render(orbit(scene, k), HARD, 160, 90)
        bad, valid = mismatch(a, b)
        assert bad <= BOUND * valid + 1
    for s in choice._lights.values():  # (timings that make reusing the dearer way)
        s["ms"].update(reuse=100.0, plain=1.0)
        s["probe"], s["since"] = None, 0
    a, b = p.render(orbit(scene, 4), HARD, 160, 90), fresh.render(orbit(scene, 4), HARD, 160, 90)
    assert a.stats["reuse_ways"] == {"reused": 0, "plain": 2}
    assert a.stats["pixels_reused"] == 0 and mismatch(a, b)[0] == 0


def test_reset_history_forgets_all(pipes):
    p, _ = pipes
    scene = basic_scene()
    p.render(orbit(scene, 0), HARD, 160, 90)
    assert p.render(orbit(scene, 1), HARD, 160, 90).stats["pixels_reused"] > 0
    p.reset_history()
    f = p.render(orbit(scene, 2), HARD, 160, 90)
    assert f.stats["pixels_reused"] == 0
    assert f.stats["rays_traced"] == f.stats["pixels"]


def test_a_moved_object_retraces_roughly_what_it_shadows(pipes):
    p, fresh = pipes
    scene = crowd()
    p.set_scene(scene)
    p.render(scene, HARD, 240, 135)
    before = fresh.render(scene, HARD, 240, 135).mask_array(0)
    k = scene.instances.names.index("c6_6")
    m = scene.instances.matrices.copy()
    m[k, :3, 3] += (0.8, 0.3, 0.0)
    scene.instances.set_matrices([k], m[[k]])
    p.move_instances(scene, [k])
    a, b = p.render(scene, HARD, 240, 135), fresh.render(scene, HARD, 240, 135)
    bad, valid = mismatch(a, b)
    assert bad <= BOUND * valid + 1, (bad, valid)
    # what changed is retraced, and not much more: at most 10 % of the pixels
    changed = int((np.nan_to_num(a.mask_array(0)) != np.nan_to_num(before)).sum())
    assert changed > 0
    assert changed <= a.stats["rays_traced"] <= 0.1 * valid, (changed, a.stats["rays_traced"], valid)


def test_a_changed_light_starts_over_alone(pipes):
    p, fresh = pipes
    scene = basic_scene(lights=all_lights())
    p.render(scene, HARD, 160, 90)
    lights = list(scene.lights)
    lights[1] = dataclasses.replace(lights[1], matrix=trs((0.5, -1.0, 3.0)))
    moved = dataclasses.replace(scene, lights=lights)
    a, b = p.render(moved, HARD, 160, 90), fresh.render(moved, HARD, 160, 90)
    bad, valid = mismatch(a, b)
    assert bad == 0
    per_light = valid // len(a.lights)
    assert a.stats["pixels_reused"] > 2 * per_light  # the other three kept theirs
    assert a.stats["rays_traced"] >= per_light  # the changed one traced every pixel


@pytest.mark.slow
def test_no_drift_over_200_frames(pipes):
    p, fresh = pipes
    scene = basic_scene(lights=all_lights()[:2], with_sphere=True)
    worst = 0.0
    for k in range(200):
        # an orbit that also closes in and backs off: zooming in must find what was sub-pixel
        s = orbit(scene, k, step=0.02, radius=6.8 - 2.5 * np.sin(k / 30.0), climb=0.0)
        a = p.render(s, HARD, 64, 36)
        if k % 20 == 19:
            bad, valid = mismatch(a, fresh.render(s, HARD, 64, 36))
            worst = max(worst, bad / valid)
            assert bad <= 1, (k, bad, valid)
    assert a.stats["pixels_reused"] > 0


def test_the_rejection_catches_a_disocclusion(pipes):
    """The camera slides past the cube: the ground it uncovers has no history of its own (the old
    image shows the cube there). With the instance and position rules off, the cube's values
    would be reused there, and the masks would be wrong."""
    p, fresh = pipes
    # a sun from behind the camera: the cube's faces in view are lit, the ground they hide is
    # in their shadow
    scene = basic_scene(lights=[Light("sun", "SUN", power=3.0, matrix=look_at((6, -8, 9), (0, 0, 0)))])

    def slide(k):
        eye = np.array((4.0 - 0.5 * k, -5.5, 1.6))
        cam = dataclasses.replace(scene.camera, matrix=look_at(eye, eye + (-3.7, 4.9, -1.2)))
        return dataclasses.replace(scene, camera=cam)

    def worst(pipe):
        pipe.reset_history()
        out = 0
        for k in range(8):
            s = slide(k)
            out = max(out, mismatch(pipe.render(s, HARD, 160, 90), fresh.render(s, HARD, 160, 90))[0])
        return out

    assert worst(p) <= 1
    rules = p.shadow_pass("raytrace").reuse.rules
    rules.update(same_instance=False, pos_tol=1e9, normal_cos=-2.0)
    assert worst(p) > 20


SOFT = Settings(mode="raytrace", quality="high", accumulate=True)  # (the viewport's samples per redraw)


def converged(p, scene, w, h):
    """The converged soft masks at ``scene``'s camera: 256 samples from another frame's sample
    pattern (so its noise is not the moving view's)."""
    view = p.view()
    try:
        s = dataclasses.replace(scene, frame=1000)
        many = SOFT.replace(samples=256, frame_samples=32)
        f = view.render(s, many, w, h)
        while f.stats["accumulated_samples"] < many.samples:
            f = view.render(s, many, w, h)
        return {li: f.mask_array(li) for li in f.lights}
    finally:
        view.release()


@pytest.mark.parametrize("step", [0.04, 0.0])  # an orbit; a slow climb (sub-pixel moves: no lag)
def test_soft_sums_carry_over_a_moving_camera(pipes, step):
    """Soft lights orbited 16 frames at the default samples per redraw: the masks reach a mean
    error <= 0.005 against the converged ones while each frame's pixels that lose their history
    start over (the fewest samples a pixel has stays one frame's)."""
    from helpers.scenes import soft_scene

    p, _ = pipes
    scene = soft_scene()
    for k in range(17):
        f = p.render(orbit(scene, k, step=step), SOFT, 240, 135)
        if k:
            assert f.stats["accumulated_samples"] == SOFT.frame_samples
    ref = converged(p, orbit(scene, 16, step=step), 240, 135)
    err = [float(np.nanmean(np.abs(f.mask_array(li) - ref[li]))) for li in f.lights]
    assert np.mean(err) <= 0.005, err


def test_an_edit_keeps_the_soft_sums_it_cannot_touch(pipes):
    """A soft sun over the crowd accumulates; one cube moves: the pixels whose cone towards the
    sun can meet its old or new place start over, the others keep their sums. The mask is then
    closer to the converged one than after starting over, and as close where the edit changed
    the shadow."""
    p, _ = pipes
    scene = crowd()
    sun = dataclasses.replace(scene.lights[0], angle=0.12)
    scene = dataclasses.replace(scene, lights=[sun])
    settings = SOFT.replace(samples=64)
    p.set_scene(scene)
    for _ in range(8):
        p.render(scene, settings, 240, 135)
    before = converged(p, scene, 240, 135)[0]
    k = scene.instances.names.index("c6_6")
    m = scene.instances.matrices.copy()
    m[k, :3, 3] += (0.8, 0.3, 0.0)
    scene.instances.set_matrices([k], m[[k]])
    p.move_instances(scene, [k])
    kept = p.render(scene, settings, 240, 135).mask_array(0)
    ref = converged(p, scene, 240, 135)[0]
    p.reset_history()
    restarted = p.render(scene, settings, 240, 135).mask_array(0)
    err_kept, err_restarted = (np.abs(np.nan_to_num(x - ref)) for x in (kept, restarted))
    changed = np.abs(np.nan_to_num(ref - before)) > 0.02
    assert changed.sum() > 20
    assert err_kept.mean() < 0.5 * err_restarted.mean(), (err_kept.mean(), err_restarted.mean())
    assert err_kept[changed].mean() <= 1.5 * err_restarted[changed].mean() + 0.01, (
        err_kept[changed].mean(), err_restarted[changed].mean())
