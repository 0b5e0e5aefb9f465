"""Crowded grid nodes: object BVHs over the node's objects ("teapot in a stadium").

Nodes with more than ``GridConfig.object_bvh_threshold`` objects carry a stackless object BVH in
the [bvh] texture (grid texel .w = root + 1), walked instead of the flat list. Checked here:
structured tracer == brute force (fresh bakes and after incremental moves that rebuild, create
and drop object BVHs), GLSL == numpy on such scenes, and the per-ray work in a crowded node being
logarithmic-ish instead of linear.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from tests.helpers.bake import assert_equal_tracers, assert_report_covers, snapshot
from tests.helpers.rays import random_rays
from tests.helpers.scenes import blob_model, plate_model, random_matrices

pytestmark = [pytest.mark.gpu]


def tiny_model(name="tiny", s=0.03):
    """A closed tetrahedron-ish cube corner set: 4 triangles, ~s wide."""
    v = np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [0, 0, s]], float) - s / 4
    return Model(name, v, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))


def crowded_scene(rng, n_crowd=3000, clusters=((0.0, 0.0),), n_far=80, far=100.0, spheres=0.4):
    """``n_crowd`` tiny meshes/spheres in 1 m clouds at ``clusters`` (x, y), random rotations and
    some negative scales, plus ``n_far`` unit boxes spread over ``far`` m (big grid nodes)."""
    models = [tiny_model(), blob_model(rng, 6, "blob6", size=0.02), plate_model(2), blob_model(rng, 20)]
    parts = []
    per = n_crowd // len(clusters)
    for k, (cx, cy) in enumerate(clusters):
        M = random_matrices(rng, per, area=0.5, zrange=(0.05, 0.8), scale=(0.6, 1.2))
        M[:, 0, 3] += cx
        M[:, 1, 3] += cy
        mid = rng.integers(0, 2, per)
        sph = rng.random(per) < spheres
        parts.append(Instances(names=[f"c{k}_{i}" for i in range(per)], model_ids=mid, matrices=M, sphere=sph))
    Mf = np.tile(np.eye(4), (n_far, 1, 1))
    Mf[:, :2, 3] = rng.uniform(-far, far, (n_far, 2))
    Mf[:, 2, 3] = 0.5
    Mf[:, :3, :3] *= 0.5
    parts.append(Instances(names=[f"f{i}" for i in range(n_far)], model_ids=np.full(n_far, 2), matrices=Mf))
    return Scene(models=models, instances=Instances.concatenate(parts))


def crowd_rays(rng, scene, n, clusters=((0.0, 0.0),)):
    """Shadow-like rays: half start inside the clouds (towards a sun or a nearby point), half
    are the generic mix (aimed at instance centres, random, axis-aligned)."""
    k = n // 2
    o1, d1, t1 = random_rays(rng, scene, n - k)
    c = np.array(clusters, float)[rng.integers(0, len(clusters), k)]
    o2 = np.column_stack([c + rng.uniform(-0.6, 0.6, (k, 2)), rng.uniform(0.0, 0.9, k)])
    d2 = rng.normal(size=(k, 3))
    d2[:, 2] = np.abs(d2[:, 2]) + 0.2
    axis = rng.random(k) < 0.2
    d2[axis] = [0.0, 0.0, 1.0]
    t2 = rng.choice([np.inf, 0.3, 2.0], k)
    return np.concatenate([o1, o2]), np.concatenate([d1, d2]), np.concatenate([t1, t2])


def _obvh_nodes(baked):
    g = baked.textures["grid"].linear()
    return np.nonzero(g[:, 3])[0]


def _check_tree(baked, node):
    """The object BVH of ``node`` covers exactly the node's entries, leaf ranges in order, and
    every leaf box holds its objects' stored spheres."""
    g = baked.textures["grid"].linear()[node]
    bvh = baked.textures["bvh"].records(2)
    obj = baked.textures["object"].records(4)
    root = int(g[3]) - 1
    end = int(bvh[root, 3])
    leaves = [(int(bvh[i, 7]) >> 3, int(bvh[i, 7]) & 7) for i in range(root, end) if bvh[i, 7]]
    starts = [a for a, _ in leaves]
    assert starts == sorted(starts) and starts[0] == g[0]
    assert sum(c for _, c in leaves) == g[1] and starts[-1] + leaves[-1][1] == g[0] + g[1]
    idx = baked.textures["grid_index"].linear()
    for i in range(root, end):
        if not bvh[i, 7]:
            continue
        a, c = int(bvh[i, 7]) >> 3, int(bvh[i, 7]) & 7
        o = obj[idx[a:a + c, 0].astype(int)]
        lo, hi = bvh[i, 0:3].view(np.float32), bvh[i, 4:7].view(np.float32)
        assert (o[:, 12:15] - o[:, 15:16] >= lo).all() and (o[:, 12:15] + o[:, 15:16] <= hi).all()


# ------------------------------------------------------------------------------------------
def test_crowded_node_gets_object_bvh_and_matches_brute():
    rng = np.random.default_rng(0)
    clusters = ((0.0, 0.0), (30.0, -20.0))
    scene = crowded_scene(rng, 4000, clusters)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    st = baked.stats
    assert st["max_objects_per_node"] >= 1000 and st["object_bvh_nodes"] >= 2
    assert st["object_bvh_objects"] >= 3900
    for n in _obvh_nodes(baked):
        _check_tree(baked, n)
        assert baked.textures["grid"].linear()[n, 1] > baked.config.grid.object_bvh_threshold
    o, d, t = crowd_rays(rng, scene, 2500, clusters)
    hit = assert_equal_tracers(scene, baked, o, d, t)
    assert 0.05 < hit.mean() < 0.95
    # the flat-list bake agrees ray for ray
    flat = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(object_bvh_threshold=10 ** 9)))
    assert flat.stats["object_bvh_nodes"] == 0
    assert (trace_structured(flat, o, d, t) == hit).all()


@pytest.mark.parametrize("leaf, threshold", [(1, 8), (7, 32), (3, 200)])
def test_leaf_sizes_and_thresholds(leaf, threshold):
    rng = np.random.default_rng(10 + leaf)
    scene = crowded_scene(rng, 1500)
    grid = GridConfig(object_leaf_size=leaf, object_bvh_threshold=threshold)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=grid))
    counts = baked.accel.grid.count
    assert ((counts > threshold) == (baked.accel.grid.obvh >= 0)).all()
    for n in _obvh_nodes(baked):
        _check_tree(baked, n)
    o, d, t = crowd_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)


def test_incremental_moves_rebuild_object_bvhs():
    rng = np.random.default_rng(1)
    scene = crowded_scene(rng, 2500)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    n = len(scene.instances)
    crowd = np.nonzero(baked.accel.grid.obvh[baked.accel.instances.node] >= 0)[0]
    assert crowd.size >= 1000
    steps = [
        ("jiggle inside the crowd", rng.choice(crowd, 40, replace=False),
         lambda M: M[:, :3, 3] + rng.normal(scale=0.05, size=(len(M), 3))),
        ("crowd objects leave far away", rng.choice(crowd, 60, replace=False),
         lambda M: M[:, :3, 3] + [40.0, 25.0, 0.0]),
        ("far boxes join the crowd", np.arange(n - 60, n - 30),
         lambda M: np.column_stack([rng.uniform(-0.3, 0.3, (len(M), 2)), np.full(len(M), 0.4)])),
        ("a new crowd forms", rng.choice(crowd, 400, replace=False),
         lambda M: np.column_stack([rng.uniform(-40.3, -39.7, (len(M), 2)), rng.uniform(0.1, 0.6, len(M))])),
    ]
    for name, idx, new_t in steps:
        before = snapshot(baked)
        M = scene.instances.matrices[idx].copy()
        M[:, :3, 3] = new_t(M)
        scene.instances.set_matrices(idx, M)
        rep = baked.update_instances(scene, idx)
        assert not rep.regrid, name
        assert_report_covers(baked, before, rep)
        for nd in _obvh_nodes(baked):
            _check_tree(baked, nd)
        o, d, t = crowd_rays(rng, scene, 1200, ((0.0, 0.0), (-40.0, -40.0)))
        assert_equal_tracers(scene, baked, o, d, t)
    assert baked.stats["object_bvh_nodes"] >= 2  # the new crowd got its own tree
    # the remaining crowd thins out below the threshold: back to a flat list
    idx = np.nonzero(baked.accel.instances.node == baked.accel.instances.node[crowd[0]])[0]
    node = baked.accel.instances.node[crowd[0]]
    assert baked.accel.grid.obvh[node] >= 0
    go = idx[: idx.size - 20]
    M = scene.instances.matrices[go].copy()
    M[:, 0, 3] += rng.uniform(-60, 60, go.size)
    M[:, 1, 3] += rng.uniform(-60, 60, go.size)
    scene.instances.set_matrices(go, M)
    before = snapshot(baked)
    rep = baked.update_instances(scene, go)
    if not rep.regrid:
        assert_report_covers(baked, before, rep)
        assert baked.accel.grid.count[node] <= 32 and baked.accel.grid.obvh[node] == -1
        assert baked.textures["grid"].linear()[node, 3] == 0
    o, d, t = crowd_rays(rng, scene, 1200, ((0.0, 0.0), (-40.0, -40.0)))
    a = assert_equal_tracers(scene, baked, o, d, t)
    assert (a == trace_structured(bake_scene(scene, BakeConfig(structure="grid")), o, d, t)).all()


def test_overflow_relocation_and_regrid_with_object_bvhs():
    rng = np.random.default_rng(2)
    scene = crowded_scene(rng, 1200, n_far=600)
    grid = GridConfig(index_reserve=1.0, outside_rebake_fraction=0.5)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=grid))
    n = len(scene.instances)
    node = int(np.argmax(baked.accel.grid.count))
    # pile far boxes into the crowded node: its list overflows -> tail, the tree moves too
    # (each box takes the sphere centre of a member, radius a hair bigger: same node)
    far = np.arange(n - 500, n)
    members = rng.choice(np.nonzero(baked.accel.instances.node == node)[0], far.size)
    plate_r = scene.models[2].sphere_radius
    M = np.tile(np.eye(4), (far.size, 1, 1))
    M[:, :3, :3] *= (baked.accel.instances.radius[members] * 1.001 / plate_r)[:, None, None]
    M[:, :3, 3] = baked.accel.instances.center[members] + baked.origin - M[:, :3, :3] @ scene.models[2].sphere_center
    scene.instances.set_matrices(far, M)
    tail0, bvh0, root0 = baked.accel.grid.index_tail, baked.accel.tex.bvh_tail, baked.accel.grid.obvh[node]
    before = snapshot(baked)
    rep = baked.update_instances(scene, far)
    assert not rep.regrid and baked.accel.grid.index_tail > tail0
    assert baked.accel.tex.bvh_tail > bvh0 and baked.accel.grid.obvh[node] != root0
    assert_report_covers(baked, before, rep)
    _check_tree(baked, node)
    o, d, t = crowd_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)
    # many updates until the index tail runs out: regrid (object BVHs rebuilt, region reclaimed)
    regrid = False
    for _ in range(40):
        idx = rng.choice(n, 200, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :2, 3] = rng.uniform(-0.5, 0.5, (idx.size, 2)) + rng.choice([0.0, 50.0], (idx.size, 1))
        scene.instances.set_matrices(idx, M)
        before = snapshot(baked)
        rep = baked.update_instances(scene, idx)
        assert_report_covers(baked, before, rep)
        if rep.regrid:
            regrid = True
            ends = baked.accel.models.node_start + baked.accel.models.node_cap
            assert baked.accel.grid.bvh_range[0] == ends.max()
            break
    assert regrid
    for nd in _obvh_nodes(baked):
        _check_tree(baked, nd)
    o, d, t = crowd_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)


def test_update_model_in_crowded_node():
    rng = np.random.default_rng(3)
    scene = crowded_scene(rng, 1500)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    scene.models[0] = blob_model(rng, 10, "bigger tiny", size=0.05)  # spheres grow: trees rebuilt
    before = snapshot(baked)
    rep = baked.update_model(scene, 0)
    assert_report_covers(baked, before, rep)
    for nd in _obvh_nodes(baked):
        _check_tree(baked, nd)
    o, d, t = crowd_rays(rng, scene, 1500)
    assert_equal_tracers(scene, baked, o, d, t)


def _cloud_scene(rng, n):
    """``n`` tiny spheres on a jittered 1 m x 1 m layer in ONE grid node (far boxes make the
    nodes big), radius shrinking with the spacing so a vertical ray meets O(1) of them."""
    side = int(np.ceil(np.sqrt(n)))
    g = (np.arange(side) + 0.5) / side - 0.5
    X, Y = np.meshgrid(g, g)
    p = np.column_stack([X.ravel(), Y.ravel()])[:n] + rng.uniform(-0.2, 0.2, (n, 2)) / side
    M = np.tile(np.eye(4), (n + 40, 1, 1))
    M[:n, :3, :3] *= 0.3 / side
    M[:n, :2, 3] = p
    M[:n, 2, 3] = 0.5 + rng.uniform(-0.05, 0.05, n)
    M[n:, :2, 3] = rng.uniform(-100, 100, (40, 2))
    M[n:, :2, 3] += np.sign(M[n:, :2, 3]) * 5
    ball = Model("ball", [[-1, -1, -1], [1, 1, 1], [1, -1, 1]], [[0, 1, 2]])
    inst = Instances(names=[f"o{i}" for i in range(n + 40)], model_ids=np.zeros(n + 40), matrices=M,
                     sphere=np.ones(n + 40, bool))
    return Scene(models=[ball], instances=inst)


def test_objects_per_ray_in_a_crowded_node_is_logarithmic():
    rng = np.random.default_rng(4)
    per_ray = {}
    for n in (512, 8192):
        scene = _cloud_scene(rng, n)
        tree = bake_scene(scene, BakeConfig(structure="grid"))
        flat = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(object_bvh_threshold=10 ** 9)))
        assert tree.stats["max_objects_per_node"] >= n and tree.stats["object_bvh_nodes"] >= 1
        k = 400
        o = np.column_stack([rng.uniform(-0.5, 0.5, (k, 2)), np.full(k, 2.0)])
        d = np.column_stack([rng.normal(scale=0.05, size=(k, 2)), -np.ones(k)])
        st_t, st_f = {}, {}
        a = trace_structured(tree, o, d, np.inf, stats=st_t)
        b = trace_structured(flat, o, d, np.inf, stats=st_f)
        assert (a == b).all() and a.any() and (~a).any()
        assert (a == trace_brute(scene, o, d, np.inf)).all()
        assert st_f["objects"] >= 0.95 * k * n  # flat: every object of the node, per ray
        per_ray[n] = (st_t["objects"] / k, st_t["obvh_nodes"] / k)
        assert per_ray[n][0] < 24, per_ray  # a few leaves of pre-tests per ray
        assert per_ray[n][1] < 8 * np.log2(n), per_ray  # tree nodes visited ~ depth
    # 16x the objects: far less than 16x the work (logarithmic-ish)
    assert per_ray[8192][0] < 2.5 * per_ray[512][0] + 2, per_ray
    assert per_ray[8192][1] < 2.5 * per_ray[512][1], per_ray


def test_glsl_matches_structured_on_crowded_scenes(gl_ctx):
    from tests.helpers import glsl as tg

    rng = np.random.default_rng(5)
    clusters = ((0.0, 0.0), (20.0, 10.0))
    scene = crowded_scene(rng, 3000, clusters)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(object_leaf_size=3)))
    assert baked.stats["object_bvh_nodes"] >= 2
    o, d, t = crowd_rays(rng, scene, 12000, clusters)
    ref = trace_structured(baked, o, d, t)
    gl = tg.gl_trace(gl_ctx, baked, o, d, t)
    assert ref.any() and (~ref).any()
    assert (ref == gl).mean() >= 0.999, f"{int((ref != gl).sum())} rays differ"
    # after incremental moves (trees rebuilt in place and at the tail)
    idx = rng.choice(len(scene.instances) - 80, 300, replace=False)
    M = scene.instances.matrices[idx].copy()
    M[:, :3, 3] += rng.normal(scale=[0.2, 0.2, 0.05], size=(idx.size, 3))
    M[:100, :2, 3] = rng.uniform(19.6, 20.4, (100, 2))
    scene.instances.set_matrices(idx, M)
    rep = baked.update_instances(scene, idx)
    assert not rep.regrid
    ref = trace_structured(baked, o, d, t)
    gl = tg.gl_trace(gl_ctx, baked, o, d, t)
    assert (ref == gl).mean() >= 0.999, f"{int((ref != gl).sum())} rays differ"
    sub = rng.choice(len(o), 1500, replace=False)
    assert (ref[sub] == trace_brute(scene, o[sub], d[sub], t[sub])).all()
