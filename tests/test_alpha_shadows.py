"""Alpha-cut shadows and textured albedo on the GPU (hand-made core scenes, no bpy): the
ray-traced masks against the numpy oracle (``visibility_brute``), the G-buffer's albedo and cut
against ``oracle.alpha``, the shadow-map variant, the atlas and its mips, what an opaque scene
compiles, and frame-to-frame sync when materials change."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.bake.materials import bake_materials, mip_chain, shelf_pack, srgb_decode
from hybrid_shadow_addon.core.oracle.alpha import albedo as oracle_albedo
from hybrid_shadow_addon.core.oracle.alpha import material_alpha
from hybrid_shadow_addon.core.oracle.tracer import visibility_brute
from hybrid_shadow_addon.core.scene import Camera, Image, Instances, Light, Material, Model, Scene
from hybrid_shadow_addon.core.scene_sync import FULL, sync_scene
from hybrid_shadow_addon.core.settings import Settings
from tests.test_gpu_scenes import look_at, trs

QUAD_UV = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)


def quad(name, size=1.0, uv_scale=1.0):
    v = np.array([[-size, -size, 0], [size, -size, 0], [size, size, 0], [-size, size, 0]], np.float32)
    return Model(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), uvs=QUAD_UV * uv_scale)


def leaf_alpha(n=64):
    """A soft-edged leaf: alpha falls from 1 to 0 across an ellipse's rim, with a round hole."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n * 2 - 1
    r = np.sqrt((x / 0.9) ** 2 + (y / 0.55) ** 2)
    a = np.clip((1.0 - r) * 6.0, 0, 1) * (np.hypot(x - 0.3, y) > 0.18)
    px = np.zeros((n, n, 4), np.uint8)
    px[..., 1] = 160
    px[..., 3] = np.round(a * 255)
    return px


def checker(n=8):
    a = ((np.arange(n)[:, None] + np.arange(n)[None, :]) % 2 * 255).astype(np.uint8)
    px = np.full((n, n, 4), 200, np.uint8)
    px[..., 3] = a
    return px


def colour_image(n=32):
    y, x = np.mgrid[0:n, 0:n]
    px = np.zeros((n, n, 4), np.uint8)
    px[..., 0] = x * 255 // (n - 1)
    px[..., 1] = y * 255 // (n - 1)
    px[..., 2] = ((x // 4 + y // 4) % 2) * 200
    px[..., 3] = 255
    return px


def alpha_scene(lights=("sun",), card_materials=(0, 1, 2, 3)):
    """A textured ground, four cards above it: a Closest checker (BLEND), a Linear soft leaf
    (BLEND), two stacked alpha-0.5 cards, a CLIP leaf; an opaque cube as a plain caster."""
    images = [Image("checker", checker(), interpolation="Closest"), Image("leaf", leaf_alpha()),
              Image("ground", colour_image(), extension="REPEAT")]
    materials = [Material("checker", alpha_image=0), Material("leaf", alpha_image=1),
                 Material("half", alpha=0.5), Material("clip", alpha_image=1, alpha_mode="CLIP", alpha_threshold=0.7),
                 Material("ground", color_image=2, uv_transform=np.float32([[3, 0, 0.1], [0, 3, 0]]))]
    cube_v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube = Model("cube", cube_v, np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.uint32))
    models = [quad("ground", 6.0), quad("card"), cube]
    mats = [trs((0, 0, 0)), trs((-2.2, 1.5, 1.4), rot_z=0.3, rot_x=0.2), trs((1.8, 1.6, 1.3), rot_z=-0.4),
            trs((-1.8, -1.8, 1.0), scale=(0.8, 0.8, 1)), trs((-1.8, -1.8, 1.5), scale=(0.8, 0.8, 1)),
            trs((2.0, -1.5, 1.2), rot_x=-0.3), trs((0.2, 0.0, 0.4), scale=(0.3, 0.3, 0.4))]
    mids = [0, 1, 1, 1, 1, 1, 2]
    cm = list(card_materials)
    material_ids = [4, cm[0], cm[1], cm[2], cm[2], cm[3], -1]
    inst = Instances(names=["ground", "checker", "leaf", "half_a", "half_b", "clip", "cube"], model_ids=mids,
                     matrices=np.array(mats), material_ids=material_ids, base_color=[(1, 1, 1, 1)] * 7)
    ls = []
    if "sun" in lights:
        ls.append(Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=0.7, rot_x=0.45)))
    if "point" in lights:
        ls.append(Light("point", "POINT", power=800.0, matrix=trs((0.5, 0.8, 5.0))))
    cam = Camera(matrix=look_at((0.5, -7.5, 8.5), (0, 0, 0.3)), lens=30.0)
    return Scene(models=models, instances=inst, lights=ls, camera=cam, resolution=(200, 150),
                 materials=materials, images=images).validate()


def _shadow_rays(frame, scene, li):
    """Origins (a little off the surface along the normal) and directions to light ``li`` of
    every covered pixel, row order of ``mask_array``."""
    pos = frame.gbuffer.read("position")
    nrm = frame.gbuffer.read("normal")
    ok = pos[..., 3] > 0
    p = pos[..., :3][ok].astype(np.float64)
    n = nrm[..., :3][ok].astype(np.float64)
    light = scene.lights[li]
    o = p + n * 2e-4
    if light.type == "SUN":
        d = np.broadcast_to(-light.direction, o.shape)
        tmax = np.full(len(o), np.inf)
    else:
        d = light.position - o
        tmax = np.ones(len(o))
    facing = (n * d).sum(axis=1) > 0
    return ok, o, d, tmax, facing


def render(pipeline, sc, mode="raytrace"):
    """A frame of ``sc`` at quality high, baked afresh (the pipeline keeps its bake otherwise)."""
    if mode == "raytrace":
        pipeline.set_scene(sc, "bvh")
    return pipeline.render(sc, Settings(mode=mode, quality="high", structure="bvh"))


@pytest.fixture(scope="module")
def scene():
    return alpha_scene(lights=("sun", "point"))


@pytest.mark.parametrize("li", [0, 1])
def test_raytraced_masks_match_the_oracle(pipeline, scene, li):
    f = render(pipeline, scene)
    assert "HS_HAS_ALPHA=1" in f.stats["defines"]
    mask = f.mask_array(li)
    ok, o, d, tmax, facing = _shadow_rays(f, scene, li)
    ref = visibility_brute(scene, o, d, tmax)
    got = mask[ok]
    sel = facing
    diff = np.abs(got[sel] - ref[sel])
    # the contact of the origin offset and texel-edge rounding leave a few pixels apart
    assert (diff > 0.02).mean() < 0.002, (diff > 0.02).sum()
    assert diff.mean() < 0.002
    # the soft leaf and the stacked cards give partial light, and the GPU sees it
    assert ((ref > 0.05) & (ref < 0.95)).sum() > 50
    assert ((got > 0.05) & (got < 0.95)).sum() > 50
    stacked = np.isclose(ref, 0.25, atol=1e-6)
    assert stacked.sum() > 20 and np.allclose(got[stacked & sel], 0.25, atol=0.01)


def test_transparent_shadow_off_casts_the_whole_card(pipeline):
    sc = alpha_scene()
    sc.materials[0].transparent_shadow = False
    f = render(pipeline, sc)
    mask = f.mask_array(0)
    ok, o, d, tmax, facing = _shadow_rays(f, sc, 0)
    ref = visibility_brute(sc, o, d, tmax)
    diff = np.abs(mask[ok][facing] - ref[facing])
    assert (diff > 0.02).mean() < 0.002
    sc_on = alpha_scene()
    f2 = render(pipeline, sc_on)
    assert np.nansum(f2.mask_array(0)) > np.nansum(mask) + 50  # the checker's holes let light through


def test_gbuffer_albedo_and_cut_match_the_oracle(pipeline, scene):
    f = render(pipeline, scene, "none")
    gb = f.gbuffer
    alb = gb.read("albedo")
    pos = gb.read("position")
    mat = gb.read("material")
    ok = pos[..., 3] > 0
    inst = np.round(mat[..., 2]).astype(int)
    # ground pixels: the colour image (uv from the ground plane's position: x, y in [-6, 6])
    g = ok & (inst == 0)
    p = pos[..., :3][g].astype(np.float64)
    uv = (p[:, :2] + 6.0) / 12.0
    ref = oracle_albedo(scene, np.zeros(len(uv), np.int64), uv)
    err = np.abs(alb[..., :3][g] - ref)
    # mip mapping blurs where the image is minified; most pixels are at level ~0 here
    assert np.median(err) < 0.01 and (err.max(axis=1) > 0.1).mean() < 0.05
    # no visible card pixel is one its alpha cuts
    for row in (1, 2, 5):
        sel = ok & (inst == row)
        assert sel.sum() > 30
        m = scene.instances.matrices[row]
        local = (np.linalg.inv(m) @ np.c_[pos[..., :3][sel], np.ones(sel.sum())].T).T[:, :3]
        uv = (local[:, :2] + 1.0) / 2.0
        a = material_alpha(scene, int(scene.instances.material_ids[row]), uv)
        thr = scene.materials[int(scene.instances.material_ids[row])].alpha_threshold \
            if scene.materials[int(scene.instances.material_ids[row])].alpha_mode == "CLIP" else 0.5
        assert (a < thr - 0.02).mean() < 0.01


def test_shadow_maps_cut_the_alpha_too(pipeline):
    sc = alpha_scene()
    rt = render(pipeline, sc).mask_array(0)
    sm = render(pipeline, sc, "shadowmap").mask_array(0)
    opaque = alpha_scene(card_materials=(-1, -1, -1, -1))
    sm_opaque = render(pipeline, opaque, "shadowmap").mask_array(0)
    ok = np.isfinite(rt) & np.isfinite(sm)
    # binary shadow maps against the fractional ray-traced mask: same side of 1/2 nearly everywhere
    assert ((rt[ok] < 0.5) != (sm[ok] < 0.5)).mean() < 0.02
    ok2 = np.isfinite(sm_opaque)
    assert (sm_opaque[ok2] < 0.5).sum() > (sm[ok] < 0.5).sum() + 100  # opaque cards shadow more


def test_opaque_scene_compiles_no_alpha_code(pipeline):
    sc = alpha_scene(card_materials=(-1, -1, -1, -1))
    sc.materials = sc.materials[4:5]  # the textured ground only
    sc.instances.material_ids[:] = np.where(sc.instances.material_ids == 4, 0, -1)
    sc.validate()
    b = bake_scene(sc, BakeConfig(structure="bvh"))
    assert not b.has_alpha and "HS_HAS_ALPHA" not in b.defines
    assert "uv" not in b.textures and "mat" in b.textures  # the G-buffer still has its texture
    none = Scene(models=sc.models, instances=Instances(names=sc.instances.names, model_ids=sc.instances.model_ids,
                                                        matrices=sc.instances.matrices), lights=sc.lights,
                 camera=sc.camera, resolution=sc.resolution)
    b2 = bake_scene(none, BakeConfig(structure="bvh"))
    assert b2.materials is None and not {"uv", "mat", "atlas"} & set(b2.textures)
    f = render(pipeline, none)
    assert not any("ALPHA" in d for d in f.stats["defines"])
    progs = pipeline.gpu.programs
    opaque_prog = progs.fullscreen("raytrace", {**b2.defines, "HS_LIGHT_SUN": 1})[0]
    assert not {"hs_uv_tex", "hs_mat_tex", "hs_atlas_tex"} & set(opaque_prog)
    b3 = bake_scene(alpha_scene(), BakeConfig(structure="bvh"))
    alpha_prog = progs.fullscreen("raytrace", {**b3.defines, "HS_LIGHT_SUN": 1})[0]
    assert {"hs_uv_tex", "hs_mat_tex", "hs_atlas_tex"} <= set(alpha_prog)


def test_atlas_mips_and_packing():
    px = colour_image(32)
    levels = mip_chain(px, srgb=True)
    assert [lv.shape[:2] for lv in levels] == [(32 >> k, 32 >> k) for k in range(6)]
    lin = srgb_decode(px[..., :3] / 255.0)
    top = srgb_decode(levels[-1][0, 0, :3] / 255.0)
    np.testing.assert_allclose(top, lin.mean(axis=(0, 1)), atol=0.01)  # averaged in linear light
    pos = shelf_pack([(300, 200), (100, 100), (512, 40), (200, 250)], 512)
    rects = [(x, y, l, w, h) for (x, y, l), (w, h) in zip(pos.tolist(), [(300, 200), (100, 100), (512, 40), (200, 250)])]
    for i, a in enumerate(rects):
        assert a[0] + a[3] <= 512 and a[1] + a[4] <= 512
        for b in rects[i + 1:]:
            if a[2] == b[2]:
                assert a[0] + a[3] <= b[0] or b[0] + b[3] <= a[0] or a[1] + a[4] <= b[1] or b[1] + b[4] <= a[1]
    sc = alpha_scene()
    mb = bake_materials(sc, 64)
    assert mb.cuts_shadows and list(mb.alpha_slot) == [1, 2, 3, 4, 0]
    # each image's level 0 bytes sit where its record says
    lin = mb.mat.linear()
    for i, img in enumerate(sc.images):
        r = int(mb.image_record[i])
        x, y, layer, wh = lin[r + 1]
        w, h = wh & 0xFFFF, wh >> 16
        assert (w, h) == img.size
        np.testing.assert_array_equal(mb.atlas.data[layer, y:y + h, x:x + w], img.pixels)
    assert lin[int(mb.image_record[2]), 0] == 6 and lin[int(mb.image_record[0]), 0] == 1  # mips for colour only


def test_sync_rebakes_when_materials_change(pipeline):
    a = alpha_scene()
    pipeline.set_scene(a, "bvh")
    b = alpha_scene()
    assert sync_scene(pipeline, a, b, structure="bvh").kind != FULL  # equal content: kept
    c = alpha_scene()
    c.materials[1].alpha_threshold = 0.2
    c.materials[1].alpha_mode = "CLIP"
    rep = sync_scene(pipeline, b, c, structure="bvh")
    assert rep.kind == FULL and "material" in rep.reason
    d = alpha_scene()
    d.materials[1].alpha_mode = "CLIP"
    d.materials[1].alpha_threshold = 0.2
    d.instances.material_ids[1] = -1
    assert sync_scene(pipeline, c, d, structure="bvh").kind == FULL
    e = alpha_scene()
    e.materials[1].alpha_mode = "CLIP"
    e.materials[1].alpha_threshold = 0.2
    e.instances.material_ids[1] = -1
    e.images[0].pixels[0, 0, 3] ^= 255
    assert sync_scene(pipeline, d, e, structure="bvh").kind == FULL


def test_moving_an_alpha_card_keeps_the_masks_exact(pipeline):
    a = alpha_scene()
    pipeline.set_scene(a, "bvh")
    b = alpha_scene()
    b.instances.set_matrices([2], trs((0.8, 1.9, 1.6), rot_z=0.9)[None])
    rep = sync_scene(pipeline, a, b, structure="bvh")
    assert rep.kind != FULL and 2 in rep.moved
    moved = pipeline.render(b, Settings(mode="raytrace", quality="high", structure="bvh")).mask_array(0)
    c = alpha_scene()
    c.instances.set_matrices([2], trs((0.8, 1.9, 1.6), rot_z=0.9)[None])
    fresh = render(pipeline, c).mask_array(0)
    np.testing.assert_array_equal(np.nan_to_num(moved, nan=-1), np.nan_to_num(fresh, nan=-1))
