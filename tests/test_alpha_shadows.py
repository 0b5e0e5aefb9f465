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
from hybrid_shadow_addon.core.scene import Image, Instances, Scene
from hybrid_shadow_addon.core.scene_sync import FULL, sync_scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import shadow_rays
from tests.helpers.scenes import alpha_scene, colour_image, trs

pytestmark = [pytest.mark.gpu]


def render(pipeline, sc, mode="raytrace"):
    """A frame of ``sc`` at quality high, baked afresh (the pipeline keeps its bake otherwise); one
    G-buffer, cut at 0.5 (see-through accumulation: test_see_through.py)."""
    if mode == "raytrace":
        pipeline.set_scene(sc, "bvh")
    return pipeline.render(sc, Settings(mode=mode, quality="high", structure="bvh", transparency_samples=1))


@pytest.fixture(scope="module")
def scene():
    return alpha_scene(lights=("sun", "point"))


@pytest.mark.parametrize("li", [0, 1])
def test_raytraced_masks_match_the_oracle(pipeline, scene, li):
    f = render(pipeline, scene)
    assert "HS_HAS_ALPHA=1" in f.stats["defines"]
    mask = f.mask_array(li)
    ok, o, d, tmax, facing = shadow_rays(f, scene, li)
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
    ok, o, d, tmax, facing = shadow_rays(f, sc, 0)
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


def test_cubic_images_cut_as_the_oracle(pipeline):
    """Cubic images (Cycles' Cubic and Smart) cut shadow rays and the G-buffer with the cubic
    B-spline at level 0, as the oracle reads them: a card of random binary texels (whose lone
    opaque texels the B-spline lowers to alpha 4/9) casts another shadow and shows other pixels
    than when read bilinearly."""
    dots = np.full((8, 8, 4), 200, np.uint8)
    dots[..., 3] = (np.random.default_rng(4).random((8, 8)) < 0.4) * 255
    masks, kept = {}, {}
    for interp in ("Cubic", "Linear"):
        sc = alpha_scene()
        sc.images[0] = Image("dots", dots, interpolation=interp)  # the checker card's image
        f = render(pipeline, sc)
        ok, o, d, tmax, facing = shadow_rays(f, sc, 0)
        ref = visibility_brute(sc, o, d, tmax)
        diff = np.abs(f.mask_array(0)[ok][facing] - ref[facing])
        assert (diff > 0.02).mean() < 0.002 and diff.mean() < 0.002, (interp, (diff > 0.02).sum())
        masks[interp] = f.mask_array(0)
        # the card's visible pixels: alpha >= 0.5 there, as the oracle samples it
        pos = f.gbuffer.read("position")
        sel = (pos[..., 3] > 0) & (np.round(f.gbuffer.read("material")[..., 2]).astype(int) == 1)
        local = (np.linalg.inv(sc.instances.matrices[1]) @ np.c_[pos[..., :3][sel], np.ones(sel.sum())].T).T
        a = material_alpha(sc, 0, (local[:, :2] + 1.0) / 2.0)
        assert sel.sum() > 30 and (a < 0.5 - 1e-3).mean() < 0.01, (interp, (a < 0.5 - 1e-3).sum())
        kept[interp] = sel
    both = np.isfinite(masks["Cubic"]) & np.isfinite(masks["Linear"])
    assert (np.abs(masks["Cubic"] - masks["Linear"])[both] > 0.1).sum() > 100
    assert (kept["Cubic"] != kept["Linear"]).sum() > 30


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
    rects = [(x, y, lay, w, h)
             for (x, y, lay), (w, h) in zip(pos.tolist(), [(300, 200), (100, 100), (512, 40), (200, 250)])]
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
    moved = pipeline.render(b, Settings(mode="raytrace", quality="high", structure="bvh",
                                        transparency_samples=1)).mask_array(0)
    c = alpha_scene()
    c.instances.set_matrices([2], trs((0.8, 1.9, 1.6), rot_z=0.9)[None])
    fresh = render(pipeline, c).mask_array(0)
    np.testing.assert_array_equal(np.nan_to_num(moved, nan=-1), np.nan_to_num(fresh, nan=-1))


def test_a_float_alpha_keeps_its_clip_threshold(pipeline):
    """A float (or 16-bit) image keeps its alpha unquantised: alpha 0.7005 under a clip threshold
    of 0.701 cuts the clip card away, where the same image as bytes (179 / 255 = 0.70196) keeps
    it and its shadow. GPU and oracle agree in both, and the float atlas is RGBA32F."""
    flat = np.full((4, 4, 4), 0.8, np.float32)
    flat[..., 3] = 0.7005
    lit = {}
    for name, px in (("float", flat), ("bytes", np.round(flat * 255).astype(np.uint8))):
        sc = alpha_scene()
        sc.images[1] = Image("flat", px)
        sc.materials[3].alpha_threshold = 0.701
        assert sc.images[1].is_float == (name == "float")
        assert bake_materials(sc, 64).atlas.fmt == ("f4" if name == "float" else "f1")
        f = render(pipeline, sc)
        ok, o, d, tmax, facing = shadow_rays(f, sc, 0)
        ref = visibility_brute(sc, o, d, tmax)
        diff = np.abs(f.mask_array(0)[ok][facing] - ref[facing])
        assert (diff > 0.02).mean() < 0.002 and diff.mean() < 0.002, (name, (diff > 0.02).sum())
        lit[name] = np.nansum(f.mask_array(0))
    assert lit["float"] > lit["bytes"] + 100, lit
