"""The whole pipeline on the test scenes: the GLSL ray-traced masks against the numpy reference
tracer fed the same G-buffer origins; shadow maps against rays away from shadow edges;
interlacing; incremental updates; what the shader variants compile."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.oracle.tracer import trace_structured
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.blender_env import TEST_SCENES

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.slow]

W, H = 160, 120
SAMPLES_PER_LIGHT = 1500  # the numpy tracer is the slow side: compare a seeded sample of pixels



def reference_mask(frame, scene, baked, li, pixels):
    """The numpy tracer's verdict at (rows, cols): 1 lit, 0 shadowed (or facing away)."""
    o, d, tmax, facing = shadow_rays(frame.gbuffer, pixels, scene.lights[li], baked.origin)
    out = np.zeros(len(o), np.float32)
    if facing.any():
        occ = trace_structured(baked, o[facing], d[facing], tmax[facing])
        out[facing] = np.where(occ, 0.0, 1.0)
    return out


@pytest.mark.parametrize("structure", ["grid", "bvh"])
@pytest.mark.parametrize("name", list(TEST_SCENES) + ["smooth_shapes"])
def test_glsl_masks_equal_numpy_reference(name, structure, pipeline, loaded):
    """(The fragment path, as a GL 4.1 context traces; tests/test_trace_path.py shows the compute
    path's masks equal to it in every mode.)"""
    scene = loaded(name)
    pipeline.set_scene(scene, structure)
    frame = pipeline.render(scene, Settings(hard=True, mode="raytrace", structure=structure, trace_path="fragment"),
                            W, H)
    assert pipeline.baked.structure == structure
    assert frame.stats["trace_path"] == "fragment"
    assert frame.lights, "every test scene has shadowed lights"
    rng = np.random.default_rng(7)
    total = mismatched = 0
    for li in frame.lights:
        mask = frame.mask_array(li)
        valid = np.argwhere(~np.isnan(mask))
        pick = valid[rng.choice(len(valid), min(SAMPLES_PER_LIGHT, len(valid)), replace=False)]
        pixels = (pick[:, 0], pick[:, 1])
        ref = reference_mask(frame, scene, pipeline.baked, li, pixels)
        got = mask[pixels]
        assert set(np.unique(got)) <= {0.0, 1.0}
        total += len(ref)
        mismatched += int((ref != got).sum())
    assert total > 0
    assert mismatched <= 0.001 * total, f"{name}: {mismatched} of {total} samples differ"


def edge_distance_mask(mask: np.ndarray, radius: int) -> np.ndarray:
    """True where a pixel is more than ``radius`` pixels from any change of the mask (or NaN)."""
    m = np.nan_to_num(mask, nan=-1.0)
    far = np.ones(m.shape, bool)
    pad = np.pad(m, radius, mode="edge")
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            shifted = pad[radius + dy:radius + dy + m.shape[0], radius + dx:radius + dx + m.shape[1]]
            far &= shifted == m
    return far & ~np.isnan(mask)


def lit_region(frame, light) -> np.ndarray:
    """Pixels the light reaches at all: inside a spot's cone (elsewhere a mask means nothing)."""
    pos = frame.gbuffer.read("position")[..., :3].astype(np.float64)
    if light.type != "SPOT":
        return np.ones(pos.shape[:2], bool)
    v = pos - light.position
    cos = (v @ light.direction) / np.maximum(np.linalg.norm(v, axis=-1), 1e-12)
    return cos > np.cos(light.spot_size / 2)


@pytest.mark.parametrize("name", ["cube_on_plane", "forest", "city"])
def test_shadowmap_agrees_with_rays_away_from_edges(name, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene)
    rt = pipeline.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    rays = {li: rt.mask_array(li) for li in rt.lights}
    sm = pipeline.render(scene, Settings(hard=True, mode="shadowmap", shadowmap_size=2048), W, H)
    for li in sm.lights:
        far = edge_distance_mask(rays[li], 3) & lit_region(sm, scene.lights[li])
        if far.sum() < 50:  # (a spot aimed outside the view)
            continue
        got = sm.mask_array(li)[far]
        agree = (np.abs(got - rays[li][far]) < 0.5).mean()
        assert agree >= 0.98, f"{name} light {scene.lights[li].name}: {agree:.4f}"


def test_quality_levels_and_upsample(pipeline, loaded):
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene)
    full = pipeline.render(scene, Settings(hard=True, mode="raytrace", quality="high"), W, H)
    ref = full.mask_array(full.lights[0])
    for quality, floor in (("medium", 0.97), ("low", 0.93)):
        frame = pipeline.render(scene, Settings(hard=True, mode="raytrace", quality=quality), W, H)
        assert frame.stats["mask_resolution"] == list(Settings(hard=True, quality=quality).mask_size(W, H))
        m = frame.mask_array(frame.lights[0])
        assert m.shape == (H, W)
        ok = ~np.isnan(ref) & ~np.isnan(m)
        assert (np.abs(m[ok] - ref[ok]) < 0.5).mean() >= floor


def test_interlacing_converges_and_never_keeps_stale_shadows(pipeline, loaded):
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene)
    exact = pipeline.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    exact_mask = exact.mask_array(exact.lights[0])
    inter = Settings(hard=True, mode="raytrace", interlace=True)
    pipeline.reset_history()
    for _ in range(4):
        frame = pipeline.render(scene, inter, W, H)
    np.testing.assert_array_equal(frame.mask_array(frame.lights[0]), exact_mask)

    # move the cube far away: the next interlaced frame must not show its old shadow anywhere
    cube = scene.instances.names.index("Cube")
    old = scene.instances.matrices[cube].copy()
    moved = old.copy()
    moved[:3, 3] += (0.0, 0.0, 500.0)
    scene.instances.set_matrices([cube], moved)
    pipeline.move_instances(scene, [cube])
    first = pipeline.render(scene, inter, W, H).mask_array(exact.lights[0])
    valid = ~np.isnan(first)
    assert (first[valid] == 1.0).all(), "a stale shadow survived the move"
    scene.instances.set_matrices([cube], old)
    pipeline.move_instances(scene, [cube])


def test_incremental_move_equals_fresh_bake(pipeline, loaded, gl_ctx):
    scene = loaded("forest")
    pipeline.set_scene(scene)
    rng = np.random.default_rng(3)
    idx = rng.choice(len(scene.instances), 20, replace=False)
    before = scene.instances.matrices[idx].copy()
    m = before.copy()
    m[:, :3, 3] += rng.uniform(-15, 15, (20, 3)) * (1, 1, 0)
    scene.instances.set_matrices(idx, m)
    try:
        pipeline.move_instances(scene, idx)
        inc = pipeline.render(scene, Settings(hard=True, mode="raytrace"), W, H)
        inc_masks = {li: inc.mask_array(li) for li in inc.lights}
        fresh = Pipeline(gl_ctx)
        fresh.set_scene(scene)
        full = fresh.render(scene, Settings(hard=True, mode="raytrace"), W, H)
        for li in full.lights:
            np.testing.assert_array_equal(inc_masks[li], full.mask_array(li))
        fresh.release()
    finally:
        scene.instances.set_matrices(idx, before)
        pipeline.set_scene(scene)


def test_shader_variants_hold_only_what_the_scene_needs(pipeline, loaded):
    scene = loaded("cube_on_plane")  # one sun, meshes only
    pipeline.set_scene(scene)
    frame = pipeline.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    defines = set(frame.stats["defines"])
    assert "HS_LIGHT_SUN=1" in defines and "HS_HAS_MESHES=1" in defines
    assert not any(d.startswith(("HS_LIGHT_LOCAL", "HS_HAS_SPHERES", "HS_MAX_DISTANCE", "HS_INTERLACE"))
                   for d in defines)
    frame = pipeline.render(scene, Settings(hard=True, mode="raytrace", max_distance=5.0), W, H)
    assert "HS_MAX_DISTANCE=1" in frame.stats["defines"]
    forest = loaded("forest")
    assert "HS_HAS_SPHERES" in bake_scene(forest, BakeConfig(structure="grid")).defines


def test_progress_steps_and_cancel(pipeline, loaded):
    scene = loaded("forest")
    pipeline.set_scene(scene)
    seen = []
    frame = pipeline.render(scene, Settings(hard=True, mode="raytrace"), 40, 30,
                            progress=lambda done, total, label: seen.append((label, done, total)))
    labels = [label for label, _, _ in seen]
    assert labels[0] == "G-buffer" and labels[-1] == "Reading the image"
    for li in frame.lights:
        assert f"Ray tracing shadows: {scene.lights[li].name}" in labels
    assert [done for _, done, _ in seen] == list(range(len(seen)))
    assert all(total == len(seen) for _, _, total in seen)

    class StopError(Exception):
        pass

    def cancel(done, total, label):
        if label.startswith("Shadow map"):
            raise StopError

    with pytest.raises(StopError):
        pipeline.render(scene, Settings(hard=True, mode="shadowmap"), 40, 30, progress=cancel)


@pytest.mark.parametrize("name", list(TEST_SCENES) + ["stiff/stadium", "stiff/clip_range", "stiff/far_away"])
def test_bvh_masks_equal_grid_masks(name, pipeline, loaded):
    """Both structures trace the same triangles with the same tests: the masks agree (also where
    a 5 km ground triangle lies under centimetre-scale receivers: no self-shadowing)."""
    scene = loaded(name)
    pipeline.set_scene(scene, "grid")
    masks = {}
    for structure in ("grid", "bvh"):
        frame = pipeline.render(scene, Settings(hard=True, mode="raytrace", structure=structure), W, H)
        assert pipeline.baked.structure == structure  # the render re-baked for the structure
        masks[structure] = [frame.mask_array(li) for li in frame.lights]
    for a, b in zip(masks["grid"], masks["bvh"]):
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        assert same.mean() >= 0.9999, f"{name}: {int((~same).sum())} pixels differ"


def test_incremental_move_with_bvh_equals_fresh_bake(pipeline, loaded, gl_ctx):
    scene = loaded("forest")
    settings = Settings(hard=True, mode="raytrace", structure="bvh")
    pipeline.set_scene(scene, "bvh")
    rng = np.random.default_rng(4)
    idx = rng.choice(len(scene.instances), 20, replace=False)
    before = scene.instances.matrices[idx].copy()
    m = before.copy()
    m[:, :3, 3] += rng.uniform(-15, 15, (20, 3)) * (1, 1, 0)
    scene.instances.set_matrices(idx, m)
    try:
        pipeline.move_instances(scene, idx)
        inc = pipeline.render(scene, settings, W, H)
        assert pipeline.baked.structure == "bvh"
        inc_masks = {li: inc.mask_array(li) for li in inc.lights}
        fresh = Pipeline(gl_ctx)
        fresh.set_scene(scene, "bvh")
        full = fresh.render(scene, settings, W, H)
        for li in full.lights:
            np.testing.assert_array_equal(inc_masks[li], full.mask_array(li))
        fresh.release()
    finally:
        scene.instances.set_matrices(idx, before)
        pipeline.set_scene(scene)


def test_a_cancelled_frame_leaves_nothing_behind(gl_ctx, loaded):
    """A frame aborted inside the shadow-map pass (blending on, MIN equation) does not change
    the next frame of the same pipeline."""
    scene = loaded("forest")
    pipe, fresh = Pipeline(gl_ctx), Pipeline(gl_ctx)
    try:
        pipe.set_scene(scene)

        def cancel(done, total, label):
            if label.startswith("Shadow map") and done > 2:
                raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            pipe.render(scene, Settings(hard=True, mode="shadowmap"), W, H, progress=cancel)
        for settings in (Settings(hard=True, mode="raytrace"), Settings(hard=True, mode="raytrace", quality="medium"),
                         Settings(hard=True, mode="raytrace", structure="bvh"),
                         Settings(hard=True, mode="shadowmap")):
            a = pipe.render(scene, settings, W, H)
            b = fresh.render(scene, settings, W, H)
            assert np.array_equal(a.image, b.image, equal_nan=True), settings
    finally:
        pipe.release()
        fresh.release()


def test_a_frames_masks_are_read_before_the_next_frame(pipeline, loaded):
    """A frame's masks live in the pipeline's targets: read after the next frame (or after the
    targets were given back) they are one clear error, not the later frame's masks."""
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene)
    first = pipeline.render(scene, Settings(hard=True), W, H)
    kept = first.mask_array(first.lights[0])
    second = pipeline.render(scene, Settings(hard=True), W, H)
    np.testing.assert_array_equal(second.mask_array(second.lights[0]), kept)
    with pytest.raises(RuntimeError, match="drawn over by a later frame"):
        first.mask_array(first.lights[0])
    pipeline.release_targets()
    with pytest.raises(RuntimeError, match="drawn over by a later frame"):
        second.mask_array(second.lights[0])
