"""Grid, texture packing and layout invariants."""
import numpy as np

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.bake.grid import MARGIN_CELLS, place, plan_grid
from hybrid_shadow_addon.core.bake.textures import MAX_TEX_SIZE, OBJECT_TEXELS
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from tests.helpers.rays import random_rays
from tests.helpers.scenes import adversarial_scene, random_scene


def _node_lists(baked):
    g = baked.textures["grid"].linear()
    idx = baked.textures["grid_index"].linear()
    return {n: idx[g[n, 0]:g[n, 0] + g[n, 1], 0].astype(int).tolist() for n in range(baked.accel.layout.n_nodes)
            if g[n, 1]}


def test_every_caster_in_exactly_one_node_at_its_lowest_level():
    rng = np.random.default_rng(1)
    scene, *_ = adversarial_scene(rng)
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=1.0)))
    lay = baked.accel.layout
    lists = _node_lists(baked)
    seen = np.concatenate([np.array(v) for v in lists.values()])
    casters = np.nonzero(scene.instances.casts_shadow)[0]
    assert sorted(seen.tolist()) == casters.tolist()  # nothing dropped, nothing twice
    c, r = scene.instance_spheres()
    grid = baked.textures["grid"].linear()
    for node, objs in lists.items():
        assert node != lay.outside_node
        lvl = int(np.searchsorted(lay.level_offset, node, side="right") - 1)
        s = lay.node_sizes[lvl]
        nx = lay.dims[lvl][0]
        ix, iy = (node - lay.level_offset[lvl]) % nx, (node - lay.level_offset[lvl]) // nx
        lo = lay.origin + s * np.array([ix, iy])
        objs = np.array(objs)
        # sphere inside the node rectangle
        assert (c[objs, :2] - r[objs, None] >= lo - 1e-9).all()
        assert (c[objs, :2] + r[objs, None] <= lo + s + 1e-9).all()
        # ... and not inside a node of the level below (with the margin): it had to move up
        if lvl > 0:
            s0 = s / 2
            m = r[objs] + s0 * MARGIN_CELLS
            p = c[objs, :2] - lay.origin
            fits = (np.floor((p - m[:, None]) / s0) == np.floor((p + m[:, None]) / s0)).all(axis=1)
            assert not fits.any()
        # max height = highest sphere top (rounded up)
        h = grid[node, 2:3].view(np.float32)[0]
        top = (c[objs, 2] + r[objs]).max()
        assert h >= top and h <= top + 1e-3 * (1 + abs(top))
    assert baked.uniforms["hs_scene_max_height"] >= (c[:, 2] + r).max()


def test_grid_fits_scene_and_stats():
    rng = np.random.default_rng(2)
    scene = random_scene(rng, n_inst=400, area=500)
    baked = bake_scene(scene, BakeConfig(structure="grid"))
    lay = baked.accel.layout
    c, r = scene.instance_spheres()
    cs = scene.instances.casts_shadow
    lo = (c[cs, :2] - r[cs, None]).min(0)
    hi = (c[cs, :2] + r[cs, None]).max(0)
    top = lay.node_sizes[-1]
    assert (lay.origin <= lo).all() and (lay.origin + top >= hi).all()
    assert top < 4 * (hi - lo).max()  # bounds fit the scene (no fixed 2048 m square)
    assert tuple(lay.dims[-1]) == (1, 1)
    st = baked.stats
    assert st["casters"] == cs.sum() and st["outside_objects"] == 0
    assert set(st["bytes"]) == {"grid", "grid_index", "object", "model", "bvh", "tri"}
    assert sum(st["objects_per_level"]) == cs.sum()
    for _name, v in baked.defines.items():
        assert isinstance(v, (int, str))
    assert baked.defines["HS_GRID_LEVELS"] == lay.levels


def test_nodes_at_agrees_with_place():
    """``GridLayout.nodes_at`` of a small sphere's centre, at the level ``place`` chose, is the node
    ``place`` put it in; a point off the grid rectangle (or NaN) is -1 at every level."""
    rng = np.random.default_rng(7)
    n = 3000
    c = np.column_stack([rng.uniform(-50, 150, n), rng.uniform(-20, 80, n), rng.uniform(0, 5, n)])
    r = rng.uniform(1e-4, 0.3, n)
    lay = plan_grid(c, r, base_node_size=1.0)
    node = place(lay, c, r)
    assert (node != lay.outside_node).all()
    lvl = lay.node_level(node)
    assert (lvl == 0).mean() > 0.5 and lvl.max() > 0
    at = lay.nodes_at(c[:, :2])
    assert at.shape == (lay.levels, n) and at.dtype == np.int64
    assert (at[lvl, np.arange(n)] == node).all()
    for level in range(lay.levels):  # the centre is inside every level, in that level's id range
        assert (at[level] >= lay.level_offset[level]).all()
        assert (at[level] < lay.level_offset[level] + lay.dims[level].prod()).all()
    off = np.array([[lay.origin[0] - 1.0, lay.origin[1] + 1.0], [lay.origin[0] + 1e6, lay.origin[1] + 1.0],
                    [lay.origin[0] + 1.0, lay.origin[1] - 1e-9], [np.nan, 0.0]])
    assert (lay.nodes_at(off) == -1).all()
    # through a bake far from world zero: the layout is in bake space (world - origin)
    tet = Model("tet", [(0, 0, 0), (0.2, 0, 0), (0, 0.2, 0), (0, 0, 0.2)], [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)])
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, 3] = c + (2e5, -3e5, 0)
    scene = Scene(models=[tet],
                  instances=Instances(names=[f"t{i}" for i in range(n)], model_ids=np.zeros(n), matrices=m))
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=1.0)))
    assert np.abs(baked.origin).max() > 0
    wc, _ = scene.instance_spheres()
    held = baked.accel.instances.node
    at = baked.accel.layout.nodes_at(wc[:, :2] - baked.origin[:2])
    assert (at[baked.accel.layout.node_level(held), np.arange(n)] == held).all()
    assert (baked.accel.grid.count[held] > 0).all()


def test_texture_sizes_and_layers():
    """A narrow texture width forces several layers; the tracer reads across layer borders."""
    rng = np.random.default_rng(3)
    big = Model("big", rng.normal(size=(3 * 23000, 3)), np.arange(3 * 23000).reshape(-1, 3))
    n = 40
    M = np.tile(np.eye(4), (n, 1, 1))
    M[:, :2, 3] = rng.uniform(-30, 30, (n, 2))
    M[:, :3, :3] *= 0.5
    scene = Scene(models=[big], instances=Instances(names=[f"o{i}" for i in range(n)], matrices=M))
    cfg = BakeConfig(structure="grid", tex_width=4)
    baked = bake_scene(scene, cfg)
    tri = baked.textures["tri"]
    assert tri.layers >= 2 and tri.height == MAX_TEX_SIZE
    for tex in baked.textures.values():
        assert tex.width == 4 and tex.height <= MAX_TEX_SIZE
        assert tex.data.dtype in (np.float32, np.uint32) and 1 <= tex.components <= 4
    # object texels: rows of the inverse world matrix, then the world sphere
    rec = baked.textures["object"].records(OBJECT_TEXELS)
    assert np.allclose(rec[:n, 0:12].reshape(n, 3, 4), scene.instances.inverse[:, :3, :], rtol=1e-6)
    o, d, t = random_rays(rng, scene, 150)
    a = trace_structured(baked, o, d, t)
    b = trace_structured(bake_scene(scene, BakeConfig(structure="grid")), o, d, t)
    assert (a == b).all()


def test_crowded_node_thousands_of_objects():
    rng = np.random.default_rng(4)
    n = 5000
    M = np.tile(np.eye(4), (n, 1, 1))
    M[:, :3, 3] = rng.uniform([0, 0, 0], [2, 2, 2], (n, 3))
    M[:, :3, :3] *= 0.01
    sphere = rng.random(n) < 0.5
    model = Model("t", [[0, 0, 0], [1, 0, 0], [0, 1, 1]], [[0, 1, 2]])
    scene = Scene(models=[model], instances=Instances(names=[f"o{i}" for i in range(n)], matrices=M, sphere=sphere))
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=64.0)))
    assert baked.stats["max_objects_per_node"] >= 3000
    o = rng.uniform(-1, 3, (400, 3))
    d = rng.normal(size=(400, 3))
    assert (trace_structured(baked, o, d, np.inf) == trace_brute(scene, o, d, np.inf)).all()
