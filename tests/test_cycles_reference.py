"""Against Cycles: the G-buffer's world positions equal Cycles' position pass at pixel centres,
and the ray-traced mask equals Cycles' per-light visibility on cube_on_plane."""
import numpy as np
import pytest

W, H = 160, 120


@pytest.fixture(scope="module")
def cube_scene_and_reference():
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.blender.cycles_reference import render_reference

    import bpy

    bscene = open_scene("cube_on_plane")
    engine_before = bscene.render.engine
    ref = render_reference(bscene, resolution=(W, H))
    assert bscene.render.engine == engine_before, "the user's scene must be restored"
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    return scene, ref


def interior(valid: np.ndarray) -> np.ndarray:
    """Valid pixels whose 8 neighbours are valid too (no silhouettes)."""
    p = np.pad(valid, 1, constant_values=False)
    out = valid.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out &= p[1 + dy:1 + dy + valid.shape[0], 1 + dx:1 + dx + valid.shape[1]]
    return out


def test_gbuffer_positions_match_cycles_position_pass(cube_scene_and_reference, gl_ctx):
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    scene, ref = cube_scene_and_reference
    pipe = Pipeline(gl_ctx)
    frame = pipe.render(scene, Settings(mode="none"), W, H)
    pos = frame.gbuffer.read("position")
    ours = pos[..., 3] > 0.5
    theirs = ~np.isnan(ref.position[..., 0])
    # coverage agrees except on silhouette pixels
    assert (ours != theirs).mean() < 0.01
    both = interior(ours & theirs)
    assert both.sum() > 0.3 * W * H
    cam = scene.camera.matrix[:3, 3]
    dist = np.linalg.norm(ref.position[both] - cam, axis=1)
    err = np.linalg.norm(pos[both, :3] - ref.position[both], axis=1)
    # Cycles samples within +-0.005 px of the centre (filter_width 0.01): allow that footprint
    pixel_size = dist * scene.camera.sensor_width / scene.camera.lens / W
    assert np.percentile(err / pixel_size, 99) < 0.05, np.percentile(err / pixel_size, [50, 99, 100])
    pipe.release()


def test_raytraced_mask_matches_cycles_visibility(cube_scene_and_reference, gl_ctx):
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    scene, ref = cube_scene_and_reference
    pipe = Pipeline(gl_ctx)
    pipe.set_scene(scene)
    frame = pipe.render(scene, Settings(mode="raytrace"), W, H)
    for li in frame.lights:
        name = scene.lights[li].name
        ours = frame.mask_array(li)
        theirs = ref.visibility[name]
        valid = ~np.isnan(ours) & ~np.isnan(theirs)
        assert valid.sum() > 0.3 * W * H
        assert (theirs[valid] < 0.5).sum() > 100, "the reference shows a shadow"
        mismatch = (np.abs(ours[valid] - theirs[valid]) > 0.5).mean()
        assert mismatch <= 0.001, f"{name}: {mismatch:.4%} mismatched"
    pipe.release()
