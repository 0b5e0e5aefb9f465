"""Ray visibility and holdout: instances the camera does not see are not drawn and still cast;
holdouts are drawn as holes in the image (alpha 0, no colour) and still cast; both change with
no re-bake. Against an exact float64 ray cast and the numpy shadow-ray tracer, and
(``test_scenes/visibility.py``) against Cycles."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.oracle.tracer import trace_structured
from hybrid_shadow_addon.core.scene_sync import NONE, sync_scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import interior, ray_cast
from tests.helpers.scenes import basic_scene, trs

W, H = 160, 120
CUBE, BOX, BALL = 1, 2, 3  # basic_scene's rows: ground, cube, box, ball (a sphere primitive)
HARD = Settings(hard=True, mode="raytrace")

pytestmark = [pytest.mark.gpu]


@pytest.fixture(scope="module")
def pipe(gl_ctx):
    p = Pipeline(gl_ctx)
    yield p
    p.release()


def _scene():
    """basic_scene with a sun low enough that the cube's shadow falls on the ground beside it:
    the cube unseen, the box (triangles) and the ball (sphere primitive) holdouts."""
    scene = basic_scene(with_sphere=True)
    scene.lights[0].matrix = trs((0, 0, 10), rot_z=2.2, rot_x=0.9)
    scene.instances.visible_camera[CUBE] = False
    scene.instances.holdout[[BOX, BALL]] = True
    return scene


def _first_hits(scene):
    """(t, instance) of the camera rays against the instances the camera sees (instance -1:
    none), in ``scene``'s row numbers."""
    seen = np.nonzero(scene.instances.visible_camera)[0]
    view = type(scene)(models=scene.models, instances=scene.instances.take(seen), lights=scene.lights,
                       camera=scene.camera, world_color=scene.world_color, resolution=scene.resolution)
    o, d = scene.camera.pixel_rays(W, H)
    t, inst, face = ray_cast(view, o, d)
    return t, np.where(inst >= 0, seen[np.maximum(inst, 0)], -1), interior(np.where(np.isfinite(t), face, -10**6))


def _oracle_mask(frame, scene, baked, li, pixels):
    o, d, tmax, facing = shadow_rays(frame.gbuffer, pixels, scene.lights[li], baked.origin)
    out = np.zeros(len(o), np.float32)
    if facing.any():
        out[facing] = np.where(trace_structured(baked, o[facing], d[facing], tmax[facing]), 0.0, 1.0)
    return out


def _shadowed_by(scene, frame, row):
    """(H, W) bool: ground pixels whose ray to the sun meets instance ``row`` first."""
    pos = frame.gbuffer.read("position")
    nrm = frame.gbuffer.read("normal")[..., :3].astype(np.float64)
    cov = pos[..., 3] > 0.5
    sun = scene.lights[0].matrix[:3, 2] / np.linalg.norm(scene.lights[0].matrix[:3, 2])
    o = pos[..., :3].astype(np.float64) + 1e-4 * nrm
    t, inst, _ = ray_cast(scene, o, np.broadcast_to(sun, o.shape), casters_only=True)
    return cov & (inst == row)


def test_unseen_instances_are_not_drawn_and_still_cast(pipe):
    scene = _scene()
    pipe.set_scene(scene)
    frame = pipe.render(scene, HARD, W, H)
    gb = frame.gbuffer
    t, first, ok = _first_hits(scene)
    cov = gb.coverage()
    index = np.rint(gb.read("material")[..., 2]).astype(int)
    drawn = ok & (first >= 0) & ~scene.instances.holdout[np.maximum(first, 0)]
    assert drawn.sum() > 0.3 * W * H
    assert cov[drawn].all() and (index[drawn] == first[drawn]).all()
    assert not (index[cov] == CUBE).any(), "the unseen cube was drawn"
    # the cube's shadow on the ground: its pixels are shadowed by the cube and by nothing nearer
    by_cube = _shadowed_by(scene, frame, CUBE) & ok
    assert by_cube.sum() > 200
    mask = frame.mask_array(frame.lights[0])
    assert (mask[by_cube] == 0).all()
    # and the masks are the numpy tracer's on the same G-buffer
    baked = bake_scene(scene, BakeConfig(structure="bvh"))
    rows, cols = np.nonzero(cov)
    ours = mask[rows, cols]
    ref = _oracle_mask(frame, scene, baked, frame.lights[0], (rows, cols))
    assert np.mean(np.abs(ours - ref) > 0.5) < 1e-3


@pytest.mark.parametrize("film_transparent", [False, True])
def test_holdouts_are_holes_in_the_image_and_still_cast(pipe, film_transparent):
    scene = _scene()
    pipe.set_scene(scene)
    frame = pipe.render(scene, HARD, W, H, film_transparent=film_transparent)
    gb = frame.gbuffer
    t, first, ok = _first_hits(scene)
    hole = ok & np.isin(first, [BOX, BALL])
    assert hole.sum() > 300 and (first[hole] == BALL).sum() > 100
    img = frame.image
    assert (img[hole] == 0).all(), "a holdout pixel has colour or alpha"
    assert (gb.read("material")[..., 3][hole] == -1).all()
    assert not gb.coverage()[hole].any()
    assert np.isnan(frame.mask_array(frame.lights[0])[hole]).all()
    background = ok & (first < 0)
    if not film_transparent:
        assert background.any() and (img[background][:, 3] == 1).all()
    seen = ok & (first >= 0) & ~hole
    assert (img[seen][:, 3] == 1).all()
    # the holdouts cast: the ground they shade is shadowed
    mask = frame.mask_array(frame.lights[0])
    for row in (BOX, BALL):
        by = _shadowed_by(scene, frame, row) & ok
        assert by.sum() > 50, row
        assert (mask[by] == 0).all(), row


def test_visibility_changes_need_no_bake_and_moves_keep_unseen_casters(pipe, gl_ctx):
    prev = _scene()
    pipe.set_scene(prev)
    baked = pipe.baked
    scene = _scene()
    scene.instances.visible_camera[CUBE] = True
    scene.instances.holdout[BOX] = False
    assert sync_scene(pipe, prev, scene).kind == NONE
    assert pipe.baked is baked
    frame = pipe.render(scene, HARD, W, H)
    index = np.rint(frame.gbuffer.read("material")[..., 2]).astype(int)
    cov = frame.gbuffer.coverage()
    assert (index[cov] == CUBE).sum() > 100 and (index[cov] == BOX).sum() > 100
    # move the unseen cube: the incremental update gives a fresh bake's masks
    moved = _scene()
    moved.instances.set_matrices([CUBE], trs((-1.0, 1.5, 1.2))[None])
    pipe.set_scene(_scene())
    pipe.move_instances(moved, [CUBE])
    a = pipe.render(moved, HARD, W, H)
    ma = a.mask_array(a.lights[0])
    fresh = Pipeline(gl_ctx)
    try:
        fresh.set_scene(moved)
        b = fresh.render(moved, HARD, W, H)
        mb = b.mask_array(b.lights[0])
    finally:
        fresh.release()
    assert np.array_equal(np.isnan(ma), np.isnan(mb))
    assert np.nanmax(np.abs(ma - mb)) == 0
    assert (_shadowed_by(moved, a, CUBE)).sum() > 100


# ---------------------------------------------------------------------------------------------
# test_scenes/visibility.py against Cycles
# ---------------------------------------------------------------------------------------------
LIMIT_PCT = 0.5


def _cycles_errors(pipe, scene, ref) -> tuple:
    """``({light: MaskError}, share of pixels whose coverage differs from Cycles')``: Cycles'
    film is transparent (alpha < 1, NaN position) on holdouts and the background."""
    from hybrid_shadow_addon.tools.metrics import mask_error

    pipe.set_scene(scene)
    w, h = scene.resolution
    frame = pipe.render(scene, HARD, w, h, film_transparent=True)
    errors = {scene.lights[li].name: mask_error(ref.visibility[scene.lights[li].name], frame.mask_array(li))
              for li in frame.lights}
    opaque = frame.image[..., 3] > 0.5
    return errors, float(np.mean(opaque != np.isfinite(ref.position[..., 0])))


@pytest.mark.blender
@pytest.mark.cycles
def test_visibility_scene_matches_cycles(pipe):
    """Every hard light within 0.5% of the valid pixels, and the image's holes where Cycles'
    film is transparent; the same scene read without its ray visibility and holdouts (all drawn,
    all casting) is not: the scene measures the flags."""
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    bscene = open_scene("visibility")
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get()).validate()
    inst = scene.instances
    assert (~inst.visible_camera).sum() >= 5 and inst.holdout.sum() >= 2 and (~inst.casts_shadow).sum() >= 4
    assert "Emitter" not in inst.names and "Cone" not in inst.names
    assert sum(n.startswith("Emitter/") for n in inst.names) == 10
    ref = render_reference(bscene, resolution=scene.resolution)
    errors, coverage = _cycles_errors(pipe, scene, ref)
    assert coverage < 0.005, coverage  # holes where Cycles' holdouts are (silhouette pixels aside)
    assert sorted(errors) == ["Point", "Sun"]
    for light, e in errors.items():
        assert e.valid_pixels > 20000, light
        assert np.sum(ref.visibility[light] < 0.5) > 2000, f"{light}: the reference shows little shadow"
        assert e.mismatch_pct <= LIMIT_PCT, f"{light}: {e.mismatch_pct:.3f}% ({e.mismatch_pixels}/{e.valid_pixels})"
    inst.visible_camera[:] = True
    inst.holdout[:] = False
    inst.casts_shadow[:] = True
    plain, plain_coverage = _cycles_errors(pipe, scene, ref)
    assert plain_coverage > 0.01, plain_coverage
    assert all(e.mismatch_pct > 2 * LIMIT_PCT for e in plain.values()), \
        {k: round(e.mismatch_pct, 3) for k, e in plain.items()}
