"""The shadow ray's origin (``offset_origin`` in ``shaders/common/shadow_ray.glsl``, mirrored by
``core/oracle/rays.offset_origins``): pushed along the normal only, by a few ULPs of the
point's largest coordinate, and far enough that a lone convex object never shadows itself,
however far from the bake origin it sits and however close the camera is.

1. numpy: the push is along ``n`` (across the surface by at most the rounding of the result)
   and between 4 and 8 ULPs of the largest coordinate (plus the slack), 2^-16 at least.
2. GLSL: a lone rotated, sheared box or octahedron sphere 150 m to 20 km from the bake origin (an
   anchor on the opposite side centres the bounds), seen from 3 sizes away, lit by suns from
   many directions: no interior pixel that faces a sun is shadowed. (Silhouette pixels are left
   out: their rasterised triangle may not hold the pixel centre, which is the G-buffer's matter.)
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.oracle.rays import ORIGIN_MIN_STEP, ORIGIN_ULPS, offset_origins
from tests.helpers.scenes import cube_model, look_at
from tests.test_stiff import closed_mesh, random_affine


def _ulp(x):
    return np.spacing(np.abs(np.asarray(x, np.float32)))


def test_offset_is_along_the_normal_and_a_few_ulps():
    rng = np.random.default_rng(3)
    n_pts = 20000
    scale = 10.0 ** rng.uniform(-3, 4.5, (n_pts, 1))
    p = (rng.normal(size=(n_pts, 3)) * scale).astype(np.float32)
    p[rng.random((n_pts, 3)) < 0.2] = 0.0  # points on an axis plane
    n = rng.normal(size=(n_pts, 3))
    n[rng.random((n_pts, 3)) < 0.3] = 0.0
    n[(n == 0).all(axis=1), 2] = 1.0
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    slack = np.where(rng.random(n_pts) < 0.5, 0.0, rng.uniform(0, 1e-4, n_pts)).astype(np.float32)
    o = offset_origins(p, n, slack).astype(np.float64)
    d = o - p.astype(np.float64)
    along = (d * n).sum(axis=1)
    across = np.linalg.norm(d - along[:, None] * n, axis=1)
    m = np.abs(p).max(axis=1).astype(np.float64)
    big_ulp = _ulp(m).astype(np.float64)
    want = np.maximum(m * ORIGIN_ULPS, ORIGIN_MIN_STEP) + slack
    # the rounding of n * step and of p + n * step: a ULP of the step and of each coordinate of o
    rounding = (np.linalg.norm(_ulp(o.astype(np.float32)).astype(np.float64), axis=1)
                + _ulp(want).astype(np.float64))
    assert (across <= rounding + 1e-12).all(), float((across / np.maximum(big_ulp, 1e-30)).max())
    assert (np.abs(along - want) <= rounding + 1e-6 * want).all()
    assert (along >= np.maximum(4 * big_ulp, ORIGIN_MIN_STEP) - rounding).all()  # never below 4 ULPs
    far = m > 64.0  # (nearer, the 2^-16 floor is more than 8 ULPs)
    assert far.sum() > 1000
    assert (along[far] - slack[far] <= 8 * big_ulp[far] + rounding[far]).all()  # nor above 8


def _acne(ctx, far, size, which, rng, W=64, H=48, n_suns=8):
    """Interior pixels of a lone convex object facing a sun (n.l > 0.05) that the ray-traced
    mask shadows, and how many such pixels there are."""
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Scene
    from hybrid_shadow_addon.core.settings import Settings

    M = random_affine(rng, 0.0)
    M[:3, :3] *= size / np.abs(np.linalg.det(M[:3, :3])) ** (1 / 3)
    c = np.array([far, far / 7.0, far / 50.0])
    M[:3, 3] = c
    anchor = np.diag([0.01, 0.01, 0.01, 1.0])
    anchor[:3, 3] = -c
    cam = Camera(matrix=look_at(c + np.array([0.3, -3.0, 1.8]) * size, c), lens=35, clip_start=0.01 * size,
                 clip_end=1e5)
    lights = []
    for k in range(n_suns):
        d = rng.normal(size=3)
        lights.append(Light(f"sun{k}", "SUN", matrix=look_at(np.zeros(3), -d / np.linalg.norm(d), up=(0.3, 0.2, 1.0))))
    scene = Scene(models=[closed_mesh(1), cube_model()],
                  instances=Instances(names=["obj", "anchor"], model_ids=[which, 1], matrices=np.array([M, anchor])),
                  lights=lights, camera=cam, resolution=(W, H)).validate()
    pipe = Pipeline(ctx)
    try:
        fr = pipe.render(scene, Settings(mode="raytrace", quality="high", hard=True), W, H)
        gb = fr.gbuffer
        obj = (gb.read("position")[..., 3] > 0.5) & (np.rint(gb.read("material")[..., 2]) == 0)
        pad = np.pad(obj, 1)
        interior = obj & pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
        n = gb.read("normal")[..., :3]
        bad = seen = 0
        for li in fr.lights:
            sel = interior & ((n @ -scene.lights[li].direction) > 0.05)
            bad += int((sel & (fr.mask_array(li) < 0.5)).sum())
            seen += int(sel.sum())
    finally:
        pipe.release()
    return bad, seen


@pytest.mark.gpu
def test_no_self_shadow_far_from_the_bake_origin(gl_ctx):
    rng = np.random.default_rng(1)
    total = 0
    for far in (150.0, 1000.0, 20000.0):
        for size in (0.01, 1.0):
            for which in (0, 1):
                bad, seen = _acne(gl_ctx, far, size, which, rng)
                assert seen > 100, (far, size, which, seen)
                assert bad == 0, f"far {far} size {size} object {which}: {bad} of {seen} pixels self-shadowed"
                total += seen
    assert total > 5000
