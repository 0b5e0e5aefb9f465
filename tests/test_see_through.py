"""See-through surfaces seen by the camera (stochastic transparency, core/gpu/see_through.py):
the G-buffer's cut per sample against the oracle's hash, convergence of the averaged image and
masks to alpha x pane + (1 - alpha) x what lies behind, stacked panes, one pass for scenes
without see-through surfaces, and the viewport's running average."""
import dataclasses

import numpy as np
import pytest

from hybrid_shadow_addon.core.oracle.alpha import camera_keeps, see_through_threshold
from hybrid_shadow_addon.core.oracle.tracer import visibility_brute
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import shadow_rays
from tests.helpers.scenes import alpha_scene, basic_scene, pane_scene

pytestmark = [pytest.mark.gpu]

HARD = Settings(hard=True, structure="bvh")


def pane_pixels(sc, rows, margin=0.03):
    """{instance row: (H, W) bool} pixels whose camera ray crosses the pane of that instance
    (level quads of half-size (1.4, 1.8)) at least ``margin`` inside its edges."""
    w, h = sc.resolution
    o, d = sc.camera.pixel_rays(w, h)
    out = {}
    for r in rows:
        m = sc.instances.matrices[r]
        t = (m[2, 3] - o[..., 2]) / d[..., 2]
        p = o + t[..., None] * d
        out[r] = ((t > 0) & (np.abs(p[..., 0] - m[0, 3]) < 1.4 - margin)
                  & (np.abs(p[..., 1] - m[1, 3]) < 1.8 - margin))
    return out


def instance_map(frame):
    gb = frame.gbuffer
    inst = np.round(gb.read("material")[..., 2]).astype(int)
    return np.where(gb.read("position")[..., 3] > 0, inst, -1)


def gl_pixels(shape):
    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w]
    return cols, h - 1 - rows


def test_thresholds_stratify_and_decorrelate():
    """Any first 2^k samples of a pixel put one threshold in each 1/2^k of (0, 1); pixels and
    surfaces get other rotations."""
    for n in (4, 16):
        t = np.array([see_through_threshold(7, 3, s, 2) for s in range(n)]).ravel()
        assert ((t > 0) & (t < 1)).all()
        assert np.array_equal(np.sort(np.floor(t * n)), np.arange(n))
    a = see_through_threshold(np.arange(1000), 5, 0, 1)
    b = see_through_threshold(np.arange(1000), 5, 0, 2)
    assert 0.4 < a.mean() < 0.6 and abs(np.corrcoef(a, b)[0, 1]) < 0.1


def test_each_sub_frame_cuts_as_the_oracle(pipeline):
    """Sub-frame by sub-frame (the viewport's accumulation, one per render), a pane pixel shows
    the pane exactly where the oracle's hash keeps it; the first sub-frame's mask is the
    brute-force visibility of what its G-buffer holds."""
    sc = pane_scene()
    pipeline.set_scene(sc, "bvh")
    pipeline.reset_history()
    panes = pane_pixels(sc, (3, 4))
    s = HARD.replace(accumulate=True, transparency_samples=8)
    x, y = gl_pixels(panes[3].shape)
    for k in range(8):
        f = pipeline.render(sc, s)
        assert f.stats["see_through_samples"] == k + 1
        got = instance_map(f)
        for row, sel in panes.items():
            mat = int(sc.instances.material_ids[row])
            want = camera_keeps(sc, mat, np.zeros((sel.sum(), 2)), k, x[sel], y[sel], row)
            assert sel.sum() > 200
            assert np.array_equal(got[sel] == row, want), (k, row, (got[sel] == row).sum(), want.sum())
        if k == 0:
            ok, o, d, tmax, facing = shadow_rays(f, sc, 0)
            ref = visibility_brute(sc, o, d, tmax)
            diff = np.abs(f.mask_array(0)[ok][facing] - ref[facing])
            assert (diff > 0.02).mean() < 0.002


def test_accumulation_converges_to_the_blend(pipeline):
    """16 sub-frames: at the panes (0.3 and 0.7, casting no shadow here, so that what lies behind
    is lit the same with and without them) image and mask are alpha x the opaque pane's +
    (1 - alpha) x the render without panes, within the stratified samples' 1/16."""
    sc = pane_scene()
    sc.instances.casts_shadow[3:] = False
    pipeline.set_scene(sc, "bvh")
    f = pipeline.render(sc, HARD.replace(transparency_samples=16))
    assert f.stats["see_through_samples"] == 16
    data_inst = instance_map(f)  # (the G-buffer is the pass's, drawn over by the next render)
    opaque = dataclasses.replace(sc, materials=[sc.materials[0]] + [dataclasses.replace(m, alpha=1.0)
                                                                    for m in sc.materials[1:]])
    front = pipeline.render(opaque, HARD.replace(transparency_samples=1))
    front_img, front_mask = front.image.copy(), front.mask_array(0)
    bare = pane_scene(panes=False)
    pipeline.set_scene(bare, "bvh")
    back = pipeline.render(bare, HARD)
    assert "see_through_samples" not in back.stats
    back_img, back_mask = back.image.copy(), back.mask_array(0)
    mask = f.mask_array(0)
    for row, sel in pane_pixels(sc, (3, 4)).items():
        a = float(sc.materials[int(sc.instances.material_ids[row])].alpha)
        want = a * front_img[sel][:, :3] + (1 - a) * back_img[sel][:, :3]
        err = np.abs(f.image[sel][:, :3] - want)
        spread = np.abs(front_img[sel][:, :3] - back_img[sel][:, :3])
        assert (err <= spread / 16 + 1e-4).mean() > 0.99, (a, err.max())
        assert err.mean() < 0.01
        # the cube's shadow and the lit ground both lie behind the pane
        bm = back_mask[sel]
        assert (bm < 0.5).sum() > 20 and (bm > 0.5).sum() > 200
        wm = a * front_mask[sel] + (1 - a) * bm
        assert np.abs(mask[sel] - wm).max() <= 1 / 16 + 1e-6
        assert np.abs(mask[sel] - wm).mean() < 0.02
    # without accumulation the 0.3 pane is not there and the 0.7 one is solid; the accumulated
    # frame's G-buffer (its data passes) shows them so too
    one = pipeline.render(sc, HARD.replace(transparency_samples=1))
    sel = pane_pixels(sc, (3,))[3]
    assert np.abs(one.image[sel][:, :3] - back_img[sel][:, :3]).max() < 1e-5
    assert np.array_equal(data_inst, instance_map(one))


def test_stacked_panes_decorrelate(pipeline):
    """Two stacked alpha-0.5 panes: the front one shows half the time, the back one a quarter,
    the ground a quarter (one shared threshold would show the ground half the time)."""
    sc = pane_scene(alphas=(0.5,), stacked=True)
    pipeline.set_scene(sc, "bvh")
    pipeline.reset_history()
    sel = pane_pixels(sc, (2,))[2] & pane_pixels(sc, (3,))[3]
    s = HARD.replace(accumulate=True, transparency_samples=16)
    seen = {"front": 0.0, "back": 0.0, "ground": 0.0}
    for _ in range(16):
        inst = instance_map(pipeline.render(sc, s))[sel]
        seen["front"] += (inst == 3).mean() / 16
        seen["back"] += (inst == 2).mean() / 16
        seen["ground"] += (inst == 0).mean() / 16
    assert sel.sum() > 300
    assert abs(seen["front"] - 0.5) < 0.02, seen
    assert abs(seen["back"] - 0.25) < 0.04, seen
    assert abs(seen["ground"] - 0.25) < 0.04, seen


def test_one_pass_without_see_through_surfaces(pipeline):
    """Opaque scenes, cut-only scenes (CLIP), panes out of view and transparency_samples 1 render
    one G-buffer pass; a see-through pane in view renders transparency_samples of them, and one
    more for the data passes (cut at 0.5)."""
    cases = [(basic_scene(), 16, 1), (alpha_scene(card_materials=(0, 3, 3, 3)), 16, 1),
             (pane_scene(), 1, 1), (pane_scene(), 6, 7)]
    cases.append((pane_scene(pane_x=500.0), 16, 1))
    for sc, n, passes in cases:
        pipeline.set_scene(sc, "bvh")
        before = pipeline.gbuffer_renders
        f = pipeline.render(sc, HARD.replace(transparency_samples=n))
        assert pipeline.gbuffer_renders - before == passes, (sc.name, n)
        assert ("see_through_samples" in f.stats) == (passes > 1)


def test_viewport_accumulation_stops_and_restarts(pipeline):
    """One sub-frame per render up to the target, then the same frame without new passes; a
    reset or other settings start afresh."""
    sc = pane_scene()
    pipeline.set_scene(sc, "bvh")
    pipeline.reset_history()
    s = HARD.replace(accumulate=True, transparency_samples=3)
    counts = [pipeline.render(sc, s).stats["see_through_samples"] for _ in range(3)]
    assert counts == [1, 2, 3]
    before = pipeline.gbuffer_renders
    again = pipeline.render(sc, s)
    assert pipeline.gbuffer_renders == before and again.stats["see_through_samples"] == 3
    assert pipeline.render(sc, s.replace(specular=False)).stats["see_through_samples"] == 1
    pipeline.reset_history()
    assert pipeline.render(sc, s.replace(specular=False)).stats["see_through_samples"] == 1


def test_settings_validate_transparency_samples():
    for bad in (0, -1, 1.5, True, 5000):
        with pytest.raises(ValueError, match="transparency_samples"):
            Settings(transparency_samples=bad)
    assert Settings().transparency_samples == 16
