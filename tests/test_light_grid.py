"""Hard lights' light-space grids (``core/bake/lightgrid.py``, ``shaders/common/scene_lightgrid.glsl``).

1. The bake is conservative: for suns from many directions (straight down, along the axes,
   grazing) with rays from random origins and from origins on cell borders, and for local lights
   at many places (among the casters, touching them, far off) with rays from random origins and
   along the cube's face borders, the numpy mirror of the lookup (``tracer.trace_light_grid``)
   finds every caster that a brute-force test of all casters hits, with the same float32
   triangle and sphere tests.
2. On the GPU the grids' masks equal the two-level BVH's on every test scene and light, and the
   mirror's answer on the frame's own rays.
3. They are used only where they apply (hard lights on the BVH, no alpha-cut casters, the
   setting on, a grid that fits), and follow the scene and the lights: a moved caster, a turned
   sun or a moved lamp rebuilds them.
"""
from dataclasses import replace

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import lightgrid
from hybrid_shadow_addon.core.bake.baked import choose_origin
from hybrid_shadow_addon.core.oracle import tracer
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.blender_env import TEST_SCENES

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.slow]

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
    for i in wc.sphere_inst.tolist():
        occ |= tracer.instance_sphere_hit(scene, origin, np.full(n, i), o, d, tm)
    return occ


def rays_for(grid, wc, direction, rng, n=600):
    """Origins over the casters' light-space extent at random depths, half of them exactly on
    cell borders (across the sun), all with the sun's direction."""
    basis = lightgrid.sun_basis(direction)
    lo, hi, _, _ = lightgrid.caster_boxes(wc, basis)
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    xy = rng.uniform(lo[:2], hi[:2], (n, 2))
    u = grid.uniforms
    cs = 1.0 / float(u["hs_lg_inv_cell"])
    half = n // 2
    xy[:half, 0] = u["hs_lg_base"][0] + np.round((xy[:half, 0] - u["hs_lg_base"][0]) / cs) * cs
    z = rng.uniform(lo[2] - 0.1 * (hi[2] - lo[2]), hi[2], n)
    o = xy[:, 0:1] * basis[0] + xy[:, 1:2] * basis[1] + z[:, None] * basis[2]
    d = np.broadcast_to(np.asarray(direction, np.float32), (n, 3))
    return o, d


@pytest.mark.parametrize("name", ["cube_on_plane", "stiff/grazing", "stiff/thin", "stiff/instance_scales",
                                  "stiff/axis_aligned", "stiff/degenerate", "stiff/far_away", "clusters"])
def test_bake_finds_every_caster_a_ray_hits(name, loaded):
    scene = loaded(name)
    origin = choose_origin(scene)
    wc = lightgrid.world_casters(scene, origin)
    if len(wc.tris) > 3000:  # (keep the brute force small: the first casters only)
        keep = np.random.default_rng(1).choice(len(wc.tris), 3000, replace=False)
        wc = lightgrid.WorldCasters(wc.tris[np.sort(keep)], wc.sphere_inst[:40], wc.sphere_center[:40],
                                  wc.sphere_radius[:40], wc.scale)
    rng = np.random.default_rng(7)
    hits = 0
    for direction in DIRECTIONS:
        direction = np.asarray(direction) / np.linalg.norm(direction)
        grid = lightgrid.build_sun_grid(wc, direction)
        assert grid is not None
        o, d = rays_for(grid, wc, direction, rng)
        tmax = np.where(rng.uniform(size=len(o)) < 0.3, rng.uniform(0.0, 50.0, len(o)), np.inf)
        want = brute(wc, scene, origin, o, d, tmax)
        got = tracer.trace_light_grid(grid, wc.tris, scene, origin, o, d, tmax)
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
    wc = lightgrid.world_casters(scene, choose_origin(scene))
    grid = lightgrid.build_sun_grid(wc, (0.3, -0.2, 0.93))
    cells = grid.textures["lg_cell"].linear()
    ent = grid.textures["lg_entry"].linear()[: grid.entries]
    assert int(cells[:, 1].sum()) == grid.entries == len(ent)
    keys = ent[:, 1].view(np.float32)
    for s, c in cells[cells[:, 1] > 1][:500]:
        k = keys[s:s + c]
        assert np.all(k[:-1] >= k[1:])
    tri = ent[(ent[:, 0] & lightgrid.SPHERE_FLAG) == 0, 0]
    assert set(np.unique(tri).tolist()) == set(range(len(wc.tris)))
    sph = ent[(ent[:, 0] & lightgrid.SPHERE_FLAG) != 0, 0] & ~lightgrid.SPHERE_FLAG
    assert set(np.unique(sph).tolist()) == set(wc.sphere_inst.tolist())
    b = [(ent[:, 2] >> np.uint32(8 * j)) & np.uint32(255) for j in range(4)]
    assert np.all(b[0] <= b[1]) and np.all(b[2] <= b[3])


def test_grid_that_does_not_fit_is_none(monkeypatch, loaded):
    scene = loaded("cube_on_plane")
    wc = lightgrid.world_casters(scene, choose_origin(scene))
    monkeypatch.setattr(lightgrid, "MAX_CELL", 1)
    assert lightgrid.build_sun_grid(wc, (0.0, 0.0, 1.0)) is None
    assert lightgrid.build_local_grid(wc, (0.0, 0.0, 5.0)) is None


def local_rays(grid, wc, L, rng, n=600):
    """Rays from origins among and around the casters (a third of them on the cube's face
    borders, seen from the light) to the light at ``L`` (tmax 1)."""
    lo = wc.tris.reshape(-1, 3).min(axis=0) if len(wc.tris) else np.full(3, -1.0)
    hi = wc.tris.reshape(-1, 3).max(axis=0) if len(wc.tris) else np.full(3, 1.0)
    ext = hi - lo
    o = rng.uniform(lo - 0.2 * ext, hi + 0.2 * ext, (n, 3))
    third = n // 3
    w = o[:third] - L
    w[:, 1] = np.abs(w[:, 0]) * np.sign(w[:, 1] + 1e-12)  # |w.x| == |w.y|: the x / y face border
    o[:third] = L + w
    Lf = np.asarray(L, np.float32)
    d = (Lf.astype(np.float32) - o.astype(np.float32)).astype(np.float32)
    return o.astype(np.float32), d


def light_places(wc, rng):
    """Local lights: among the casters, just off a triangle, on a vertex's line, far off."""
    lo = wc.tris.reshape(-1, 3).min(axis=0)
    hi = wc.tris.reshape(-1, 3).max(axis=0)
    t = wc.tris[rng.integers(len(wc.tris))].astype(np.float64)
    centre = t.mean(axis=0)
    nrm = np.cross(t[1] - t[0], t[2] - t[0])
    nrm /= max(np.linalg.norm(nrm), 1e-30)
    return [(lo + hi) / 2 + np.array([0.0, 0.0, 0.3]) * (hi - lo), centre + 1e-3 * nrm, centre + 0.05 * nrm,
            rng.uniform(lo, hi), hi + 3.0 * (hi - lo), np.array([t[0][0], t[0][1], hi[2] + 1.0])]


@pytest.mark.parametrize("name", ["cube_on_plane", "stiff/point_in_box", "stiff/spot_touching", "stiff/thin",
                                  "stiff/instance_scales", "stiff/far_away", "clusters"])
def test_local_bake_finds_every_caster_a_ray_hits(name, loaded):
    scene = loaded(name)
    origin = choose_origin(scene)
    wc = lightgrid.world_casters(scene, origin)
    if len(wc.tris) > 3000:
        keep = np.random.default_rng(1).choice(len(wc.tris), 3000, replace=False)
        wc = lightgrid.WorldCasters(wc.tris[np.sort(keep)], wc.sphere_inst[:40], wc.sphere_center[:40],
                                    wc.sphere_radius[:40], wc.scale)
    rng = np.random.default_rng(11)
    places = light_places(wc, rng) + [np.asarray(light.position - origin) for light in scene.lights
                                          if light.type != "SUN"]
    hits = 0
    for L in places:
        L = np.asarray(L, np.float32)
        grid = lightgrid.build_local_grid(wc, L)
        assert grid is not None
        o, d = local_rays(grid, wc, L, rng)
        want = brute(wc, scene, origin, o, d, 1.0)
        got = tracer.trace_light_grid(grid, wc.tris, scene, origin, o, d, 1.0)
        missed = np.nonzero(want & ~got)[0]
        assert not len(missed), f"{name} light at {L}: {len(missed)} rays slip through the grid"
        assert not (got & ~want).any()
        hits += int(want.sum())
    assert hits > 50


@pytest.fixture(autouse=True)
def eager(request):
    """The GPU tests build every grid at once (not only once it pays back)."""
    if "pipeline" in request.fixturenames:
        rt = request.getfixturevalue("pipeline").shadow_pass("raytrace")
        rt.options = replace(rt.options, eager_light_grids=True)
        yield
        rt.options = replace(rt.options, eager_light_grids=False)
    else:
        yield


def masks(pipeline, scene, settings):
    fr = pipeline.render(scene, settings, W, H)
    return fr, {li: fr.mask_array(li) for li in fr.lights}


def gridded(pipeline) -> set:
    """Names of the lights the last frame traced through their grids."""
    return set(pipeline.shadow_pass("raytrace").light_grids.last)


@pytest.mark.parametrize("name", list(TEST_SCENES) + ["stiff/point_in_box", "stiff/spot_touching"])
def test_gpu_masks_equal_the_bvh(name, pipeline, loaded):
    scene = loaded(name)
    pipeline.set_scene(scene, "bvh")
    s = Settings(hard=True)
    fr0, plain = masks(pipeline, scene, s.replace(light_grid=False))
    assert "HS_LIGHT_GRID=1" not in fr0.stats["defines"]
    fr1, grid = masks(pipeline, scene, s)
    assert "HS_LIGHT_GRID=1" in fr1.stats["defines"]
    culled = {scene.lights[li].name for li in pipeline.shadow_pass("raytrace").culled}
    assert gridded(pipeline) == {scene.lights[li].name for li in fr1.lights} - culled
    for li in plain:
        v = ~np.isnan(plain[li])
        same = np.mean(plain[li][v] == grid[li][v])
        assert same >= 0.9999, f"{name} {scene.lights[li].name}: {same:.6f}"


@pytest.mark.parametrize("name", ["forest", "clusters", "stiff/grazing", "stiff/point_in_box"])
def test_gpu_equals_the_mirror(name, pipeline, loaded):
    from hybrid_shadow_addon.core.gpu.lights import light_ray_uniforms

    scene = loaded(name)
    pipeline.set_scene(scene, "bvh")
    fr = pipeline.render(scene, Settings(hard=True), W, H)
    grids = pipeline.shadow_pass("raytrace").light_grids
    checked = 0
    for li in fr.lights:
        light = scene.lights[li]
        if light.name not in grids.last:
            continue
        m = fr.mask_array(li)
        cov = ~np.isnan(m)
        o, d, tmax, facing = shadow_rays(fr.gbuffer, np.nonzero(cov), light, pipeline.baked.origin)
        local, vec = light_ray_uniforms(light, pipeline.baked.origin)
        grid = grids.for_light(scene, light, local, vec).grid
        st = {}
        occ = tracer.trace_light_grid(grid, grids._casters.tris, scene, pipeline.baked.origin, o[facing],
                                      d[facing], np.broadcast_to(tmax, facing.shape)[facing], st)
        # (the shader's reach test, a spot's cone, gives 0 without a ray: compare where it traced)
        traced = m[cov][facing]
        np.testing.assert_array_equal(np.where(occ, 0.0, 1.0)[traced > 0], traced[traced > 0])
        assert st["tests"] > 0
        checked += 1
    assert checked


def test_used_only_where_it_applies(pipeline, loaded):
    forest = loaded("forest")
    pipeline.set_scene(forest, "bvh")
    on = Settings(hard=True)
    assert "HS_LIGHT_GRID=1" in pipeline.render(forest, on, W, H).stats["defines"]
    assert "HS_LIGHT_GRID=1" not in pipeline.render(forest, on.replace(light_grid=False), W, H).stats["defines"]
    assert "HS_LIGHT_GRID=1" not in pipeline.render(forest, on.replace(structure="grid"), W, H).stats["defines"]
    # lights with a size (soft) sample them: no grid for their rays, the hard ones keep theirs
    soft = loaded("soft_lights")
    pipeline.set_scene(soft, "bvh")
    fr = pipeline.render(soft, Settings(samples=4), W, H)
    from hybrid_shadow_addon.core.gpu.lights import soft_shape

    hard = {soft.lights[li].name for li in fr.lights if soft_shape(soft.lights[li]) is None}
    assert gridded(pipeline) == hard - {soft.lights[li].name for li in pipeline.shadow_pass("raytrace").culled}
    assert len(hard) < len(fr.lights)
    # alpha-cut casters keep the tree
    cards = loaded("alpha_cards")
    pipeline.set_scene(cards, "bvh")
    fr = pipeline.render(cards, on, W, H)
    assert fr.lights and "HS_LIGHT_GRID=1" not in fr.stats["defines"]


def test_grid_that_does_not_fit_keeps_the_bvh(monkeypatch, pipeline, loaded):
    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene, "bvh")
    _, plain = masks(pipeline, scene, Settings(hard=True, light_grid=False))
    monkeypatch.setattr(lightgrid, "MAX_CELL", 1)
    pipeline.set_scene(scene, "bvh")
    fr, got = masks(pipeline, scene, Settings(hard=True))
    assert "HS_LIGHT_GRID=1" not in fr.stats["defines"]
    for li in plain:
        np.testing.assert_array_equal(got[li], plain[li])


def test_a_build_out_of_memory_keeps_the_bvh(monkeypatch, pipeline, loaded):
    from hybrid_shadow_addon.core.gpu.passes import light_grid

    def no_memory(*args):
        raise MemoryError

    scene = loaded("cube_on_plane")
    pipeline.set_scene(scene, "bvh")
    _, ref = masks(pipeline, scene, Settings(hard=True, light_grid=False))
    monkeypatch.setattr(light_grid, "build_sun_grid", no_memory)
    pipeline.set_scene(scene, "bvh")
    fr, got = masks(pipeline, scene, Settings(hard=True))
    assert not gridded(pipeline)
    for li in fr.lights:
        np.testing.assert_array_equal(got[li], ref[li])


def test_grids_stop_at_the_memory_budget(monkeypatch, pipeline, loaded):
    """Once the grids kept hold MAX_BYTES, the other lights keep the tree (same masks)."""
    from hybrid_shadow_addon.core.gpu.passes import light_grid

    scene = loaded("clusters")
    pipeline.set_scene(scene, "bvh")
    _, ref = masks(pipeline, scene, Settings(hard=True, light_grid=False))
    monkeypatch.setattr(light_grid, "MAX_BYTES", 1)
    pipeline.set_scene(scene, "bvh")
    fr, got = masks(pipeline, scene, Settings(hard=True))
    assert len(gridded(pipeline)) == 1  # (the first light's grid, then the budget is spent)
    for li in fr.lights:
        np.testing.assert_array_equal(got[li], ref[li])


def test_grids_follow_moves_and_the_lights(pipeline, loaded):
    import copy

    from hybrid_shadow_addon.core.scene import Light

    scene = copy.deepcopy(loaded("cube_on_plane"))
    lamp = np.eye(4)
    lamp[:3, 3] = (1.5, -1.0, 3.0)
    scene.lights.append(Light(name="Lamp", type="POINT", matrix=lamp))
    pipeline.set_scene(scene, "bvh")
    s = Settings(hard=True)
    assert {light.type for light in scene.lights} >= {"SUN", "POINT"}

    def check(changed_from=None):
        fr, got = masks(pipeline, scene, s)
        _, ref = masks(pipeline, scene, s.replace(light_grid=False))
        out = {}
        for li in fr.lights:
            a, b = got[li], ref[li]
            v = ~np.isnan(b)
            np.testing.assert_array_equal(a[v], b[v], err_msg=scene.lights[li].name)
            out[li] = a
        if changed_from is not None:
            for li in changed_from:
                v = ~np.isnan(out[li])
                assert np.mean(out[li][v] != changed_from[li][v]) > 0.001, scene.lights[li].name
        return out

    before = check()
    # move every caster but the largest (the ground) sideways: the shadows move with them
    inst = scene.instances
    sizes = [float(np.ptp(scene.models[m].vertices, axis=0).max()) for m in inst.model_ids]
    moved = [i for i in range(len(inst.names)) if sizes[i] < max(sizes)]
    assert moved
    inst.matrices[moved, 0, 3] += 0.7
    inst.inverse[moved] = np.linalg.inv(inst.matrices[moved])
    pipeline.move_instances(scene, moved)
    after = check(before)
    # turn the sun, move the lamps: new grids, still the BVH's answers
    for light in scene.lights:
        if light.type == "SUN":
            d = np.asarray(light.direction, np.float64) + np.array([0.25, -0.1, 0.0])
            aim(light, d / np.linalg.norm(d))
        else:
            light.matrix = light.matrix.copy()
            light.matrix[:3, 3] += (0.6, -0.4, 0.2)
    pipeline.reset_history()
    check(after)


def aim(light, d) -> None:
    """Turn ``light`` to shine along unit ``d`` (its local -Z)."""
    z = -np.asarray(d, np.float64)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    m = light.matrix.copy()
    m[:3, 0], m[:3, 1], m[:3, 2] = x, np.cross(z, x), z
    light.matrix = m


def test_grids_are_built_once_they_pay_back(monkeypatch, pipeline, loaded):
    """Not eager: a light's first frame traces the tree (and times it); a later frame with the
    light and the bake unchanged builds its grid if the estimated build costs at most
    PAYBACK_FRAMES of those traces; a change starts over."""
    from hybrid_shadow_addon.core.gpu.passes import light_grid

    scene = loaded("clusters")
    rt = pipeline.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=False)
    grids = rt.light_grids
    pipeline.set_scene(scene, "bvh")
    s = Settings(hard=True)
    pipeline.render(scene, s, W, H)
    assert not gridded(pipeline)  # (a one-frame render builds nothing)
    monkeypatch.setattr(light_grid, "PAYBACK_FRAMES", 1e-6)
    pipeline.render(scene, s, W, H)
    assert not gridded(pipeline)  # (too costly for what it saves)
    monkeypatch.setattr(light_grid, "PAYBACK_FRAMES", 1e9)
    fr = pipeline.render(scene, s, W, H)  # (the builds start in the background: this frame the tree)
    assert not gridded(pipeline)
    grids.wait()
    _, ref = masks(pipeline, scene, s.replace(light_grid=False))
    fr, got = masks(pipeline, scene, s)  # (uploads and uses them)
    culled = {scene.lights[li].name for li in pipeline.shadow_pass("raytrace").culled}
    assert gridded(pipeline) == {scene.lights[li].name for li in fr.lights} - culled
    assert grids.build_ms > 0
    for li in fr.lights:
        np.testing.assert_array_equal(got[li], ref[li])
    pipeline.render(scene, s, W, H)
    assert grids.build_ms == 0  # (kept)
    pipeline.set_scene(scene, "bvh")  # a new bake: the first frame traces the tree again
    pipeline.render(scene, s, W, H)
    assert not gridded(pipeline)


def test_setting_is_checked():
    with pytest.raises(ValueError, match="light_grid"):
        Settings(light_grid=1)
