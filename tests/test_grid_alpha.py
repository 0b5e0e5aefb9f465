"""Alpha-cut (alpha-textured) shadows through both structures, the hierarchical grid
(``structure="grid"``) and the two-level BVH (``"bvh"``), against the brute-force numpy
visibility (``oracle.tracer.visibility_brute``: the product of the transmittances of every
alpha-cut surface a shadow ray crosses, 0 at an opaque one).

Hand-made core scenes (no bpy): cards over a ground with a Closest-interpolated checker, a
Linear-interpolated soft-edged alpha, two stacked BLEND cards of alpha 0.5 (0.25 where both are
crossed), a CLIP card, a card whose material has transparent shadows off, an opaque cube; a sun
and a point light. The masks of the whole pipeline are compared with the oracle fed the very rays
the GPU traces (``oracle.rays.shadow_rays``: G-buffer points, offset along the normal); a GLSL
harness traces random rays through a crowded grid (several levels, object BVHs). Incremental
moves and mesh edits must give what a fresh bake gives; opaque scenes must compile no alpha code.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.oracle.tracer import visibility_brute
from hybrid_shadow_addon.core.scene import Camera, Image, Instances, Light, Material, Model, Scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.glsl import gl_rays, ray_fragment
from tests.helpers.scenes import cube_model, look_at, plane_model, trs

pytestmark = [pytest.mark.gpu]

STRUCTURES = ("grid", "bvh")
TOL = 0.02  # |GPU - oracle| allowed on ...
AGREE = 0.999  # ... this fraction of the pixels / rays
CARD_UVS = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
CHECKER = 2  # instance index of the Closest checker card
CHECKER_MODEL = 2


# ------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------
def card_model(name="card", n=1):
    """A 2 x 2 card in the XY plane (z = 0) with UVs 0..1, as n x n quads."""
    xs = np.linspace(-1.0, 1.0, n + 1)
    v = np.array([[x, y, 0.0] for y in xs for x in xs], np.float32)
    tris, uvs = [], []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i
            for t in ((a, b, c), (a, c, d)):
                tris.append(t)
                uvs.append([[(v[k, 0] + 1) / 2, (v[k, 1] + 1) / 2] for k in t])
    return Model(name, v, np.array(tris, np.uint32), uvs=np.array(uvs, np.float32))


def images():
    a = ((np.arange(8)[:, None] + np.arange(8)[None, :]) % 2 * 255).astype(np.uint8)
    checker = np.zeros((8, 8, 4), np.uint8)
    checker[..., :3] = 200
    checker[..., 3] = a
    yy, xx = np.mgrid[0:16, 0:16]
    r = np.hypot(xx - 7.5, yy - 7.5) / 7.5
    soft = np.zeros((16, 16, 4), np.uint8)
    soft[..., :3] = 180
    soft[..., 3] = np.round(np.clip(1.2 - r, 0, 1) * 255)
    grad = np.zeros((16, 16, 4), np.uint8)
    grad[..., :3] = 120
    grad[..., 3] = np.round(np.linspace(0, 1, 16)[None, :] * np.linspace(0.3, 1, 16)[:, None] * 255)
    return [Image("checker", checker, interpolation="Closest"), Image("soft", soft, interpolation="Linear"),
            Image("grad", grad, interpolation="Linear", extension="EXTEND")]


def materials():
    return [Material("checker", alpha_image=0),  # 0: BLEND, alpha 0 / 1
            Material("soft", alpha_image=1),  # 1: BLEND, soft edges
            Material("half", alpha=0.5),  # 2: BLEND, constant 0.5
            Material("clip", alpha_image=2, alpha_mode="CLIP", alpha_threshold=0.5),  # 3
            Material("solid", alpha_image=0, transparent_shadow=False)]  # 4: casts the whole card


def alpha_scene(with_materials=True):
    """Ground, six cards (one per case) and a cube; a sun and a point light."""
    names = ["ground", "cube", "checker", "soft", "half_low", "half_high", "clip", "solid"]
    mats = [trs(scale=(5, 5, 1)),
            trs((0.3, -3.0, 0.4), rot_z=0.5, scale=(0.4, 0.4, 0.4)),
            trs((-2.2, -1.6, 1.5), rot_z=0.3, scale=(0.8, 0.8, 1)),
            trs((2.2, -1.5, 1.2), rot_z=-0.4, rot_x=0.3, scale=(0.9, 0.9, 1)),
            trs((-2.0, 2.0, 1.0), scale=(0.8, 0.8, 1)),
            trs((-1.6, 2.3, 2.0), rot_z=0.2, scale=(0.8, 0.8, 1)),
            trs((2.0, 2.0, 1.4), rot_z=0.1, scale=(0.9, 0.9, 1)),
            trs((0.3, 0.2, 1.6), rot_z=0.7, scale=(0.6, 0.6, 1))]
    model_ids = [0, 3, CHECKER_MODEL, 1, 1, 1, 1, 1]
    mids = [-1, -1, 0, 1, 2, 2, 3, 4] if with_materials else [-1] * 8
    inst = Instances(names=names, model_ids=model_ids, matrices=np.array(mats), material_ids=mids)
    ground = plane_model(1.0)
    ground.uvs = CARD_UVS.copy()
    cam = Camera(matrix=look_at((0.0, -0.5, 11.0), (0.0, 0.0, 0.0)), lens=30.0)
    lights = [Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=0.4, rot_x=-0.5)),
              Light("point", "POINT", power=2000.0, matrix=trs((0.8, -0.4, 6.0)))]
    return Scene(models=[ground, card_model(), card_model("checker"), cube_model()], instances=inst,
                 lights=lights, camera=cam, resolution=(160, 120),
                 materials=materials() if with_materials else [], images=images() if with_materials else [])


# ------------------------------------------------------------------------------------------
# pipeline helpers
# ------------------------------------------------------------------------------------------
def render(pipeline, scene, structure):
    pipeline.set_scene(scene, structure)
    # (one G-buffer, cut at 0.5: the masks are checked against its shadow rays)
    return pipeline.render(scene, Settings(mode="raytrace", quality="high", structure=structure,
                                           transparency_samples=1))


def oracle_mask(frame, scene, baked, li):
    """visibility_brute of the rays the GPU traced, at every covered pixel (NaN elsewhere)."""
    mask = frame.mask_array(li)
    rows, cols = np.nonzero(~np.isnan(mask))
    o, d, tmax, facing = shadow_rays(frame.gbuffer, (rows, cols), scene.lights[li], baked.origin)
    ref = np.full(mask.shape, np.nan)
    vis = np.zeros(len(o))
    vis[facing] = visibility_brute(scene, o[facing], d[facing], tmax[facing])
    ref[rows, cols] = vis
    return ref, (rows, cols, o, d, tmax, facing)


def agreement(a, b, tol=TOL):
    ok = ~np.isnan(a) & ~np.isnan(b)
    assert (np.isnan(a) == np.isnan(b)).all()
    return float((np.abs(a[ok] - b[ok]) <= tol).mean()), int((np.abs(a[ok] - b[ok]) > tol).sum())


def checker_uv(scene, o, d, tmax):
    """(uv (N, 2), crossed (N,)) where each ray crosses the checker card's plane."""
    inv = scene.instances.inverse[CHECKER]
    om = o @ inv[:3, :3].T + inv[:3, 3]
    dm = d @ inv[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -om[:, 2] / dm[:, 2]
    p = om + t[:, None] * dm
    uv = (p[:, :2] + 1.0) / 2.0
    crossed = (t > 0) & (t < tmax) & (uv >= 0).all(axis=1) & (uv < 1).all(axis=1)
    return uv, crossed


@pytest.fixture(scope="module")
def masks(pipeline):
    """(scene, {structure: (frame masks, oracle masks, rays)}) of alpha_scene()."""
    scene = alpha_scene().validate()
    out = {}
    for structure in STRUCTURES:
        frame = render(pipeline, scene, structure)
        assert pipeline.baked.has_alpha and "HS_HAS_ALPHA=1" in frame.stats["defines"]
        out[structure] = {li: (frame.mask_array(li),) + oracle_mask(frame, scene, pipeline.baked, li)
                          for li in frame.lights}
    return scene, out


# ------------------------------------------------------------------------------------------
# tests
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("structure", STRUCTURES)
def test_masks_equal_brute_force_visibility(masks, structure):
    scene, res = masks
    seen = np.zeros(0)
    for li, (got, ref, _rays) in res[structure].items():
        frac, bad = agreement(got, ref)
        assert frac >= AGREE, f"light {li}: {bad} pixels differ by more than {TOL}"
        seen = np.concatenate([seen, ref[~np.isnan(ref)]])
    # every case is on screen: alpha 0 / 1 (checker, clip), 0.5 and 0.25 (the stacked cards),
    # soft values in between (the Linear texture)
    assert (np.abs(seen - 0.5) < 1e-6).sum() > 50 and (np.abs(seen - 0.25) < 1e-6).sum() > 50
    soft = (seen > 0.05) & (seen < 0.95) & (np.abs(seen - 0.5) > 0.01) & (np.abs(seen - 0.25) > 0.01)
    assert soft.sum() > 50
    assert (seen == 0).sum() > 200 and (seen == 1).sum() > 200


@pytest.mark.parametrize("structure", STRUCTURES)
def test_closest_checker_is_exact_away_from_texel_edges(masks, structure):
    scene, res = masks
    n_tested = 0
    values = set()
    for _li, (got, ref, (rows, cols, o, d, tmax, facing)) in res[structure].items():
        uv, crossed = checker_uv(scene, o, d, tmax)
        st = uv * 8.0
        edge = np.minimum(np.abs(st - np.round(st)), 1.0).min(axis=1)
        r = ref[rows, cols]
        pick = facing & crossed & (edge > 0.02) & ((r == 0.0) | (r == 1.0))
        g = got[rows, cols][pick]
        assert set(np.unique(g)) <= {0.0, 1.0}
        np.testing.assert_array_equal(g, r[pick])
        n_tested += int(pick.sum())
        values |= set(np.unique(r[pick]).tolist())
    assert n_tested > 100 and values == {0.0, 1.0}


def test_grid_and_bvh_masks_agree(masks):
    _scene, res = masks
    for li in res["grid"]:
        frac, bad = agreement(res["grid"][li][0], res["bvh"][li][0])
        assert frac >= AGREE, f"light {li}: {bad} pixels differ between grid and bvh"


def test_opaque_scenes_compile_no_alpha(pipeline):
    # no materials at all; colour-only textured materials; alpha only on non-casters, on spheres
    # or with transparent shadows off: no [uv], no [object_mat], no HS_HAS_ALPHA
    plain = alpha_scene(with_materials=False)
    textured = alpha_scene()
    textured.materials = [Material("tex", color_image=0)] * 5
    solid = alpha_scene()
    solid.materials = [Material(m.name, alpha_image=m.alpha_image, alpha=m.alpha, transparent_shadow=False)
                       for m in solid.materials]
    hidden = alpha_scene()
    hidden.instances.casts_shadow[2:] = False
    hidden.instances.casts_shadow[[4]] = True
    hidden.instances.sphere[4] = True
    progs = pipeline.programs
    for scene in (plain, textured, solid, hidden):
        scene.validate()
        for structure in STRUCTURES:
            b = bake_scene(scene, BakeConfig(structure=structure))
            assert not b.has_alpha and "HS_HAS_ALPHA" not in b.defines
            assert "uv" not in b.textures and "object_mat" not in b.textures
            src, _ = progs.source("raytrace", "FRAGMENT_SHADER", sorted(b.defines.items()))
            assert "#define HS_HAS_ALPHA" not in src
        frame = render(pipeline, scene, "grid")
        assert not any(d.startswith("HS_HAS_ALPHA") for d in frame.stats["defines"])
        assert "hs_uv_tex" not in pipeline.baked.samplers.values()
    # and the alpha scene has them
    b = bake_scene(alpha_scene(), BakeConfig(structure="grid"))
    assert b.has_alpha and b.defines.get("HS_HAS_ALPHA") == 1
    assert {"uv", "object_mat", "mat", "atlas"} <= set(b.textures)
    assert b.samplers["uv"] == "hs_uv_tex" and b.samplers["object_mat"] == "hs_object_mat_tex"
    src, _ = progs.source("raytrace", "FRAGMENT_SHADER", sorted(b.defines.items()))
    assert "#define HS_HAS_ALPHA" in src


def test_grid_alpha_textures(pipeline):
    """[object_mat] = 1 + material of the alpha-cut casters; [uv] holds their models' UVs at
    the triangles' [tri] records (and only theirs)."""
    scene = alpha_scene()
    b = bake_scene(scene, BakeConfig(structure="grid"))
    slots = b.accel.tex.object_mat.linear()[: len(scene.instances), 0]
    np.testing.assert_array_equal(slots, [0, 0, 1, 2, 3, 3, 4, 0])
    assert b.accel.models.uv.tolist() == [False, True, True, False]
    _check_uvs(b, scene)


def _check_uvs(b, scene):
    """Every [tri] triangle of a model with kept UVs has the UVs of the same mesh triangle."""
    ms = b.accel.models
    tri = b.accel.tex.tri.records(3)
    uv = b.accel.tex.uv.records(2)
    for m, model in enumerate(scene.models):
        ts, tc = int(ms.tri_start[m]), int(ms.tri_count[m])
        if not ms.uv[m]:
            continue
        world = model.vertices[model.triangles]  # (T, 3, 3)
        stored = tri[ts:ts + tc].reshape(tc, 3, 3)
        su = uv[ts:ts + tc, :6].reshape(tc, 3, 2)
        for k in range(tc):  # find the mesh triangle of each stored one
            j = int(np.nonzero((world == stored[k]).all(axis=(1, 2)))[0][0])
            np.testing.assert_array_equal(su[k], model.uvs[j] if model.uvs is not None else 0.0)
        assert (uv[ts:ts + tc, 6:] == 0).all()


def _masks(pipeline, scene, structure):
    frame = pipeline.render(scene, Settings(mode="raytrace", quality="high", structure=structure,
                                            transparency_samples=1))
    return {li: frame.mask_array(li) for li in frame.lights}


def _compare_fresh(pipeline, gl_ctx, scene, structure, inc):
    fresh = Pipeline(gl_ctx)
    try:
        fresh.set_scene(scene, structure)
        full = _masks(fresh, scene, structure)
    finally:
        fresh.release()
    for li in full:
        frac, bad = agreement(inc[li], full[li], 1e-5)
        assert bad <= 2, f"light {li}: {bad} pixels differ from a fresh bake"
    return full


@pytest.mark.parametrize("structure", STRUCTURES)
def test_move_alpha_card_equals_fresh_bake(pipeline, gl_ctx, structure):
    scene = alpha_scene()
    pipeline.set_scene(scene, structure)
    before = _masks(pipeline, scene, structure)
    # the checker card slides over the cube and the soft card tilts; the stacked pair swaps
    m = scene.instances.matrices.copy()
    scene.instances.set_matrices([2, 3], np.array([trs((0.6, -2.4, 1.9), rot_z=1.0, scale=(0.8, 0.8, 1)),
                                                   trs((2.0, -1.0, 1.0), rot_x=-0.4, scale=(0.9, 0.9, 1))]))
    scene.instances.set_matrices([4, 5], m[[5, 4]])
    rep = pipeline.baked.update_instances(scene, [2, 3, 4, 5])
    pipeline.scene_textures.apply(pipeline.baked, rep)
    pipeline.reset_history()
    if structure == "grid":
        assert any(r[0] == "object_mat" for r in rep.ranges)
    inc = _masks(pipeline, scene, structure)
    assert any(agreement(inc[li], before[li], 1e-5)[1] > 100 for li in inc), "the move changed nothing"
    _compare_fresh(pipeline, gl_ctx, scene, structure, inc)
    # a material change rides on a move too (grid: [object_mat] is rewritten; the cube's model,
    # opaque at the bake, gets its UVs into [uv] when it turns alpha-cut)
    scene.instances.material_ids[[1, 2]] = [2, 3]
    pipeline.move_instances(scene, [1, 2])
    inc = _masks(pipeline, scene, structure)
    full = _compare_fresh(pipeline, gl_ctx, scene, structure, inc)
    if structure == "grid":
        _check_uvs(pipeline.baked, scene)
    ref, _ = oracle_mask(pipeline.render(scene, Settings(mode="raytrace", quality="high", structure=structure,
                                                         transparency_samples=1)), scene, pipeline.baked, 0)
    frac, bad = agreement(full[0], ref)
    assert frac >= AGREE, f"{bad} pixels differ from the brute force after the material change"


@pytest.mark.parametrize("structure", STRUCTURES)
def test_edit_alpha_mesh_equals_fresh_bake(pipeline, gl_ctx, structure):
    scene = alpha_scene()
    pipeline.set_scene(scene, structure)
    # the checker card becomes a 3 x 3 card with its UVs mirrored (more triangles: moved to
    # the [tri] tail), then a new mesh (a 2 x 2 card, UVs scaled) replaces the soft card's
    edited = card_model("checker", 3)
    edited.uvs = edited.uvs[..., ::-1] * np.float32([1.0, 0.75])
    scene.models[CHECKER_MODEL] = edited
    rep = pipeline.baked.update_model(scene, CHECKER_MODEL)
    pipeline.scene_textures.apply(pipeline.baked, rep)
    pipeline.reset_history()
    inc = _masks(pipeline, scene, structure)
    if structure == "grid":
        assert any(r[0] == "uv" for r in rep.ranges) or "uv" in rep.resized
        _check_uvs(pipeline.baked, scene)
    _compare_fresh(pipeline, gl_ctx, scene, structure, inc)
    new = card_model("new", 2)
    new.uvs = new.uvs * np.float32(1.5) - np.float32(0.25)
    scene.models.append(new)
    scene.instances.model_ids[3] = len(scene.models) - 1
    pipeline.update_model(scene, len(scene.models) - 1)
    inc = _masks(pipeline, scene, structure)
    if structure == "grid":
        assert pipeline.baked.accel.models.uv[-1]
        _check_uvs(pipeline.baked, scene)
    full = _compare_fresh(pipeline, gl_ctx, scene, structure, inc)
    for li in full:
        ref, _ = oracle_mask(pipeline.render(scene, Settings(mode="raytrace", quality="high", structure=structure,
                                                             transparency_samples=1)), scene, pipeline.baked, li)
        frac, bad = agreement(full[li], ref)
        assert frac >= AGREE, f"light {li}: {bad} pixels differ from the brute force after the edits"


# ------------------------------------------------------------------------------------------
# GLSL harness: random rays through a crowded grid (several levels, object BVHs)
# ------------------------------------------------------------------------------------------
VIS_FRAG = ray_fragment("hs_visibility(o.xyz, d.xyz, o.w)")


def gl_visibility(ctx, baked, origins, dirs, tmax):
    return gl_rays(ctx, baked, origins, dirs, tmax, VIS_FRAG).astype(np.float64)


def crowded_scene(rng, n=160):
    """n random cards (every material, some opaque, a few spheres) over a 24 m ground."""
    mats = [trs(scale=(12, 12, 1))]
    mids, models, sph = [-1], [0], [False]
    for _ in range(n):
        c = rng.uniform([-10, -10, 0.3], [10, 10, 4.0])
        s = rng.uniform(0.3, 1.2)
        mats.append(trs(c, rot_z=rng.uniform(0, 6.3), rot_x=rng.uniform(-0.6, 0.6), scale=(s, s, 1)))
        k = int(rng.integers(-1, 5))
        mids.append(k)
        models.append(int(rng.integers(1, 3)))
        sph.append(bool(rng.random() < 0.04))
    inst = Instances(names=[f"o{i}" for i in range(len(mats))], model_ids=models, matrices=np.array(mats),
                     material_ids=mids, sphere=sph)
    ground = plane_model(1.0)
    ground.uvs = CARD_UVS.copy()
    return Scene(models=[ground, card_model(), card_model("fine", 2)], instances=inst, materials=materials(),
                 images=images())


@pytest.mark.parametrize("structure", STRUCTURES)
def test_glsl_visibility_through_crowded_grid(gl_ctx, structure):
    rng = np.random.default_rng(11)
    scene = crowded_scene(rng).validate(require_camera=False)
    cfg = BakeConfig(structure=structure, grid=GridConfig(object_bvh_threshold=3, object_leaf_size=2))
    b = bake_scene(scene, cfg)
    assert b.has_alpha
    if structure == "grid":
        assert "HS_HAS_NODE_BVH" in b.defines and b.accel.layout.levels > 2 and "HS_HAS_SPHERES" in b.defines
    n = 12000
    o = np.column_stack([rng.uniform(-11, 11, (n, 2)), rng.uniform(0.01, 0.2, n)])
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.3
    tmax = np.where(rng.random(n) < 0.3, rng.uniform(0.5, 6.0, n), np.inf)
    ref = visibility_brute(scene, o, d, tmax)
    got = gl_visibility(gl_ctx, b, o, d, tmax)
    ok = np.abs(got - ref) <= TOL
    assert ok.mean() >= AGREE, f"{int((~ok).sum())} of {n} rays differ"
    partial = (ref > 0.01) & (ref < 0.99)
    assert partial.sum() > 300 and (ref == 0).sum() > 300 and (ref == 1).sum() > 300
    # crossing several alpha cards: products of several transmittances
    assert ((ref > 0.01) & (ref < 0.3)).sum() > 50


@pytest.mark.parametrize("structure", STRUCTURES)
def test_alpha_material_without_triangles_compiles(gl_ctx, structure):
    """An alpha-cut material only on a mesh without triangles (and a sphere caster): nothing to
    cut, no HS_HAS_ALPHA; the program compiles and the sphere still blocks."""
    empty = Model("empty", np.zeros((0, 3)), np.zeros((0, 3)))
    inst = Instances(names=["e", "s"], model_ids=[0, 1], matrices=np.array([trs(), trs((0, 0, 2))]),
                     material_ids=[2, -1], sphere=[False, True])
    scene = Scene(models=[empty, plane_model()], instances=inst, materials=materials(),
                  images=images()).validate(require_camera=False)
    b = bake_scene(scene, BakeConfig(structure=structure))
    assert not b.has_alpha and "HS_HAS_ALPHA" not in b.defines
    o = np.array([[0, 0, 0.0], [3, 3, 0]])
    d = np.array([[0, 0, 1.0], [0, 0, 1]])
    np.testing.assert_array_equal(gl_visibility(gl_ctx, b, o, d, np.inf), [0.0, 1.0])
