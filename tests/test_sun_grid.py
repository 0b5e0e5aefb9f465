"""A hard sun's light-space grid (``core/bake/sungrid.py``, ``shaders/common/scene_sungrid.glsl``).

1. The bake is conservative: for suns from many directions (straight down, along the axes,
   grazing) and rays from random origins and from origins on cell borders, the numpy mirror of
   the lookup (``tracer.trace_sun_grid``) finds every caster that a brute-force test of all
   casters hits, with the same float32 triangle and sphere tests.
2. On the GPU the grid's masks equal the two-level BVH's on every test scene, and the mirror's
   answer on the frame's own rays.
3. It is used only where it applies (hard suns on the BVH, no alpha-cut casters, the setting on,
   a grid that fits), and follows the scene and the sun: a moved caster or a turned sun rebuilds it.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import sungrid
from hybrid_shadow_addon.core.bake.baked import choose_origin
from hybrid_shadow_addon.core.bake.textures import f32_up
from hybrid_shadow_addon.core.oracle import tracer
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings

from conftest import TEST_SCENES

W, H = 160, 120
DIRECTIONS = [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.3, -0.2, 0.93),
              (0.97, 0.2, 0.12), (-0.6, 0.7, 0.02), (0.0, 0.8, 0.6)]


def brute(wc, scene, origin, o, d, tmax):
    """Occlusion by every caster of ``wc`` (the mirror's float32 tests, no grid)."""
    o = o.astype(np.float32)
    d = d.astype(np.float32)
    n = len(o)
    occ = np.zeros(n, bool)
    tm = np.minimum(np.broadcast_to(np.asarray(tmax, np.float64), (n,)), 3.0e38).astype(np.float32)
    T = len(wc.tris)
    if T:
        for r0 in range(0, n, max(1, 2_000_000 // T)):
            r = np.arange(r0, min(n, r0 + max(1, 2_000_000 // T)))
            ray = np.repeat(r, T)
            t = np.tile(np.arange(T), len(r))
            hit = tracer.woop_hit(o[ray], tracer.woop_setup(d[ray]), wc.tris[t, 0], wc.tris[t, 1], wc.tris[t, 2],
                                  tm[ray], floor=True)
            occ[r] |= np.bincount(ray[hit] - r0, minlength=len(r))[: len(r)] > 0
    inst = scene.instances
    for i in wc.sphere_inst.tolist():
        inv = inst.inverse[i, :3, :].copy()
        inv[:, 3] += inv[:, :3] @ np.asarray(origin, np.float64)
        inv = inv.astype(np.float32)
        m_o = ((o[:, 0:1] * inv[:, 0] + o[:, 1:2] * inv[:, 1]) + o[:, 2:3] * inv[:, 2] + inv[:, 3]).astype(np.float32)
        m_d = ((d[:, 0:1] * inv[:, 0] + d[:, 1:2] * inv[:, 1]) + d[:, 2:3] * inv[:, 2]).astype(np.float32)
        model = scene.models[inst.model_ids[i]]
        c = np.broadcast_to(np.asarray(model.sphere_center, np.float32), (n, 3))
        occ |= tracer.sphere_hit(m_o, m_d, c, np.float32(f32_up(model.sphere_radius)), tm)
    return occ


def rays_for(grid, wc, direction, rng, n=600):
    """Origins over the casters' light-space extent at random depths, half of them exactly on
    cell borders (across the sun), all with the sun's direction."""
    basis = sungrid.sun_basis(direction)
    lo, hi, _ = sungrid.caster_boxes(wc, basis)
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    xy = rng.uniform(lo[:2], hi[:2], (n, 2))
    u = grid.uniforms
    cs = 1.0 / float(u["hs_sg_inv_cell"])
    half = n // 2
    xy[:half, 0] = u["hs_sg_base"][0] + np.round((xy[:half, 0] - u["hs_sg_base"][0]) / cs) * cs
    z = rng.uniform(lo[2] - 0.1 * (hi[2] - lo[2]), hi[2], n)
    o = xy[:, 0:1] * basis[0] + xy[:, 1:2] * basis[1] + z[:, None] * basis[2]
    d = np.broadcast_to(np.asarray(direction, np.float32), (n, 3))
    return o, d


@pytest.mark.parametrize("name", ["cube_on_plane", "stiff/grazing", "stiff/thin", "stiff/instance_scales",
                                  "stiff/axis_aligned", "stiff/degenerate", "stiff/far_away", "clusters"])
def test_bake_finds_every_caster_a_ray_hits(name, loaded):
    scene = loaded(name)
    origin = choose_origin(scene)
    wc = sungrid.world_casters(scene, origin)
    if len(wc.tris) > 3000:  # (keep the brute force small: the first casters only)
        keep = np.random.default_rng(1).choice(len(wc.tris), 3000, replace=False)
        wc = sungrid.WorldCasters(wc.tris[np.sort(keep)], wc.sphere_inst[:40], wc.sphere_center[:40],
                                  wc.sphere_radius[:40], wc.scale)
    rng = np.random.default_rng(7)
    hits = 0
    for direction in DIRECTIONS:
        direction = np.asarray(direction) / np.linalg.norm(direction)
        grid = sungrid.build_sun_grid(wc, direction)
        assert grid is not None
        o, d = rays_for(grid, wc, direction, rng)
        tmax = np.where(rng.uniform(size=len(o)) < 0.3, rng.uniform(0.0, 50.0, len(o)), np.inf)
        want = brute(wc, scene, origin, o, d, tmax)
        got = tracer.trace_sun_grid(grid, scene, origin, o, d, tmax)
        missed = np.nonzero(want & ~got)[0]
        assert not len(missed), f"{name} sun {direction}: {len(missed)} rays slip through the grid"
        assert not (got & ~want).any()  # (the same tests: never more)
        hits += int(want.sum())
    assert hits > 50  # the rays do meet casters


def test_bake_layout():
    """Lists highest first, keys rounded up, every caster filed at least once, entries' boxes
    within [0, 255]."""
    from hybrid_shadow_addon.blender.load import load_scene

    scene = load_scene("clusters")
    wc = sungrid.world_casters(scene, choose_origin(scene))
    grid = sungrid.build_sun_grid(wc, (0.3, -0.2, 0.93))
    cells = grid.textures["sg_cell"].linear()
    ent = grid.textures["sg_entry"].linear()[: grid.entries]
    assert int(cells[:, 1].sum()) == grid.entries == len(ent)
    keys = ent[:, 1].view(np.float32)
    for s, c in cells[cells[:, 1] > 1][:500]:
        k = keys[s:s + c]
        assert np.all(k[:-1] >= k[1:])
    tri = ent[(ent[:, 0] & sungrid.SPHERE_FLAG) == 0, 0]
    assert set(np.unique(tri).tolist()) == set(range(len(wc.tris)))
    sph = ent[(ent[:, 0] & sungrid.SPHERE_FLAG) != 0, 0] & ~sungrid.SPHERE_FLAG
    assert set(np.unique(sph).tolist()) == set(wc.sphere_inst.tolist())
    b = [(ent[:, 2] >> np.uint32(8 * j)) & np.uint32(255) for j in range(4)]
    assert np.all(b[0] <= b[1]) and np.all(b[2] <= b[3])


def test_grid_that_does_not_fit_is_none(monkeypatch, loaded):
    scene = loaded("cube_on_plane")
    wc = sungrid.world_casters(scene, choose_origin(scene))
    monkeypatch.setattr(sungrid, "MAX_CELL", 1)
    assert sungrid.build_sun_grid(wc, (0.0, 0.0, 1.0)) is None


def masks(pipeline, scene, settings):
    fr = pipeline.render(scene, settings, W, H)
    return fr, {li: fr.mask_array(li) for li in fr.lights}


@pytest.mark.parametrize("name", list(TEST_SCENES))
def test_gpu_masks_equal_the_bvh(name, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene, "bvh")
    s = Settings(hard=True)
    fr0, plain = masks(pipeline, scene, s.replace(sun_grid=False))
    fr1, grid = masks(pipeline, scene, s)
    suns = [li for li in fr1.lights if scene.lights[li].type == "SUN"]
    assert ("HS_SUN_GRID=1" in fr1.stats["defines"]) == bool(suns)
    assert "HS_SUN_GRID=1" not in fr0.stats["defines"]
    for li in plain:
        v = ~np.isnan(plain[li])
        same = np.mean(plain[li][v] == grid[li][v])
        assert same >= 0.9999, f"{name} {scene.lights[li].name}: {same:.6f}"


@pytest.mark.parametrize("name", ["forest", "clusters", "stiff/grazing"])
def test_gpu_equals_the_mirror(name, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene, "bvh")
    fr = pipeline.render(scene, Settings(hard=True), W, H)
    sp = pipeline.shadow_pass("raytrace")
    suns = [li for li in fr.lights if scene.lights[li].type == "SUN"]
    assert suns
    for li in suns:
        light = scene.lights[li]
        m = fr.mask_array(li)
        cov = ~np.isnan(m)
        o, d, tmax, facing = shadow_rays(fr.gbuffer, np.nonzero(cov), light, pipeline.baked.origin)
        _, grid = sp.sun_grids.get(scene, light, -np.asarray(light.direction, np.float64))
        st = {}
        occ = tracer.trace_sun_grid(grid, scene, pipeline.baked.origin, o[facing], d[facing],
                                    np.broadcast_to(tmax, facing.shape)[facing], st)
        np.testing.assert_array_equal(np.where(occ, 0.0, 1.0), m[cov][facing])
        assert 0 < occ.mean() < 1 and st["tests"] > 0


def test_used_only_where_it_applies(pipeline, loaded):
    forest = loaded("forest")
    pipeline.set_scene(forest, "bvh")
    on = Settings(hard=True)
    assert "HS_SUN_GRID=1" in pipeline.render(forest, on, W, H).stats["defines"]
    assert "HS_SUN_GRID=1" not in pipeline.render(forest, on.replace(sun_grid=False), W, H).stats["defines"]
    assert "HS_SUN_GRID=1" not in pipeline.render(forest, on.replace(structure="grid"), W, H).stats["defines"]
    # a sun with a size (soft) samples it: no grid for its rays
    soft = forest.__class__(**{**forest.__dict__})
    soft.lights = [l.__class__(**{**l.__dict__, "angle": 0.05}) if l.type == "SUN" else l for l in forest.lights]
    pipeline.set_scene(soft, "bvh")
    assert "HS_SUN_GRID=1" not in pipeline.render(soft, Settings(samples=4), W, H).stats["defines"]
    # alpha-cut casters keep the tree
    cards = loaded("alpha_cards")
    pipeline.set_scene(cards, "bvh")
    fr = pipeline.render(cards, on, W, H)
    assert any(cards.lights[li].type == "SUN" for li in fr.lights)
    assert "HS_SUN_GRID=1" not in fr.stats["defines"]


def test_grid_that_does_not_fit_keeps_the_bvh(monkeypatch, pipeline, loaded):
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene, "bvh")
    _, plain = masks(pipeline, scene, Settings(hard=True, sun_grid=False))
    monkeypatch.setattr(sungrid, "MAX_CELL", 1)
    pipeline.set_scene(scene, "bvh")
    fr, got = masks(pipeline, scene, Settings(hard=True))
    assert "HS_SUN_GRID=1" not in fr.stats["defines"]
    for li in plain:
        np.testing.assert_array_equal(got[li], plain[li])


def test_grid_follows_moves_and_the_sun(pipeline, loaded):
    import copy

    scene = copy.deepcopy(loaded("cube_on_plane"))
    pipeline.set_scene(scene, "bvh")
    s = Settings(hard=True)
    sun = [li for li, l in enumerate(scene.lights) if l.type == "SUN"]
    assert sun
    li = sun[0]
    before = pipeline.render(scene, s, W, H).mask_array(li)
    # move every caster but the largest (the ground) sideways: the shadows move with them
    inst = scene.instances
    sizes = [float(np.ptp(scene.models[m].vertices, axis=0).max()) for m in inst.model_ids]
    moved = [i for i in range(len(inst.names)) if sizes[i] < max(sizes)]
    assert moved
    inst.matrices[moved, 0, 3] += 0.7
    inst.inverse[moved] = np.linalg.inv(inst.matrices[moved])
    pipeline.move_instances(scene, moved)
    after = pipeline.render(scene, s, W, H).mask_array(li)
    ref = pipeline.render(scene, s.replace(sun_grid=False), W, H).mask_array(li)
    v = ~np.isnan(ref)
    assert np.mean(after[v] != before[v]) > 0.001
    np.testing.assert_array_equal(after[v], ref[v])
    # turn the sun: a new grid, still the BVH's answer
    light = scene.lights[li]
    d = np.asarray(light.direction, np.float64) + np.array([0.25, -0.1, 0.0])
    aim(light, d / np.linalg.norm(d))
    pipeline.reset_history()
    turned = pipeline.render(scene, s, W, H).mask_array(li)
    ref = pipeline.render(scene, s.replace(sun_grid=False), W, H).mask_array(li)
    np.testing.assert_array_equal(turned[v], ref[v])
    assert np.mean(turned[v] != after[v]) > 0.001


def aim(light, d) -> None:
    """Turn ``light`` to shine along unit ``d`` (its local -Z)."""
    z = -np.asarray(d, np.float64)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    m = light.matrix.copy()
    m[:3, 0], m[:3, 1], m[:3, 2] = x, np.cross(z, x), z
    light.matrix = m


def test_setting_is_checked():
    with pytest.raises(ValueError, match="sun_grid"):
        Settings(sun_grid=1)
