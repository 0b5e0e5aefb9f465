"""Refinement (``quality`` medium/low): coarse rays, classification, full-resolution rays where the
coarse answer cannot stand for a pixel, traced under a depth mask.

1. On every test scene and every stiff scene, medium and low differ from high's masks on at most
   0.1% of the valid pixels (all shadowed lights together). One documented exception:
   ``stiff/thin`` at low (shadows thinner than a pixel, from poles, wires and leaf blades): a
   shadow that falls between the coarse samples, nowhere near one that sees it, is missed (0.14%
   of the pixels; medium 0.04%, since a marked pixel's SIMD group is traced whole: the ``group``
   rule); high holds 0.1% against Cycles there.
2. Every pixel that got its own ray equals high's (the same ray); pixels decided without a ray
   by the facing/reach tests equal high's too; a pixel the camera sees at a grazing angle gets
   its own ray (its samples' spacing on the surface is stretched: without the rule ``forest``'s
   distant terrain loses shadow streaks a pixel high); on llvmpipe every pixel of a 4x2 block
   that holds a marked pixel gets its own ray unless it is known without one (``group``).
3. Stats: ``rays_traced`` and ``pixels``; an unknown refinement method is refused; the
   ``nearest`` option still gives the blocky coarse masks; interlacing converges to high and
   its first frame after a change is refined, not blocky.
"""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.blender_env import TEST_SCENES

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
W, H = 160, 120
LIMIT_PCT = 0.1
STIFF = sorted(p.stem for p in (REPO / "test_scenes" / "stiff").glob("*.py") if not p.stem.startswith("_"))
EXCEPTIONS = {("stiff/thin", "low"): 0.2}  # (see the module docstring)


def masks(pipeline, scene, settings, w, h):
    f = pipeline.render(scene, settings, w, h)
    return f, {li: f.mask_array(li) for li in f.lights}


def mismatch_pct(a: dict, b: dict) -> tuple:
    bad = n = 0
    worst = 0.0
    for li in a:
        ok = np.isfinite(a[li]) & np.isfinite(b[li])
        k = int((a[li][ok] != b[li][ok]).sum())
        bad, n = bad + k, n + int(ok.sum())
        worst = max(worst, 100.0 * k / max(1, int(ok.sum())))
    return 100.0 * bad / max(n, 1), worst


def size_of(name, scene):
    return tuple(scene.resolution) if name.startswith("stiff/") else (W, H)


@pytest.mark.parametrize("name", list(TEST_SCENES) + [f"stiff/{c}" for c in STIFF])
def test_medium_and_low_match_high(name, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene)
    w, h = size_of(name, scene)
    _, high = masks(pipeline, scene, Settings(hard=True, quality="high"), w, h)
    assert high, "no shadowed light"
    for quality in ("medium", "low"):
        limit = EXCEPTIONS.get((name, quality), LIMIT_PCT)
        frame, got = masks(pipeline, scene, Settings(hard=True, quality=quality), w, h)
        assert set(got) == set(high)
        for li in got:
            assert got[li].shape == (h, w)
            np.testing.assert_array_equal(np.isnan(got[li]), np.isnan(high[li]))
        pct, worst = mismatch_pct(got, high)
        assert pct <= limit, f"{name} {quality}: {pct:.3f}% of pixels differ from high (worst light {worst:.3f}%)"
        st = frame.stats
        assert 0 < st["rays_traced"] < st["pixels"], st


def _capture_marks(pipeline):
    """Wrap the ray-traced pass's hard visibility so each light's ray marks are kept."""
    rp = pipeline.shadow_pass("raytrace")
    marks = {}
    orig = rp.hard._trace

    def trace(job, ray):
        out = orig(job, ray)
        if rp.hard.plan in ("refine", "interlace"):
            marks[ray.index] = rp.refiner.marked()
        return out
    rp.hard._trace = trace
    return rp, marks, orig


@pytest.mark.parametrize("name", ["forest", "clusters", "stiff/cards", "stiff/spot_touching", "stiff/thin"])
@pytest.mark.parametrize("quality", ["medium", "low"])
def test_refined_pixels_equal_high(name, quality, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene)
    w, h = size_of(name, scene)
    _, high = masks(pipeline, scene, Settings(hard=True, quality="high"), w, h)
    rp, marks, orig = _capture_marks(pipeline)
    try:
        frame, got = masks(pipeline, scene, Settings(hard=True, quality=quality), w, h)
    finally:
        rp.hard._trace = orig
    assert set(marks) == set(got) - set(rp.culled)  # (lights that reach no pixel take no pass)
    for li in rp.culled:
        np.testing.assert_array_equal(got[li], high[li])
    total = 0
    for li, m in marks.items():
        total += int(m.sum())
        np.testing.assert_array_equal(got[li][m], high[li][m], err_msg=f"{name} light {li}: a refined ray differs")
        # wrong pixels are only ever ones that took the coarse answer
        wrong = np.isfinite(got[li]) & (got[li] != high[li])
        assert not (wrong & m).any()
    assert total > 0
    assert frame.stats["rays_traced"] >= total


def test_grazing_view_pixels_get_their_own_rays(pipeline, loaded):
    """Refiner.RULES['view_cos']: every pixel that needs a ray and that the camera sees at
    |cos| < 0.5 to its normal is refined (marked), for every light; without the rule some are not."""
    from hybrid_shadow_addon.core.oracle.rays import shadow_rays

    scene = loaded("forest")
    pipeline.set_scene(scene)
    rp, marks, orig = _capture_marks(pipeline)
    assert rp.refiner.rules["view_cos"] == 0.5
    unmarked = {}
    try:
        for view_cos in (0.5, 0.0):
            rp.refiner.rules["view_cos"] = view_cos
            marks.clear()
            frame, got = masks(pipeline, scene, Settings(hard=True, quality="medium"), W, H)
            gb = frame.gbuffer
            pos = gb.read("position")
            n = gb.read("normal")[..., :3]
            v = gb.camera.cam_pos[None, None, :] - pos[..., :3].astype(np.float64)
            c = np.abs((n * v).sum(axis=2)) / np.linalg.norm(v, axis=2)
            valid = pos[..., 3] > 0
            graze = valid & (c < 0.5 - 1e-3)
            sample = np.zeros((H, W), bool)
            sample[H - 2::-2, 1::2] = True  # (pixels 2q + 1 from the bottom-left: the coarse samples)
            rows, cols = np.nonzero(graze & ~sample)
            left = 0
            for li, m in marks.items():
                facing = shadow_rays(gb, (rows, cols), scene.lights[li], rp.scene_textures.baked.origin)[3]
                left += int((~m[rows[facing], cols[facing]]).sum())
            unmarked[view_cos] = (left, len(rows))
    finally:
        rp.hard._trace = orig
        rp.refiner.rules["view_cos"] = 0.5
    assert unmarked[0.5][1] > 500, unmarked  # (forest's distant terrain)
    assert unmarked[0.5][0] == 0, unmarked
    assert unmarked[0.0][0] > 0, unmarked


def _blocks_any(m):
    """Each pixel: does its 4x2 block (llvmpipe's SIMD group: 4 columns, 2 rows from the bottom
    of the image) hold a True pixel."""
    h, w = m.shape
    gl = np.zeros((-(-h // 2) * 2, -(-w // 4) * 4), bool)
    gl[:h, :w] = m[::-1]
    b = gl.reshape(gl.shape[0] // 2, 2, gl.shape[1] // 4, 4).any(axis=(1, 3))
    return np.repeat(np.repeat(b, 2, 0), 4, 1)[:h, :w][::-1]


def test_group_rule_traces_a_marked_pixels_block_whole(pipeline, loaded):
    """Refiner.RULES['group'] (on by default on llvmpipe): the marks grow to the 4x2 blocks that
    hold one, except the pixels known without a ray (coarse samples, pixels the facing/reach
    tests decide); the extra rays are exact, and on ``stiff/thin`` they take medium from 0.12%
    to within 0.1% of high."""
    from hybrid_shadow_addon.core.gpu.passes.refine import Refiner
    from hybrid_shadow_addon.core.oracle.rays import shadow_rays

    scene = loaded("stiff/thin")
    pipeline.set_scene(scene)
    w, h = size_of("stiff/thin", scene)
    _, high = masks(pipeline, scene, Settings(hard=True, quality="high"), w, h)
    rp, marks, orig = _capture_marks(pipeline)
    assert "llvmpipe" in rp.ctx.info["GL_RENDERER"].lower()
    assert Refiner.group_default(rp.ctx) and rp.refiner.rules["group"]
    got, pct = {}, {}
    try:
        for group in (0.0, 1.0):
            rp.refiner.rules["group"] = group
            marks.clear()
            frame, m = masks(pipeline, scene, Settings(hard=True, quality="medium"), w, h)
            got[group] = (dict(marks), m, frame.gbuffer)
            pct[group] = mismatch_pct(m, high)[0]
    finally:
        rp.hard._trace = orig
        rp.refiner.rules["group"] = True
    sample = np.zeros((h, w), bool)
    sample[h - 2::-2, 1::2] = True  # (pixels 2q + 1 from the bottom-left: the coarse samples)
    off, on = got[0.0][0], got[1.0][0]
    assert set(off) == set(on)
    grown = missed = 0
    for li in on:
        assert not (off[li] & ~on[li]).any(), "a mark was lost"
        blocks = _blocks_any(off[li])
        assert not (on[li] & ~blocks).any(), "a mark outside a marked block"
        rows, cols = np.nonzero(blocks & ~on[li] & ~sample & np.isfinite(high[li]))
        facing = shadow_rays(got[1.0][2], (rows, cols), scene.lights[li], rp.scene_textures.baked.origin)[3]
        missed += int(facing.sum())
        np.testing.assert_array_equal(got[1.0][1][li][on[li]], high[li][on[li]])
        grown += int(on[li].sum() - off[li].sum())
    assert grown > 1000, grown
    # (llvmpipe's vote covers the whole 4x2 block in nearly every group, not in every one: in a
    # few groups it returns each lane's own value; Mesa 22.3 misses 26 such pixels here)
    assert missed < 0.01 * grown, (missed, grown)
    assert pct[0.0] > 0.1 >= pct[1.0], pct


def test_refinement_rules_are_checked(pipeline):
    from hybrid_shadow_addon.core.gpu.passes.refine import Refiner
    from hybrid_shadow_addon.core.gpu.passes.trace import RaytraceOptions

    rp = pipeline.shadow_pass("raytrace")
    with pytest.raises(ValueError, match="unknown refinement rule"):
        Refiner(rp.gpu, view_angle=0.5)
    kept = rp.refiner.can_vote
    rp.refiner.can_vote = False
    try:
        with pytest.raises(ValueError, match="GL_ARB_shader_group_vote"):
            rp.refiner.defines()
    finally:
        rp.refiner.can_vote = kept
    with pytest.raises(ValueError, match="refinement method must be one of depth, not 'compact'"):
        RaytraceOptions(refine_method="compact")
    with pytest.raises(ValueError, match="refinement method"):
        rp.options = replace(rp.options, refine_method="list")


def test_stats_count_pixels_and_rays(pipeline, loaded):
    scene = loaded("forest")
    pipeline.set_scene(scene)
    high = pipeline.render(scene, Settings(hard=True, quality="high"), W, H)
    valid = int(high.gbuffer.coverage().sum())
    n = len(high.lights)
    assert high.stats["pixels"] == valid * n
    # (lights that reach no pixel take no pass: forest's spots, passes/light_cull.py)
    assert high.stats["rays_traced"] == valid * (n - high.stats["lights_culled"])
    for q, most in (("medium", 0.6), ("low", 0.5)):
        st = pipeline.render(scene, Settings(hard=True, quality=q), W, H).stats
        assert st["pixels"] == valid * n
        assert 0.05 * st["pixels"] < st["rays_traced"] < most * st["pixels"], (q, st)
    none = pipeline.render(scene, Settings(hard=True, mode="none"), W, H).stats
    assert none["rays_traced"] == 0 and "pixels" in none


def test_nearest_gives_the_blocky_coarse_masks(pipeline, loaded):
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene)
    f = pipeline.render(scene, Settings(hard=True, quality="low", upsample="nearest"), W, H)
    assert f.stats["rays_traced"] < f.stats["pixels"] / 8  # the coarse rays alone
    m = f.mask_array(f.lights[0])
    assert m.shape == (H, W)
    # nearest: every 4x4 block (away from the background) holds one value
    blocks = np.nan_to_num(m, nan=0.5)[:H // 4 * 4, :W // 4 * 4].reshape(H // 4, 4, W // 4, 4)
    assert (blocks.max(axis=(1, 3)) == blocks.min(axis=(1, 3))).mean() > 0.8


@pytest.mark.parametrize("quality,size", [("high", (W, H)), ("medium", (W, H)), ("high", (W + 1, H - 1))])
def test_interlacing_refines_its_first_frame_and_converges(quality, size, pipeline, loaded):
    """(An odd width and height: the last column and row of 2x2 blocks miss a pixel of two
    phases, which each frame's quarter-resolution trace covers only where they exist.)"""
    scene = loaded("forest")
    pipeline.set_scene(scene)
    _, high = masks(pipeline, scene, Settings(hard=True, quality="high"), *size)
    inter = Settings(hard=True, quality=quality, interlace=True)
    pipeline.reset_history()
    frames = [masks(pipeline, scene, inter, *size) for _ in range(4)]
    first_pct, _ = mismatch_pct(frames[0][1], high)
    assert first_pct <= 0.2, f"first interlaced frame {first_pct:.3f}% off"
    st = frames[0][0].stats
    assert st["rays_traced"] < 0.6 * st["pixels"]
    for li in high:
        np.testing.assert_array_equal(frames[-1][1][li], high[li])
    # a still view after that: a quarter of the rays, none refined, still exact
    f, still = masks(pipeline, scene, inter, *size)
    assert f.stats["rays_traced"] <= 0.26 * f.stats["pixels"]
    for li in high:
        np.testing.assert_array_equal(still[li], high[li])


@pytest.mark.cycles
def test_thin_scene_high_matches_cycles(gl_ctx):
    """The sub-pixel casters scene is a stiff scene like the others: high within 0.1% of Cycles."""
    from benchmarks import stiff_table

    r = stiff_table.evaluate_case("thin", ("raytrace-high",), ctx=gl_ctx, repeats=1)
    res = r["raytrace-high"]
    assert len(res) == 3
    for light, m in res.items():
        assert m["valid"] > 1000, (light, m)
        assert m["mismatch_pct"] <= 0.1, f"thin/{light}: {m['mismatch_pct']:.3f}%"

