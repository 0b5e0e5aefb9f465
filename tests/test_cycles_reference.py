"""Against Cycles: the G-buffer's world positions equal Cycles' position pass at pixel centres,
and the ray-traced mask equals Cycles' per-light visibility on cube_on_plane."""
import numpy as np
import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W, H = 160, 120


@pytest.fixture(scope="module")
def cube_scene_and_reference():
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

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


def test_sphere_primitives_render_as_the_sphere_we_trace(gl_ctx):
    """A coarse UV sphere flagged as a sphere primitive (squashed by its object's scale, smoothed
    by a modifier): the reference renders the ellipsoid we trace, so the masks agree; with
    ``mesh_spheres`` it renders the facets, whose shadow differs. The scene is left as it was."""
    import bmesh  # (importable once bpy is)
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    bscene = open_scene("cube_on_plane")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=8, v_segments=4, radius=1.0)
    mesh = bpy.data.meshes.new("Coarse ball")
    bm.to_mesh(mesh)
    bm.free()
    ball = bpy.data.objects.new("Ball", mesh)
    bscene.collection.objects.link(ball)
    ball.location, ball.scale = (2.6, -1.6, 1.1), (1.0, 1.0, 0.7)
    ball["hybrid_sphere"] = True
    mod = ball.modifiers.new("Smooth", "SUBSURF")
    mod.levels = mod.render_levels = 1
    meshes_before = set(bpy.data.meshes)

    traced = render_reference(bscene, resolution=(W, H))
    assert ball.data == mesh and mod.show_render and set(bpy.data.meshes) == meshes_before
    faceted = render_reference(bscene, resolution=(W, H), mesh_spheres=True)
    assert ball.data == mesh and set(bpy.data.meshes) == meshes_before

    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    assert scene.instances.sphere.sum() == 1
    pipe = Pipeline(gl_ctx)
    pipe.set_scene(scene)
    frame = pipe.render(scene, Settings(mode="raytrace"), W, H)
    ours = frame.mask_array(frame.lights[0])
    pipe.release()
    mismatch = {}
    for label, ref in (("traced", traced), ("faceted", faceted)):
        theirs = ref.visibility["Sun"]
        valid = ~np.isnan(ours) & ~np.isnan(theirs)
        assert valid.sum() > 0.3 * W * H
        mismatch[label] = (np.abs(ours[valid] - theirs[valid]) > 0.5).mean()
    assert mismatch["traced"] <= 0.001, mismatch
    assert mismatch["faceted"] >= 0.003, mismatch


def test_reaches_tells_which_surfaces_a_light_can_light():
    """The reference's rule for pixels whose own surface no point of the light reaches (their
    light can only come from another surface in the pixel's footprint): facing, a sun's angle, a
    sphere light's radius, a spot's cone widened by that radius, an area light's one side."""
    import bpy
    from mathutils import Matrix

    from hybrid_shadow_addon.blender.cycles_reference import _reaches

    def light(kind, at=(0.0, 0.0, 2.0), **props):
        data = bpy.data.lights.new(f"reach {kind}", kind)
        for k, v in props.items():
            setattr(data, k, v)
        ob = bpy.data.objects.new(f"reach {kind}", data)
        ob.matrix_world = Matrix.Translation(at)  # shines along -z
        return ob

    def reach(ob, points, normals):
        return _reaches(ob, np.array(points, np.float64)[None], np.array(normals, np.float64)[None])[0].tolist()

    up, down, side = (0, 0, 1), (0, 0, -1), (1, 0, 0)
    o = (0.0, 0.0, 0.0)
    dipped = (0.0, 0.999, -0.01)  # 0.57° below the horizon of a sun straight above
    assert reach(light("SUN", angle=0.0), [o] * 4, [up, down, side, dipped]) == [True, False, True, False]
    assert reach(light("SUN", angle=np.radians(4.0)), [o] * 2, [down, dipped]) == [False, True]
    assert reach(light("POINT", shadow_soft_size=0.5), [o] * 2, [side, down]) == [True, False]
    assert reach(light("POINT", shadow_soft_size=3.0), [o], [down]) == [True]
    cone = dict(spot_size=np.radians(60.0))
    pts = [(0.5, 0, 0), (2.0, 0, 0)]
    assert reach(light("SPOT", shadow_soft_size=0.0, **cone), pts, [up, up]) == [True, False]
    assert reach(light("SPOT", shadow_soft_size=1.5, **cone), pts, [up, up]) == [True, True]
    area = light("AREA", size=1.0)
    assert reach(area, [o, (0, 0, 3.0), (5.0, 0, 0), (5.0, 0, 0)],
                 [up, down, (-1, 0, 0), side]) == [True, False, True, False]
