"""Incremental updates: moved instances and edited meshes."""
import numpy as np

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import trace_structured
from hybrid_shadow_addon.core.scene import Model
from tests.helpers.bake import assert_equal_tracers, assert_report_covers, snapshot
from tests.helpers.rays import random_rays
from tests.helpers.scenes import blob_model, random_scene


def test_move_instances_matches_brute_and_touches_only_moved():
    rng = np.random.default_rng(0)
    scene = random_scene(rng, n_inst=250, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    for step in range(4):
        before = snapshot(baked)
        idx = rng.choice(len(scene.instances), 12, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :3, 3] += rng.normal(scale=[8, 8, 1], size=(12, 3))
        if step == 2:
            M[:, :3, :3] *= rng.uniform(0.5, 3.0, (12, 1, 1))  # grow: may move up levels
        scene.instances.set_matrices(idx, M)
        rep = baked.update_instances(scene, idx)
        assert not rep.regrid
        for name in ("model", "bvh", "tri"):
            assert np.array_equal(before[name], baked.textures[name].data)
        assert_report_covers(baked, before, rep)
        assert rep.objects == 12 and rep.nodes_changed <= 24
        o, d, t = random_rays(rng, scene, 600)
        assert_equal_tracers(scene, baked, o, d, t)
    # equal to a fresh bake on the same rays
    o, d, t = random_rays(rng, scene, 1500)
    assert (trace_structured(baked, o, d, t)
            == trace_structured(bake_scene(scene, BakeConfig(structure="grid")), o, d, t)).all()


def test_crowding_relocates_to_tail_and_leaving_grid_goes_outside():
    rng = np.random.default_rng(1)
    scene = random_scene(rng, n_inst=300, area=20, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(outside_rebake_fraction=0.5)))
    n = len(scene.instances)
    # pile 60 instances onto one spot: their node overflows its capacity -> tail
    idx = rng.choice(n, 60, replace=False)
    M = scene.instances.matrices[idx].copy()
    M[:, :3, 3] = [1.0, 1.0, 1.0]
    M[:, :3, :3] = np.eye(3) * 0.1
    scene.instances.set_matrices(idx, M)
    tail0 = baked.accel.grid.index_tail
    before = snapshot(baked)
    rep = baked.update_instances(scene, idx)
    assert baked.accel.grid.index_tail > tail0 and not rep.regrid
    assert_report_covers(baked, before, rep)
    o, d, t = random_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)
    # move a few far outside the grid: they go to the outside node, still traced
    idx2 = rng.choice(np.setdiff1d(np.nonzero(scene.instances.casts_shadow)[0], idx), 5, replace=False)
    M = scene.instances.matrices[idx2].copy()
    M[:, 0, 3] += 500.0
    scene.instances.set_matrices(idx2, M)
    rep = baked.update_instances(scene, idx2)
    assert baked.stats["outside_objects"] == 5 and not rep.regrid
    o = scene.instances.matrices[idx2, :3, 3] + [0, 0, 10]
    d = np.tile([0.0, 0.0, -1.0], (5, 1))
    assert_equal_tracers(scene, baked, o, d, np.inf)
    o, d, t = random_rays(rng, scene, 1000)
    assert_equal_tracers(scene, baked, o, d, t)


def test_regrid_when_many_leave():
    rng = np.random.default_rng(2)
    scene = random_scene(rng, n_inst=200, area=10)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    idx = np.arange(50)
    M = scene.instances.matrices[idx].copy()
    M[:, 1, 3] += 300.0
    scene.instances.set_matrices(idx, M)
    rep = baked.update_instances(scene, idx)
    assert rep.regrid and {"grid", "grid_index"} <= rep.resized and baked.stats["outside_objects"] == 0
    o, d, t = random_rays(rng, scene, 1000)
    assert_equal_tracers(scene, baked, o, d, t)


def test_caster_flag_and_many_updates_exhaust_tail():
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n_inst=150, area=15)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(index_reserve=0.0)))
    for _ in range(30):
        idx = rng.choice(150, 20, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :2, 3] = rng.uniform(-15, 15, (20, 2))
        scene.instances.set_matrices(idx, M)
        scene.instances.casts_shadow[idx[:3]] = ~scene.instances.casts_shadow[idx[:3]]
        baked.update_instances(scene, idx)
    assert baked.stats["casters"] == scene.instances.casts_shadow.sum()
    o, d, t = random_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)


def test_update_model_rebuilds_that_model_only():
    rng = np.random.default_rng(4)
    scene = random_scene(rng, n_inst=200, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    m = 2
    before = snapshot(baked)
    other = [k for k in range(len(scene.models)) if k != m]
    old_rows = {k: (baked.accel.models.node_start[k], baked.accel.models.node_count[k]) for k in other}
    scene.models[m] = blob_model(rng, 200, "edited", size=2.0)  # bigger: appended
    rep = baked.update_model(scene, m)
    for k in other:  # other models' BVHs untouched
        s, c = old_rows[k]
        assert baked.accel.models.node_start[k] == s and baked.accel.models.node_count[k] == c
        a = before["bvh"].reshape(-1, 4)[2 * s:2 * (s + c)]
        assert np.array_equal(a, baked.textures["bvh"].linear()[2 * s:2 * (s + c)])
    assert_report_covers(baked, before, rep)
    o, d, t = random_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)
    # smaller edit: in place
    start = baked.accel.models.node_start[m]
    scene.models[m] = blob_model(rng, 30, "edited2")
    before = snapshot(baked)
    rep = baked.update_model(scene, m)
    assert baked.accel.models.node_start[m] == start and not ({"bvh", "tri"} & rep.resized)
    assert_report_covers(baked, before, rep)
    assert_equal_tracers(scene, baked, o, d, t)
    # a new model appended to the scene
    scene.models.append(Model("new", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    baked.update_model(scene, len(scene.models) - 1)
    assert baked.stats["models"] == len(scene.models)
