"""Structured tracer (grid + BVH textures) == brute force, on seeded random and adversarial scenes."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Scene
from tests.helpers.bake import assert_equal_tracers
from tests.helpers.rays import border_rays, random_rays
from tests.helpers.scenes import adversarial_scene, random_scene


# ------------------------------------------------------------------------------------------
# tests
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_random_scenes_structured_equals_brute(seed):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n_inst=150)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    o, d, t = random_rays(rng, scene, 3000)
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert 0.05 < hit.mean() < 0.95


def test_adversarial_scene():
    rng = np.random.default_rng(42)
    scene, o, d, t = adversarial_scene(rng)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=1.0)))
    assert baked.stats["max_objects_per_node"] >= 1000
    assert baked.accel.layout.levels >= 4
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert 0.05 < hit.mean() < 0.95


def test_axis_rays_on_every_border():
    """Axis-aligned rays (two components exactly 0) starting exactly on node borders and corners."""
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n_inst=120, area=10)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=1.0)))
    o, d, t = border_rays(rng, baked.accel.layout, 300)
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert hit.any()


def test_no_casters_and_empty():
    rng = np.random.default_rng(0)
    for scene in (Scene(), random_scene(rng, n_inst=10, casters=0.0)):
        baked = bake_scene(scene, BakeConfig(structure="grid"))
        for tex in baked.textures.values():
            assert tex.width >= 1 and tex.height >= 1 and tex.layers >= 1
        o, d, t = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), np.inf
        assert not trace_structured(baked, o, d, t).any()
        assert "HS_HAS_MESHES" not in baked.defines and "HS_HAS_SPHERES" not in baked.defines


def test_degenerate_rays():
    rng = np.random.default_rng(5)
    scene = random_scene(rng, n_inst=50, area=3)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    o = np.zeros((4, 3))
    d = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]], float)
    t = np.array([1.0, 0.0, -1.0, 1.0])
    assert not trace_structured(baked, o, d, t).any()
    assert not trace_brute(scene, o, d, t).any()


def test_far_from_origin():
    """A scene 10 km from the origin, small objects: conservative bounds still hold."""
    rng = np.random.default_rng(11)
    scene = random_scene(rng, n_inst=100, area=20)
    scene.instances.matrices[:, 0, 3] += 10000.0
    scene.instances.matrices[:, 1, 3] -= 7000.0
    scene.instances.set_matrices(slice(None), scene.instances.matrices.copy())
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    # bake space: a round origin near the scene, so the textures hold small coordinates
    assert np.allclose(baked.origin, (10000.0, -7000.0, 0.0), atol=64)
    assert np.abs(baked.uniforms["hs_grid_origin"]).max() < 100
    o, d, t = random_rays(rng, scene, 2000)
    assert_equal_tracers(scene, baked, o, d, t)
    # the same scene at home bakes with origin zero
    assert not bake_scene(random_scene(np.random.default_rng(11), n_inst=100, area=20),
                          BakeConfig(structure="grid")).origin.any()


def test_sun_rays_from_ground():
    """Typical shadow rays: from a ground grid towards a sun, tmax infinite."""
    rng = np.random.default_rng(9)
    scene = random_scene(rng, n_inst=200, area=20, tri_counts=(1, 12, 60))
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    X, Y = np.meshgrid(np.linspace(-25, 25, 40), np.linspace(-25, 25, 40))
    o = np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.5)], 1)
    for sun in ([0.3, 0.2, 1.0], [0, 0, 1], [1, 0, 0.2], [0, -1, 0.05]):
        d = np.broadcast_to(np.array(sun, float), o.shape)
        assert_equal_tracers(scene, baked, o, d, np.inf)
