"""Structured tracer (grid + BVH textures) == brute force, on seeded random and adversarial scenes.

Also home of the scene/ray generators the other bake tests import.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene


# ------------------------------------------------------------------------------------------
# generators
# ------------------------------------------------------------------------------------------
def blob_model(rng, n_tri, name="blob", size=1.0):
    """Random triangles in a box (overlapping soup: stresses the BVH)."""
    c = rng.uniform(-size, size, (n_tri, 1, 3))
    v = (c + rng.normal(scale=0.3 * size, size=(n_tri, 3, 3))).reshape(-1, 3)
    return Model(name, v, np.arange(3 * n_tri).reshape(-1, 3))


def plate_model(n=4, name="plate"):
    """A watertight-ish n x n grid of quads in the unit square at z = 0 (shared edges)."""
    xs = np.linspace(-1, 1, n + 1)
    X, Y = np.meshgrid(xs, xs)
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    tris = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            tris += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return Model(name, v, np.array(tris))


def random_matrices(rng, n, area=30.0, zrange=(0, 4), scale=(0.3, 2.0), negative=True):
    M = np.tile(np.eye(4), (n, 1, 1))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    S = rng.uniform(*scale, (n, 3))
    if negative:
        S *= rng.choice([-1.0, 1.0], (n, 3), p=[0.25, 0.75])
    M[:, :3, :3] = R * S[:, None, :]
    M[:, 0, 3] = rng.uniform(-area, area, n)
    M[:, 1, 3] = rng.uniform(-area, area, n)
    M[:, 2, 3] = rng.uniform(*zrange, n)
    return M


def random_scene(rng, n_inst=200, spheres=0.25, area=30.0, tri_counts=(1, 12, 60, 300), casters=0.9):
    models = [blob_model(rng, k, f"blob{k}") for k in tri_counts] + [plate_model(4)]
    n = n_inst
    inst = Instances(names=[f"o{i}" for i in range(n)], model_ids=rng.integers(0, len(models), n),
                     matrices=random_matrices(rng, n, area), sphere=rng.random(n) < spheres,
                     casts_shadow=rng.random(n) < casters)
    return Scene(models=models, instances=inst)


def random_rays(rng, scene, n, targeted=0.5, axis=0.2):
    """Mix of rays aimed at instance centres (hits likely), random rays and axis-aligned rays."""
    c = scene.instances.matrices[:, :3, 3]
    lo, hi = scene.world_bounds()
    lo, hi = lo - 3, hi + 3
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    k = int(n * targeted)
    tgt = c[rng.integers(0, len(c), k)] + rng.normal(scale=0.5, size=(k, 3))
    d[:k] = tgt - o[:k]
    a = rng.random(n) < axis
    # axis-aligned: keep 1 or 2 components, the others exactly 0
    keep = rng.random((n, 3)) < 0.5
    keep[np.arange(n), rng.integers(0, 3, n)] = True
    d[a] = np.where(keep[a], d[a], 0.0)
    t = rng.choice([np.inf, 0.5, 1.0, 1.5, 20.0], n)
    return o, d, t


def adversarial_scene(rng):
    """Objects straddling node borders and levels, a node with thousands of objects, and rays
    on node borders, along axes, from outside the grid and from above."""
    models = [plate_model(2), blob_model(rng, 20), Model("tiny", [[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0.02]], [[0, 1, 2]])]
    parts = []
    # a lattice of plates exactly on integer positions (borders of a unit grid)
    g = np.arange(-8, 9, 2.0)
    X, Y = np.meshgrid(g, g)
    n1 = X.size
    M1 = np.tile(np.eye(4), (n1, 1, 1))
    M1[:, 0, 3], M1[:, 1, 3] = X.ravel(), Y.ravel()
    M1[:, 2, 3] = rng.uniform(0, 2, n1)
    M1[:, :3, :3] *= rng.choice([-1.0, 1.0], (n1, 1, 3)) * rng.uniform(0.3, 1.2, (n1, 1, 3))
    parts.append(Instances(names=[f"p{i}" for i in range(n1)], model_ids=np.zeros(n1), matrices=M1))
    # 3000 tiny objects in one small region (thousands in a node)
    n2 = 3000
    M2 = np.tile(np.eye(4), (n2, 1, 1))
    M2[:, :3, 3] = rng.uniform([3.1, 3.1, 0.0], [3.9, 3.9, 1.0], (n2, 3))
    parts.append(Instances(names=[f"t{i}" for i in range(n2)], model_ids=np.full(n2, 2), matrices=M2,
                           sphere=rng.random(n2) < 0.5))
    # big objects spanning many nodes (go to high levels)
    M3 = random_matrices(rng, 6, area=6, scale=(3, 6))
    parts.append(Instances(names=[f"b{i}" for i in range(6)], model_ids=np.ones(6), matrices=M3,
                           sphere=np.array([0, 1, 0, 1, 0, 1], bool)))
    scene = Scene(models=models, instances=Instances.concatenate(parts))
    baked = bake_scene(scene, BakeConfig(structure="grid", base_node_size=1.0))
    lay = baked.accel.layout
    n = 6000
    o = rng.uniform(-10, 10, (n, 3))
    o[:, 2] = rng.uniform(-1, 4, n)
    # origins exactly on node borders of random levels
    lv = rng.integers(0, lay.levels, n)
    s = lay.node_sizes[lv]
    on = rng.random(n) < 0.5
    o[on, 0] = lay.origin[0] + np.round((o[on, 0] - lay.origin[0]) / s[on]) * s[on]
    on = rng.random(n) < 0.5
    o[on, 1] = lay.origin[1] + np.round((o[on, 1] - lay.origin[1]) / s[on]) * s[on]
    tgt = scene.instances.matrices[rng.integers(0, len(scene.instances), n), :3, 3]
    d = tgt - o + rng.normal(scale=0.2, size=(n, 3))
    axis = rng.random(n) < 0.4
    comp = rng.integers(0, 3, n)
    dd = np.zeros((n, 3))
    dd[np.arange(n), comp] = rng.choice([-1.0, 1.0], n)
    two = rng.random(n) < 0.5
    dd[two] += np.where(rng.random((two.sum(), 3)) < 0.5, 0, rng.choice([-1.0, 1.0], (two.sum(), 3)))
    d[axis] = dd[axis]
    d[(d == 0).all(axis=1)] = [0, 0, 1]
    far = rng.random(n) < 0.1  # outside the grid
    o[far, :2] *= 5
    t = rng.choice([np.inf, 1.0, 5.0], n)
    return scene, o, d, t


def assert_equal_tracers(scene, baked, o, d, t):
    a = trace_structured(baked, o, d, t)
    b = trace_brute(scene, o, d, t)
    bad = np.nonzero(a != b)[0]
    assert bad.size == 0, f"{bad.size} rays differ, first {bad[:5]}: structured {a[bad[:5]]}"
    return a


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
    baked = bake_scene(scene, BakeConfig(structure="grid", base_node_size=1.0))
    assert baked.stats["max_objects_per_node"] >= 1000
    assert baked.accel.layout.levels >= 4
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert 0.05 < hit.mean() < 0.95


AXIS_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                      [1, 1, 0], [1, 0, -1], [0, -1, 1], [-1, 1, -1]], float)


def border_rays(rng, layout, per_level: int):
    """Rays along axes (components exactly 0) from ``per_level`` node corners of every grid
    level, half of them infinite: ``(origins, dirs, tmax)``."""
    pts = []
    for lvl in range(layout.levels):
        s = layout.node_sizes[lvl]
        nx, ny = layout.dims[lvl]
        X, Y = np.meshgrid(layout.origin[0] + s * np.arange(nx + 1), layout.origin[1] + s * np.arange(ny + 1))
        P = np.stack([X.ravel(), Y.ravel(), rng.uniform(-1, 5, X.size)], 1)
        pts.append(P[rng.permutation(len(P))[:per_level]])
    P = np.concatenate(pts).astype(np.float32).astype(np.float64)  # (exact in float32 too)
    o = np.repeat(P, len(AXIS_DIRS), axis=0)
    d = np.tile(AXIS_DIRS, (len(P), 1))
    return o, d, np.where(rng.random(len(o)) < 0.5, np.inf, 3.0)


def test_axis_rays_on_every_border():
    """Axis-aligned rays (two components exactly 0) starting exactly on node borders and corners."""
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n_inst=120, area=10)
    baked = bake_scene(scene, BakeConfig(structure="grid", base_node_size=1.0))
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
    assert not bake_scene(random_scene(np.random.default_rng(11), n_inst=100, area=20), BakeConfig(structure="grid")).origin.any()


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
