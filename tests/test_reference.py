"""The reference tracers themselves: primitives against float64 geometry, property tests."""
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import sphere_hit, trace_brute, trace_structured, woop_hit, woop_setup
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from tests.helpers.rays import random_triangle_rays


def test_triangle_test_against_float64():
    rng = np.random.default_rng(0)
    v, o, d, tmax, ref, _ = random_triangle_rays(rng, 20000)  # float64 Moller-Trumbore
    f = np.float32
    got = woop_hit(o.astype(f), woop_setup(d.astype(f)), v[:, 0].astype(f), v[:, 1].astype(f), v[:, 2].astype(f),
                   tmax.astype(f))
    assert (got != ref).mean() < 1e-3 and ref.sum() > 100


def test_ellipsoid_sphere_primitive_exact():
    """Sphere primitive with non-uniform, negative scale and rotation = exact ellipsoid."""
    rng = np.random.default_rng(1)
    model = Model("ball", rng.normal(size=(50, 3)), np.arange(48).reshape(-1, 3))
    c, r = model.sphere_center.astype(float), model.sphere_radius
    M = np.eye(4)
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    M[:3, :3] = R @ np.diag([3.0, -0.5, 1.5])
    M[:3, 3] = [1, 2, 3]
    scene = Scene(models=[model], instances=Instances(names=["e"], matrices=M[None], sphere=[True]))
    n = 20000
    o = rng.normal(size=(n, 3)) * 4 + [1, 2, 3]
    d = rng.normal(size=(n, 3))
    tmax = rng.choice([np.inf, 1.0, 3.0], n)
    # float64: ellipsoid = M(sphere) -> solve in model space
    Mi = np.linalg.inv(M)
    om = o @ Mi[:3, :3].T + Mi[:3, 3] - c
    dm = d @ Mi[:3, :3].T
    a = (dm * dm).sum(1)
    b = (om * dm).sum(1)
    cc = (om * om).sum(1) - r * r
    disc = b * b - a * cc
    sq = np.sqrt(np.maximum(disc, 0))
    t0, t1 = (-b - sq) / a, (-b + sq) / a
    ref = (disc >= 0) & (((t0 > 0) & (t0 < tmax)) | ((t1 > 0) & (t1 < tmax)))
    got = trace_brute(scene, o, d, tmax)
    assert (got != ref).mean() < 1e-3 and ref.sum() > 1000
    assert (trace_structured(bake_scene(scene, BakeConfig(structure="grid")), o, d, tmax) == got).all()
    # the robust quadratic: tiny sphere far away along the ray
    f = np.float32
    hit = sphere_hit(np.array([[0, 0, -1e4]], f), np.array([[0, 0, 1]], f), np.zeros((1, 3), f), np.array([1e-3], f),
                     np.array([2e4], f))
    assert hit.all()


coord = st.floats(-20, 20, allow_nan=False, width=32)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 60), base=st.sampled_from([None, 0.5, 2.0, 7.0]),
       spheres=st.floats(0, 1), axis=st.floats(0, 1))
def test_property_structured_equals_brute(seed, n, base, spheres, axis):
    from tests.helpers.rays import random_rays
    from tests.helpers.scenes import blob_model, plate_model, random_matrices

    rng = np.random.default_rng(seed)
    models = [blob_model(rng, 3), plate_model(2), blob_model(rng, 20)]
    inst = Instances(names=[f"o{i}" for i in range(n)], model_ids=rng.integers(0, 3, n),
                     matrices=random_matrices(rng, n, area=rng.uniform(1, 20)), sphere=rng.random(n) < spheres,
                     casts_shadow=rng.random(n) < 0.9)
    scene = Scene(models=models, instances=inst)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=base)))
    o, d, t = random_rays(rng, scene, 300, axis=axis)
    # snap some origins onto node borders of level 0
    s = baked.accel.layout.node_sizes[0]
    k = rng.random(len(o)) < 0.3
    o[k, :2] = baked.accel.layout.origin + np.round((o[k, :2] - baked.accel.layout.origin) / s) * s
    brute = trace_brute(scene, o, d, t)
    assert (trace_structured(baked, o, d, t) == brute).all()
    assert (trace_structured(bake_scene(scene, BakeConfig(structure="bvh")), o, d, t) == brute).all()


@settings(max_examples=40, deadline=None)
@given(ox=coord, oy=coord, oz=st.floats(-2, 6, width=32), dx=st.sampled_from([0.0, 1.0, -1.0, 0.3]),
       dy=st.sampled_from([0.0, 1.0, -1.0, -0.7]), dz=st.sampled_from([0.0, 1.0, -1.0, 0.01]))
def test_property_single_rays(ox, oy, oz, dx, dy, dz):
    """Single rays with components drawn from {0, +-1, ...} over one fixed scene."""
    scene = _fixed_scene()
    o = np.array([[ox, oy, oz]])
    d = np.array([[dx, dy, dz]])
    if not d.any():
        d[0, 2] = 1.0
    for t in (np.inf, 2.0):
        brute = trace_brute(scene, o, d, t)
        assert (trace_structured(_fixed_baked(), o, d, t) == brute).all()
        assert (trace_structured(_fixed_baked("bvh"), o, d, t) == brute).all()


_CACHE = {}


def _fixed_scene():
    if "s" not in _CACHE:
        from tests.helpers.scenes import random_scene

        _CACHE["s"] = random_scene(np.random.default_rng(77), n_inst=120, area=15, tri_counts=(1, 12, 40))
    return _CACHE["s"]


def _fixed_baked(structure="grid"):
    if structure not in _CACHE:
        config = BakeConfig(structure=structure, grid=GridConfig(base_node_size=1.0))
        _CACHE[structure] = bake_scene(_fixed_scene(), config)
    return _CACHE[structure]
