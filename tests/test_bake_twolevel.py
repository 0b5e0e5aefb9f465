"""The two-level BVH (structure "bvh"): SAH build invariants, quantised boxes, the numpy walk
against brute force, the GLSL walk against the numpy walk, and incremental updates."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, BVHConfig, bake_scene
from hybrid_shadow_addon.core.bake.sah import build_sah, sah_cost
from hybrid_shadow_addon.core.bake.structures.blas import LEAF_FLAG, build_blas
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.bake import assert_equal_tracers, assert_report_covers, snapshot
from tests.helpers.rays import random_rays, terrain_rays
from tests.helpers.scenes import adversarial_scene, blob_model, plate_model, random_scene, terrain_model

pytestmark = [pytest.mark.gpu]

BVH = BakeConfig(structure="bvh")


def _check_trees(b, lo, hi, gs, gc):
    for g in range(len(gc)):
        ns, nc = b.node_start[g], b.node_count[g]
        items = []
        for i in range(ns, ns + nc):
            assert i < b.escape[i] <= ns + nc
            if b.leaf_count[i]:
                assert b.escape[i] == i + 1
                it = b.perm[b.leaf_start[i]:b.leaf_start[i] + b.leaf_count[i]]
                items += it.tolist()
                assert (b.node_min[i] <= lo[it].min(0)).all() and (b.node_max[i] >= hi[it].max(0)).all()
            else:
                kids = [i + 1, b.escape[i + 1]]
                assert b.escape[kids[1]] == b.escape[i]
                assert (b.node_min[i] <= b.node_min[kids].min(0)).all()
                assert (b.node_max[i] >= b.node_max[kids].max(0)).all()
        assert sorted(items) == list(range(gs[g], gs[g] + gc[g]))


@pytest.mark.parametrize("leaf", [1, 4])
@pytest.mark.parametrize("spatial_min", [0, 2, 64])
def test_sah_invariants(leaf, spatial_min):
    rng = np.random.default_rng(0)
    gc = np.array([1, 0, 2, 37, 500, 5, 300])
    gs = np.concatenate([[0], np.cumsum(gc)[:-1]])
    lo = rng.random((gc.sum(), 3)) * 10
    lo[gs[5]:gs[6]] = 3.0  # identical boxes: median split
    hi = lo + rng.random(lo.shape) * [5.0, 0.01, 0.01]  # long thin items
    b = build_sah(lo, hi, gs, gc, leaf_size=leaf, bins=8, sah_min=4, spatial_min=spatial_min)
    assert b.node_count[1] == 0
    _check_trees(b, lo, hi, gs, gc)


def test_sah_cost_by_hand_and_binned_below_morton_runs():
    """``sah_cost`` is the area-weighted count of inner nodes and leaf items over the root's
    area (checked node by node); on a terrain-like plate and a blob, the model trees binned at
    every level cost less than those split between runs of the Morton order alone."""
    rng = np.random.default_rng(3)
    models = [plate_model(40), blob_model(rng, 300)]
    for m in models:
        binned = sah_cost(build_blas([m], 2, spatial_min=8).build)[0]
        runs = sah_cost(build_blas([m], 2, spatial_min=0).build)[0]
        assert binned < runs
    b = build_blas(models, 2).build
    e = b.node_max.astype(np.float64) - b.node_min.astype(np.float64)
    area = e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]
    for g, got in enumerate(sah_cost(b, traverse=1.5, intersect=0.5)):
        s, c = b.node_start[g], b.node_count[g]
        want = sum((0.5 * b.leaf_count[i] if b.leaf_count[i] else 1.5) * area[i] for i in range(s, s + c)) / area[s]
        assert got == pytest.approx(want, rel=1e-9)


def test_sah_separates_long_thin_items_better_than_the_median():
    """Two bundles of long thin boxes: the root split separates the bundles."""
    rng = np.random.default_rng(1)
    n = 200
    lo = np.zeros((n, 3))
    lo[:, 1] = np.where(np.arange(n) < n // 4, 0.0, 10.0) + rng.random(n) * 0.1
    lo[:, 0] = rng.random(n) * 0.1
    hi = lo + [20.0, 0.05, 0.05]
    b = build_sah(lo, hi, [0], [n], leaf_size=1)
    # the left child of the root covers exactly one bundle
    assert b.node_max[1, 1] < 5.0 or b.node_min[1, 1] > 5.0


def test_blas_quantised_boxes_hold_their_triangles():
    rng = np.random.default_rng(2)
    models = [blob_model(rng, k) for k in (1, 3, 9, 200)] + [plate_model(6)]
    bl = build_blas(models, 2)
    for m, _model in enumerate(models):
        ns, nc = bl.node_start[m], bl.node_count[m]
        base, s = bl.base[m], 1.0 / bl.inv_s[m]
        for i in range(ns, ns + nc):
            n = bl.nodes[i]
            qlo = np.array([n[0] & 0xFFFF, n[0] >> 16, n[1] & 0xFFFF], np.float64)
            qhi = np.array([n[1] >> 16, n[2] & 0xFFFF, n[2] >> 16], np.float64)
            if n[3] & LEAF_FLAG:
                pay = int(n[3] & 0x7FFFFFFF)
                f, c = (pay >> 3) + int(bl.tri_start[m]), pay & 7
                flat = bl.tri4.reshape(-1)[(f * 4):(f * 4) + 9 * c].reshape(-1, 3)
                q = (flat.astype(np.float64) - base) / s
                assert (q >= qlo - 1e-9).all() and (q <= qhi + 1e-9).all()


@pytest.mark.parametrize("seed", range(3))
def test_random_scenes_bvh_equals_brute(seed):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n_inst=150)
    baked = bake_scene(scene, BVH)
    o, d, t = random_rays(rng, scene, 3000)
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert hit.any() and (~hit).any()


def test_adversarial_and_watertight():
    rng = np.random.default_rng(7)
    scene, o, d, t = adversarial_scene(rng)
    baked = bake_scene(scene, BVH)
    assert (trace_structured(baked, o, d, t) == trace_brute(scene, o, d, t)).all()
    plate = Scene(models=[plate_model(8)], instances=Instances(names=["p"]))
    xs = np.linspace(-1, 1, 9)[1:-1]
    X, Y = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], 1)
    o = np.concatenate([o, o + [0.125, 0, 0], o + [0.0625, 0.0625, 0]])
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    assert trace_structured(bake_scene(plate, BVH), o, d, np.inf).all()


def test_empty_and_far_from_origin():
    baked = bake_scene(Scene(), BVH)
    assert not trace_structured(baked, np.zeros((3, 3)), np.eye(3), np.inf).any()
    rng = np.random.default_rng(11)
    scene = random_scene(rng, n_inst=100, area=20)
    scene.instances.matrices[:, 0, 3] += 10000.0
    scene.instances.matrices[:, 1, 3] -= 7000.0
    scene.instances.set_matrices(slice(None), scene.instances.matrices.copy())
    baked = bake_scene(scene, BVH)
    assert np.allclose(baked.origin, (10000.0, -7000.0, 0.0), atol=64)
    o, d, t = random_rays(rng, scene, 2000)
    assert_equal_tracers(scene, baked, o, d, t)


def test_bvh_cost_is_logarithmic():
    scene = Scene(models=[terrain_model(158)], instances=Instances(names=["t"]))
    baked = bake_scene(scene, BVH)
    rng = np.random.default_rng(1)
    R = 200
    o, d = terrain_rays(rng, R, spread=0.2)
    stats = {}
    assert trace_structured(baked, o, d, np.inf, stats=stats).all()
    assert stats["iterations"] / R < 120 and stats["triangles"] / R < 40


def test_per_ray_stats_add_up_to_the_totals():
    """``stats["per_ray"]``: each ray's node steps and the per-tree counts sum to the totals,
    and the answers are those of a walk without them."""
    rng = np.random.default_rng(3)
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    quad = Model("quad", np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32), tri)
    v = rng.uniform(-0.5, 0.5, (60, 3)).astype(np.float32)
    blob = Model("blob", v, rng.integers(0, 60, (40, 3)))
    n = 30
    mats = np.tile(np.eye(4), (n, 1, 1))
    mats[:, :3, 3] = rng.uniform(-4, 4, (n, 3))
    scene = Scene(models=[quad, blob], instances=Instances(names=[f"i{k}" for k in range(n)],
                                                           model_ids=np.arange(n) % 2, matrices=mats))
    baked = bake_scene(scene, BVH)
    R = 500
    o = rng.uniform(-5, 5, (R, 3))
    d = rng.normal(size=(R, 3))
    plain, stats = {}, {"per_ray": True}
    occ = trace_structured(baked, o, d, 20.0, stats=plain)
    assert (trace_structured(baked, o, d, 20.0, stats=stats) == occ).all()
    assert 0 < occ.sum() < R
    assert stats["ray_iterations"].shape == (R,)
    assert int(stats["ray_iterations"].sum()) == stats["iterations"] == plain["iterations"]
    assert sum(stats["tree_nodes"].values()) == stats["bvh_nodes"] > 0
    assert sum(stats["tree_triangles"].values()) == stats["triangles"] > 0
    assert len(stats["tree_nodes"]) == 2


def test_move_instances_refits_and_reports_rows():
    rng = np.random.default_rng(0)
    scene = random_scene(rng, n_inst=250, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, BVH)
    for step in range(4):
        before = snapshot(baked)
        idx = rng.choice(len(scene.instances), 12, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :3, 3] += rng.normal(scale=[3, 3, 0.5], size=(12, 3))
        if step == 2:
            M[:, :3, :3] *= rng.uniform(0.5, 3.0, (12, 1, 1))
        scene.instances.set_matrices(idx, M)
        rep = baked.update_instances(scene, idx)
        assert_report_covers(baked, before, rep)
        assert rep.objects == 12
        o, d, t = random_rays(rng, scene, 600)
        assert_equal_tracers(scene, baked, o, d, t)
    o, d, t = random_rays(rng, scene, 1500)
    assert (trace_structured(baked, o, d, t) == trace_structured(bake_scene(scene, BVH), o, d, t)).all()


def test_move_far_rebuilds_top_level_and_caster_flag():
    rng = np.random.default_rng(4)
    scene = random_scene(rng, n_inst=120, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, BVH)
    before = snapshot(baked)
    M = scene.instances.matrices[:3].copy()
    M[:, :3, 3] += [500.0, 0.0, 0.0]  # outside the top level's quantisation frame
    scene.instances.set_matrices(np.arange(3), M)
    rep = baked.update_instances(scene, np.arange(3))
    assert rep.regrid and rep.uniforms_changed
    assert_report_covers(baked, before, rep)
    scene.instances.casts_shadow[5:9] = False
    rep = baked.update_instances(scene, np.arange(5, 9))
    assert rep.regrid
    o, d, t = random_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)


def test_update_model_rebuilds_that_model_only():
    rng = np.random.default_rng(5)
    scene = random_scene(rng, n_inst=100, spheres=0.0, tri_counts=(4, 30))
    baked = bake_scene(scene, BVH)
    # smaller mesh: in place; bigger: appended; a new model
    for n_tri in (2, 400):
        scene.models[0] = blob_model(rng, n_tri, size=1.5)
        before = snapshot(baked)
        rep = baked.update_model(scene, 0)
        assert_report_covers(baked, before, rep)
        o, d, t = random_rays(rng, scene, 1000)
        assert_equal_tracers(scene, baked, o, d, t)
    scene.models.append(blob_model(rng, 50, name="new"))
    baked.update_model(scene, len(scene.models) - 1)
    ids = scene.instances.model_ids.copy()
    ids[:10] = len(scene.models) - 1
    scene.instances.model_ids[:] = ids
    baked.update_instances(scene, np.arange(10))
    o, d, t = random_rays(rng, scene, 1000)
    assert_equal_tracers(scene, baked, o, d, t)


def test_structure_setting_and_config():
    assert Settings(structure="bvh").structure == "bvh"
    with pytest.raises(ValueError, match="structure"):
        Settings(structure="octree")
    with pytest.raises(ValueError, match="structure"):
        BakeConfig(structure="octree")
    with pytest.raises(ValueError):
        BakeConfig(structure="bvh", bvh=BVHConfig(leaf_size=5))


# ------------------------------------------------------------------------------------ GLSL --
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("leaf", [1, 2, 4])
def test_glsl_bvh_matches_numpy(gl_ctx, seed, leaf):
    from tests.helpers.glsl import gl_trace

    rng = np.random.default_rng(100 + seed)
    scene = random_scene(rng, n_inst=300, spheres=0.3)
    baked = bake_scene(scene, BakeConfig(structure="bvh", bvh=BVHConfig(leaf_size=leaf)))
    o, d, t = random_rays(rng, scene, 20000)
    ref = trace_structured(baked, o, d, t)
    gl = gl_trace(gl_ctx, baked, o, d, t)
    assert ref.any() and (~ref).any()
    assert (ref == gl).mean() >= 0.999, f"{int((ref != gl).sum())} rays differ"
    grid = trace_structured(bake_scene(scene), o, d, t)
    assert (grid == ref).mean() >= 0.999


def test_glsl_bvh_spheres_only_and_meshes_only(gl_ctx):
    from tests.helpers.glsl import gl_trace

    for spheres in (0.0, 1.0):
        rng = np.random.default_rng(11)
        scene = random_scene(rng, n_inst=120, spheres=spheres)
        baked = bake_scene(scene, BVH)
        assert ("HS_HAS_SPHERES" in baked.defines) == (spheres > 0)
        assert ("HS_HAS_MESHES" in baked.defines) == (spheres < 1)
        o, d, t = random_rays(rng, scene, 4000)
        assert (trace_structured(baked, o, d, t) == gl_trace(gl_ctx, baked, o, d, t)).mean() >= 0.999


@pytest.mark.parametrize("levels,order", [(2, "distance"), (2, "far"), (2, "tree"), (3, "distance")])
def test_wide_walk_answers_as_the_binary_walk_with_fewer_fetches(levels, order):
    """The trees walked as wide nodes with a stack (``oracle/tracer/wide.py``, the projection
    of ``profile_traversal.py --wide``): meshes, spheres and far misses give the binary walk's
    answers (and brute force's); a terrain's rays take fewer than half the dependent fetches."""
    from hybrid_shadow_addon.core.oracle.tracer.wide import trace_wide

    rng = np.random.default_rng(5)
    scene = random_scene(rng, n_inst=150)
    baked = bake_scene(scene, BVH)
    o, d, t = random_rays(rng, scene, 2000)
    occ, fetches, visits = trace_wide(baked, o, d, t, levels, order)
    assert (occ == trace_brute(scene, o, d, t)).all() and occ.any() and (~occ).any()
    assert (fetches >= visits).all() and visits.max() > 0
    terrain = bake_scene(Scene(models=[terrain_model(158)], instances=Instances(names=["t"])), BVH)
    o, d = terrain_rays(rng, 300)
    stats = {"per_ray": True}
    binary = trace_structured(terrain, o, d, np.inf, stats=stats)
    occ, fetches, _ = trace_wide(terrain, o, d, np.inf, levels, order)
    assert (occ == binary).all() and binary.mean() > 0.5
    assert fetches.sum() * 2 < stats["ray_fetches"].sum()


def test_wide_walk_rejects_an_unknown_order():
    from hybrid_shadow_addon.core.oracle.tracer.wide import trace_wide

    baked = bake_scene(Scene(), BVH)
    with pytest.raises(ValueError, match="order must be one of"):
        trace_wide(baked, np.zeros((1, 3)), np.eye(3)[:1], np.inf, 2, "random")
