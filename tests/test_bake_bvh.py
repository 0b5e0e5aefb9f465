"""Per-model BVH: structure invariants and logarithmic traversal cost."""
import numpy as np

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.bake.bvh import build_bvhs
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from tests.helpers.scenes import blob_model, plate_model, terrain_model


def test_bvh_invariants():
    rng = np.random.default_rng(0)
    models = ([blob_model(rng, k) for k in (1, 2, 3, 4, 5, 17, 100, 1000)]
              + [Model("empty", np.zeros((0, 3)), np.zeros((0, 3)))])
    b = build_bvhs(models)
    assert b.node_count[-1] == 0 and b.tri_count[-1] == 0
    for m in range(len(models) - 1):
        ns, nc = b.node_start[m], b.node_count[m]
        ts, tc = b.tri_start[m], b.tri_count[m]
        assert nc == 2 * (-(-tc // 4)) - 1
        # every original triangle exactly once
        assert sorted(b.tri_src[ts:ts + tc].tolist()) == list(range(tc))
        assert np.array_equal(b.tris[ts:ts + tc], models[m].vertices[models[m].triangles][b.tri_src[ts:ts + tc]])
        assert b.escape[ns] == ns + nc  # root escapes past the tree
        for i in range(ns, ns + nc):
            assert i < b.escape[i] <= ns + nc
            if b.leaf_count[i]:
                assert b.escape[i] == i + 1 and 1 <= b.leaf_count[i] <= 4
                v = b.tris[b.leaf_start[i]:b.leaf_start[i] + b.leaf_count[i]].reshape(-1, 3)
            else:
                # children: i + 1 and escape of i + 1; boxes nest
                kids = [i + 1, b.escape[i + 1]]
                assert b.escape[kids[1]] == b.escape[i]
                v = np.concatenate([b.node_min[kids], b.node_max[kids]])
            assert (b.node_min[i] < v.min(0)).all() or (b.node_min[i] <= v.min(0)).all()
            assert (b.node_max[i] >= v.max(0)).all() and (b.node_min[i] <= v.min(0)).all()
    assert b.depth[7] == int(np.ceil(np.log2(250)))


def test_bvh_cost_is_logarithmic():
    """A 50k-triangle mesh: a ray tests a few dozen nodes, not 50k triangles."""
    model = terrain_model(158)  # (2 * 158^2 = 49928 triangles)
    assert model.triangle_count > 49000
    scene = Scene(models=[model], instances=Instances(names=["t"]))
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    rng = np.random.default_rng(1)
    R = 200
    o = np.stack([rng.uniform(-9, 9, R), rng.uniform(-9, 9, R), np.full(R, 3.0)], 1)
    d = np.stack([rng.normal(scale=0.2, size=R), rng.normal(scale=0.2, size=R), -np.ones(R)], 1)
    stats = {}
    hit = trace_structured(baked, o, d, np.inf, stats=stats)
    assert hit.all()
    assert stats["bvh_nodes"] / R < 200 and stats["triangles"] / R < 64
    o2 = o[:20].copy()
    assert (trace_brute(scene, o2, d[:20], np.inf) == hit[:20]).all()


def test_shared_edges_watertight():
    """Rays through shared edges and vertices of a tessellated plate never slip through."""
    scene = Scene(models=[plate_model(8)], instances=Instances(names=["p"]))
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    xs = np.linspace(-1, 1, 9)[1:-1]
    X, Y = np.meshgrid(xs, xs)
    o = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], 1)
    o = np.concatenate([o, o + [0.125, 0, 0], o + [0.0625, 0.0625, 0]])
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    assert trace_structured(baked, o, d, np.inf).all()
    assert trace_brute(scene, o, d, np.inf).all()
