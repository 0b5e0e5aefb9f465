"""Cycles' shading normals and shadow terminator on smooth-shaded models (``light/sample.h``,
``closure/bsdf_diffuse.h``):

1. The G-buffer's ``TERMINATOR`` lift equals the numpy mirror of Cycles'
   ``shadow_ray_smooth_surface_offset`` computed from the triangles themselves (float64), on a
   smooth ball under a rotation and a non-uniform scale: wound outwards, wound inwards (the
   camera sees its triangles' backs: both normals turn over) and with its corner normals
   against its winding (the fit's other branch); flat models write none.
2. The ray-traced masks equal the numpy tracer fed the same G-buffer (shading-normal facing,
   lifted origins, the own-surface rule) under a sun and a point light low over the ball's
   terminator, where pixels lit by the shading normal while their facet turns from the light
   exist; and those pixels are traced (not all answered 0 by the geometric facing).
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.oracle.terminator import smooth_surface_offset, world_corner_normals
from hybrid_shadow_addon.core.scene import Light, Model
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import interior, ray_cast
from tests.helpers.scenes import basic_scene, trs

pytestmark = [pytest.mark.gpu]

W, H = 160, 120
BALL = 2  # the instance that becomes the smooth ball


def ball_scene(wound="outwards", lights=None):
    """``basic_scene`` with its rotated box replaced by a low-poly smooth ball (12 x 8 facets,
    corner normals of the true sphere), rotated and squashed; ``wound``: "outwards",
    "inwards" (triangles reversed) or "against" (outwards, corner normals pointing in)."""
    scene = basic_scene(lights=lights)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 13)[:-1], np.linspace(0.2, np.pi - 0.2, 7))
    verts = np.stack([np.sin(v) * np.cos(u), np.sin(v) * np.sin(u), np.cos(v)], -1).reshape(-1, 3)
    i = np.arange(6)[:, None] * 12 + np.arange(12)[None, :]
    j = np.arange(6)[:, None] * 12 + (np.arange(12)[None, :] + 1) % 12
    quads = np.stack([i, j, j + 12, i + 12], -1).reshape(-1, 4)
    tris = np.concatenate([quads[:, [0, 2, 1]], quads[:, [0, 3, 2]]])  # outwards
    if wound == "inwards":
        tris = tris[:, ::-1]
    normals = -verts[tris] if wound == "against" else verts[tris]
    scene.models.append(Model("smooth ball", verts, tris, normals=normals))
    scene.instances.model_ids[BALL] = 2
    scene.instances.set_matrices([BALL], trs((1.5, -1.2, 1.0), rot_z=0.4, rot_x=0.3, scale=(1.2, 0.9, 0.8)))
    return scene


@pytest.mark.parametrize("wound", ["outwards", "inwards", "against"])
def test_lift_is_cycles_smooth_surface_offset(pass_rig, wound):
    scene = ball_scene(wound)
    gb = pass_rig.gbuffer(scene, W, H)
    lift = gb.read("terminator")
    inst = np.round(gb.read("material")[..., 2]).astype(int)
    o, d = scene.camera.pixel_rays(W, H)
    t, hit_inst, face = ray_cast(scene, o, d)
    on = gb.coverage() & (inst == BALL) & (hit_inst == BALL) & interior(np.where(hit_inst == BALL, face, -1))
    assert on.sum() > 300
    # the hit triangle of each pixel, its world corners and normals
    first = sum(scene.models[m].triangle_count for m in scene.instances.model_ids[:BALL])
    ball = scene.models[2]
    k = face[on] - first
    m = scene.instances.matrices[BALL]
    corners = ball.vertices[ball.triangles[k]].astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    normals = world_corner_normals(ball.normals[k], np.broadcast_to(m, (len(k), 4, 4)))
    p = gb.read("position")[on][:, :3].astype(np.float64)
    e1, e2, dp = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], p - corners[:, 0]
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d20, d21 = (dp * e1).sum(1), (dp * e2).sum(1)
    den = d00 * d11 - d01 * d01
    b1, b2 = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    bary = np.stack([1 - b1 - b2, b1, b2], axis=1)
    ng = gb.read("normal")[on][:, :3].astype(np.float64)
    want = smooth_surface_offset(corners, normals, bary, ng)
    got = lift[on][:, :3].astype(np.float64)
    size = np.linalg.norm(e1, axis=1)
    assert np.abs(want).max() > 1e-3 * size.max(), "the ball's facets lift their points"
    err = np.linalg.norm(got - want, axis=1)
    assert np.percentile(err / size, 99) < 1e-4, np.percentile(err / size, [50, 99, 100])
    # the interpolated normal on the camera's side of the facet, or against it (the fit's other
    # branch), but for a few grazing pixels at the silhouette; either way the lift leaves the
    # facet on the side the shadow rays leave from
    side = (np.einsum("nk,nkj->nj", bary, normals) * ng).sum(1) > 0
    assert side.mean() > 0.95 if wound != "against" else side.mean() < 0.05
    assert ((want * ng).sum(1) >= -1e-12).all()
    np.testing.assert_allclose(lift[on][:, 3], 0.1, rtol=1e-6)  # the default geometry offset
    flat = gb.coverage() & (inst != BALL)
    assert flat.sum() > 1000 and not lift[flat].any()


LIGHTS = [Light("low sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=2.2, rot_x=1.35)),
          Light("lamp", "POINT", power=400.0, matrix=trs((3.5, -4.0, 1.1)))]


@pytest.mark.parametrize("wound", ["outwards", "inwards"])
def test_masks_follow_the_shading_normal_and_lifted_origins(pipeline, wound):
    from hybrid_shadow_addon.core.oracle.tracer import trace_structured

    scene = ball_scene(wound, lights=LIGHTS)
    pipeline.set_scene(scene, "bvh")
    frame = pipeline.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    gb = frame.gbuffer
    inst = np.round(gb.read("material")[..., 2]).astype(int)
    ns, ng = gb.read("shading_normal")[..., :3], gb.read("normal")[..., :3]
    for li in frame.lights:
        mask = frame.mask_array(li)
        rows, cols = np.nonzero(gb.coverage())
        o, d, tmax, facing = shadow_rays(gb, (rows, cols), scene.lights[li], pipeline.baked.origin)
        ref = np.zeros(len(o), np.float32)
        occ = trace_structured(pipeline.baked, o[facing], d[facing], tmax[facing])
        ref[facing] = np.where(occ, 0.0, 1.0)
        got = mask[rows, cols]
        assert (got != ref).sum() <= 0.001 * len(ref), (scene.lights[li].name, int((got != ref).sum()))
        # past the facets' terminator: lit by the shading normal, the facet turned away
        unit = d / np.linalg.norm(d, axis=1, keepdims=True)
        on_ball = inst[rows, cols] == BALL
        past = on_ball & ((ns[rows, cols] * unit).sum(1) > 0) & ((ng[rows, cols] * unit).sum(1) <= 0)
        assert past.sum() > 10, scene.lights[li].name
        assert facing[past].mean() > 0.95  # (the rays' own directions start at lifted origins)
        if wound == "outwards":  # a convex ball: most of them lit, as Cycles lights them
            assert got[past].mean() > 0.5, (scene.lights[li].name, got[past].mean())


SOFT_LIGHTS = [Light("low wide sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=2.2, rot_x=1.3),
                     angle=np.radians(12)),
               Light("ball lamp", "POINT", power=400.0, matrix=trs((3.5, -4.0, 1.1)), radius=0.4)]


def test_soft_masks_weigh_by_the_shading_normal_from_lifted_origins(pipeline):
    """Lights with a size: each sample weighs by the shading normal, as Cycles' diffuse closure
    does, from the origin the terminator lifts towards the light's centre; against the numpy soft
    oracle (256 jittered samples, the brute-force tracer: a ray may hit its own facet) on the
    smooth ball."""
    from hybrid_shadow_addon.core.oracle.soft import soft_visibility

    scene = ball_scene(lights=SOFT_LIGHTS)
    pipeline.set_scene(scene, "bvh")
    frame = pipeline.render(scene, Settings(mode="raytrace"), W, H)
    gb = frame.gbuffer
    inst = np.round(gb.read("material")[..., 2]).astype(int)
    rng = np.random.default_rng(5)
    for li in frame.lights:
        rows, cols = np.nonzero(gb.coverage() & (inst == BALL))
        pick = rng.choice(len(rows), min(1500, len(rows)), replace=False)
        rows, cols = rows[pick], cols[pick]
        o, _, _, _ = shadow_rays(gb, (rows, cols), scene.lights[li], pipeline.baked.origin)
        ns = gb.read("shading_normal")[rows, cols, :3]
        ref = soft_visibility(scene, li, o, ns, samples=256)
        err = np.abs(frame.mask_array(li)[rows, cols] - ref)
        name = scene.lights[li].name
        d = shadow_rays(gb, (rows, cols), scene.lights[li], pipeline.baked.origin)[1]
        cos = (ns * d).sum(1) / np.linalg.norm(d, axis=1)
        assert (np.abs(cos) < 0.1).sum() > 30, f"{name}: the ball's terminator in view"
        assert err.mean() < 0.01, f"{name}: mean error {err.mean():.4f}"
        assert (err > 0.15).mean() < 0.01, f"{name}: {(err > 0.15).sum()} pixels off by more than 0.15"


def test_textured_smooth_models_write_the_same_lift(pass_rig):
    """A smooth model shown with a textured material (the TEXTURED and TERMINATOR variants
    together): the same lift and shading normals as untextured, its albedo from the image."""
    from hybrid_shadow_addon.core.scene import Image, Material
    from tests.helpers.scenes import colour_image

    plain = ball_scene()
    gb = pass_rig.gbuffer(plain, W, H)
    want = {k: gb.read(k).copy() for k in ("terminator", "shading_normal", "albedo")}
    textured = ball_scene()
    ball = textured.models[2]
    ball.uvs = np.random.default_rng(1).random((ball.triangle_count, 3, 2)).astype(np.float32)
    textured.images = [Image("colours", colour_image())]
    textured.materials = [Material("colours", color_image=0)]
    textured.instances.material_ids[BALL] = 0
    textured.validate()
    gb = pass_rig.gbuffer(textured, W, H)
    on = gb.coverage() & (np.round(gb.read("material")[..., 2]) == BALL)
    assert on.sum() > 300
    for k in ("terminator", "shading_normal"):
        np.testing.assert_array_equal(gb.read(k)[on], want[k][on])
    assert np.abs(gb.read("albedo")[on] - want["albedo"][on]).max() > 0.1
