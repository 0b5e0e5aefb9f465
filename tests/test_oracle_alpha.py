"""The numpy oracle of alpha-textured shadows: image sampling, material alpha, transmittance,
albedo, the watertight test's barycentrics and brute-force visibility (hand-made scenes, no bpy)."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.oracle.alpha import albedo, material_alpha, sample_image, srgb_to_linear, transmittance
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, visibility_brute, woop_hit, woop_hit_bary, woop_setup
from hybrid_shadow_addon.core.scene import LUMA, Image, Instances, Material, Model, Scene

W = H = 4


def _pixels():
    """4x4 RGBA bytes, all distinct per texel: px[j, i] is texel (i, j) (row j = v)."""
    i, j = np.meshgrid(np.arange(W), np.arange(H))
    r = 16 * i + 64 * j + 5
    return np.stack([r, 255 - r, 7 * i + 3 * j, 60 * j + 20 * i + 1], axis=-1).astype(np.uint8)


PX = _pixels()
P = PX.astype(np.float64) / 255.0


def _img(ext="REPEAT", interp="Linear", pixels=None, srgb=True):
    return Image("img", PX if pixels is None else pixels, srgb=srgb, extension=ext, interpolation=interp)


# ------------------------------------------------------------------------------------------
# sample_image
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", ["REPEAT", "EXTEND", "CLIP", "MIRROR"])
@pytest.mark.parametrize("interp", ["Linear", "Closest"])
def test_texel_centres_exact(ext, interp):
    i, j = np.meshgrid(np.arange(W), np.arange(H))
    uv = np.stack([(i.ravel() + 0.5) / W, (j.ravel() + 0.5) / H], 1)
    got = sample_image(_img(ext, interp), uv)
    np.testing.assert_array_equal(got, P[j.ravel(), i.ravel()])
    assert got.shape == (W * H, 4) and got.dtype == np.float64


def test_cubic_is_cycles_bspline():
    """Cubic (Cycles' Cubic and Smart): the uniform cubic B-spline over the 4x4 nearest texels
    (weights 1/6, 2/3, 1/6 at a texel centre; 1/48, 23/48, 23/48, 1/48 half-way), constant
    images stay constant, and each extension rule applies to every texel index."""
    one = np.zeros((8, 8, 4), np.uint8)
    one[4, 3] = 255  # texel (3, 4)
    img = Image("dot", one, srgb=False, interpolation="Cubic")
    centre = lambda i, j: [(i + 0.5) / 8, (j + 0.5) / 8]  # noqa: E731
    got = sample_image(img, [centre(3, 4), centre(4, 4), centre(4, 5), centre(5, 4), [0.5, 4.5 / 8]])[:, 3]
    np.testing.assert_allclose(got, [4 / 9, 1 / 9, 1 / 36, 0.0, 23 / 48 * 2 / 3], rtol=0, atol=1e-12)
    flat = Image("flat", np.full((3, 5, 4), 90, np.uint8), extension="CLIP", interpolation="Cubic")
    inner = sample_image(flat, [[0.5, 0.5]])[0]
    np.testing.assert_allclose(inner, 90 / 255, rtol=0, atol=1e-12)
    for ext in ("REPEAT", "EXTEND", "MIRROR"):
        uv = np.random.default_rng(1).uniform(-2, 3, (50, 2))
        np.testing.assert_allclose(sample_image(Image("f", flat.pixels, extension=ext, interpolation="Cubic"), uv),
                                   90 / 255, rtol=0, atol=1e-12)
    # CLIP: texels beyond the image are transparent black, so the edge fades
    assert sample_image(flat, [[0.5 / 5, 0.5]])[0, 3] == pytest.approx(5 / 6 * 90 / 255)
    # REPEAT wraps: the dot seen across the seam equals the dot seen from inside
    dot = Image("dot", np.roll(one, (-4, -3), axis=(0, 1)), srgb=False, interpolation="Cubic")
    np.testing.assert_allclose(sample_image(dot, [[0.5 / 8 - 1 / 16, 0.5 / 8]])[:, 3],
                               sample_image(img, [[3.5 / 8 - 1 / 16, 4.5 / 8]])[:, 3], rtol=0, atol=1e-12)
    # the albedo reads a Cubic colour image bilinearly (the G-buffer's mip-mapped colour)
    sc = Scene(models=[], instances=Instances(names=["a"], model_ids=[0], matrices=np.eye(4)[None],
                                              material_ids=[0], base_color=[(1, 1, 1, 1)]),
               materials=[Material("m", color_image=0)], images=[img])
    lin = sample_image(img, [[0.5, 4.5 / 8]], "Linear")[0, :3]
    np.testing.assert_allclose(albedo(sc, [0], [[0.5, 4.5 / 8]])[0], lin, rtol=0, atol=1e-12)


def test_row_zero_is_bottom():
    got = sample_image(_img(), [[0.125, 0.01 + 0.115], [0.125, 0.875]])
    np.testing.assert_array_equal(got[0], P[0, 0])
    np.testing.assert_array_equal(got[1], P[3, 0])


@pytest.mark.parametrize("ext", ["REPEAT", "EXTEND", "CLIP", "MIRROR"])
def test_linear_midpoints_are_averages(ext):
    img = _img(ext)
    # between texel i and i + 1 along u (at row j's centre), and between rows along v
    for i in range(W - 1):
        for j in range(H):
            got = sample_image(img, [[(i + 1) / W, (j + 0.5) / H]])[0]
            np.testing.assert_allclose(got, (PX[j, i].astype(float) + PX[j, i + 1]) / 2 / 255, rtol=0, atol=1e-15)
    for i in range(W):
        for j in range(H - 1):
            got = sample_image(img, [[(i + 0.5) / W, (j + 1) / H]])[0]
            np.testing.assert_allclose(got, (PX[j, i].astype(float) + PX[j + 1, i]) / 2 / 255, rtol=0, atol=1e-15)
    # the corner shared by 4 texels: their mean
    got = sample_image(img, [[0.5, 0.5]])[0]
    np.testing.assert_allclose(got, PX[1:3, 1:3].reshape(4, 4).astype(float).mean(0) / 255, rtol=0, atol=1e-15)
    # a quarter of the way: 3/4 of one, 1/4 of the next
    got = sample_image(img, [[(1.5 + 0.25) / W, 2.5 / H]])[0]
    np.testing.assert_allclose(got, 0.75 * P[2, 1] + 0.25 * P[2, 2], rtol=0, atol=1e-12)


def test_extension_modes_linear():
    v = 1.5 / H  # row 1's centre
    uv = [[-0.1, v], [1.1, v]]
    row = P[1]
    rep = sample_image(_img("REPEAT"), uv)
    np.testing.assert_allclose(rep[0], 0.9 * row[3] + 0.1 * row[0], atol=1e-12)
    np.testing.assert_allclose(rep[1], 0.1 * row[3] + 0.9 * row[0], atol=1e-12)
    ext = sample_image(_img("EXTEND"), uv)
    np.testing.assert_allclose(ext, [row[0], row[3]], atol=1e-12)
    mir = sample_image(_img("MIRROR"), uv)
    np.testing.assert_allclose(mir, [row[0], row[3]], atol=1e-12)
    np.testing.assert_array_equal(sample_image(_img("CLIP"), uv), 0.0)
    # MIRROR beyond the first texel: u = -0.3 -> x = -1.7: texels -2 (0.7) and -1 (0.3) = 1 and 0
    np.testing.assert_allclose(sample_image(_img("MIRROR"), [[-0.3, v]])[0], 0.7 * row[1] + 0.3 * row[0], atol=1e-12)
    # REPEAT: a whole period away is the same sample
    np.testing.assert_allclose(sample_image(_img("REPEAT"), [[0.3 + 2, v - 1]]),
                               sample_image(_img("REPEAT"), [[0.3, v]]), atol=1e-12)
    # CLIP inside [0, 1) near the border: the texel beyond the image reads transparent black
    np.testing.assert_allclose(sample_image(_img("CLIP"), [[0.05, v]])[0], 0.7 * row[0], atol=1e-12)
    np.testing.assert_allclose(sample_image(_img("CLIP"), [[0.95, v]])[0], 0.7 * row[3], atol=1e-12)
    # CLIP: [0, 1) is half open
    np.testing.assert_array_equal(sample_image(_img("CLIP"), [[1.0, v], [0.5, 1.0], [0.5, -1e-9]]), 0.0)
    assert sample_image(_img("CLIP"), [[0.0, v]])[0].any()


def test_extension_modes_closest():
    v = 1.5 / H
    uv = [[-0.1, v], [1.1, v], [-0.3, v], [1.3, v]]
    row = P[1]
    np.testing.assert_array_equal(sample_image(_img("REPEAT", "Closest"), uv), row[[3, 0, 2, 1]])
    np.testing.assert_array_equal(sample_image(_img("EXTEND", "Closest"), uv), row[[0, 3, 0, 3]])
    np.testing.assert_array_equal(sample_image(_img("MIRROR", "Closest"), uv), row[[0, 3, 1, 2]])
    np.testing.assert_array_equal(sample_image(_img("CLIP", "Closest"), uv), 0.0)
    # and along v
    np.testing.assert_array_equal(sample_image(_img("MIRROR", "Closest"), [[0.6, -0.1], [0.6, 1.3]]), P[[0, 2], 2])


def test_closest_floor():
    got = sample_image(_img("REPEAT", "Closest"), [[0.3, 0.6], [0.0, 0.0], [0.2499, 0.7501], [0.999, 0.999]])
    np.testing.assert_array_equal(got, P[[2, 0, 3, 3], [1, 0, 0, 3]])


def test_nonfinite_uv_is_black():
    got = sample_image(_img(), [[np.nan, 0.5], [0.5, np.inf]])
    np.testing.assert_array_equal(got, 0.0)


def test_non_square_image():
    px = np.zeros((2, 8, 4), np.uint8)
    px[..., 3] = np.arange(8)[None, :] * 30 + np.arange(2)[:, None] * 5
    img = Image("wide", px, extension="EXTEND")
    got = sample_image(img, [[(5 + 0.5) / 8, 1.5 / 2], [6 / 8, 0.5 / 2]])[:, 3]
    np.testing.assert_allclose(got, [(150 + 5) / 255, (150 + 180) / 2 / 255], atol=1e-15)


def test_srgb_to_linear():
    c = np.array([0.0, 0.04045, 0.5, 1.0, 0.2])
    np.testing.assert_allclose(srgb_to_linear(c), [0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0,
                                                   ((0.2 + 0.055) / 1.055) ** 2.4], rtol=1e-15)
    assert abs(srgb_to_linear(0.5) - 0.214041140) < 1e-8


# ------------------------------------------------------------------------------------------
# materials
# ------------------------------------------------------------------------------------------
def _mat_scene(*materials, images=None):
    return Scene(materials=list(materials), images=images if images is not None else [_img()])


def test_material_alpha_channel_a_and_constant():
    sc = _mat_scene(Material("a", alpha_image=0, alpha=0.5), Material("c", alpha=0.3), Material("o"))
    uv = [[0.375, 0.625]]  # texel (1, 2)
    np.testing.assert_allclose(material_alpha(sc, 0, uv), [P[2, 1, 3] * 0.5], rtol=1e-15)
    np.testing.assert_array_equal(material_alpha(sc, 1, uv * 3), [0.3, 0.3, 0.3])
    np.testing.assert_array_equal(material_alpha(sc, 2, uv), [1.0])
    np.testing.assert_array_equal(material_alpha(sc, -1, uv), [1.0])


def test_material_alpha_luma_srgb():
    px = np.array([[[200, 100, 50, 7]]], np.uint8)
    rgb = np.array([200, 100, 50]) / 255
    for srgb in (True, False):
        sc = _mat_scene(Material("l", alpha_image=0, alpha_channel="LUMA", alpha=0.8),
                        images=[Image("px", px, srgb=srgb)])
        want = (srgb_to_linear(rgb) if srgb else rgb) @ np.array(LUMA) * 0.8
        np.testing.assert_allclose(material_alpha(sc, 0, [[0.3, 0.7]]), [want], rtol=1e-14)
    # decoding matters: the sRGB luma is well below the stored one
    s_on = material_alpha(_mat_scene(Material("l", alpha_image=0, alpha_channel="LUMA"),
                                     images=[Image("px", px, srgb=True)]), 0, [[0.5, 0.5]])[0]
    s_off = material_alpha(_mat_scene(Material("l", alpha_image=0, alpha_channel="LUMA"),
                                      images=[Image("px", px, srgb=False)]), 0, [[0.5, 0.5]])[0]
    assert s_on < 0.6 * s_off


def test_uv_transform():
    # image u = 2 u + 0.125, image v = v: mesh (0.25, 0.375) -> texel (2, 1)'s centre
    sc = _mat_scene(Material("t", alpha_image=0, uv_transform=[[2, 0, 0.125], [0, 1, 0]]),
                    Material("swap", alpha_image=0, uv_transform=[[0, 1, 0], [1, 0, 0]]))
    np.testing.assert_array_equal(material_alpha(sc, 0, [[0.25, 0.375]]), [P[1, 2, 3]])
    # swapped axes: mesh (v, u) of texel (1, 3) = image (0.375, 0.875)
    np.testing.assert_array_equal(material_alpha(sc, 1, [[0.875, 0.375]]), [P[3, 1, 3]])
    # a rotation (not symmetric): image (u, v) = (v, 1 - u); mesh (0.375, 0.625) -> texel (2, 2)
    sc = _mat_scene(Material("rot", alpha_image=0, uv_transform=[[0, 1, 0], [-1, 0, 1]]))
    np.testing.assert_array_equal(material_alpha(sc, 0, [[0.375, 0.625]]), [P[2, 2, 3]])
    np.testing.assert_array_equal(material_alpha(sc, 0, [[0.125, 0.875]]), [P[3, 3, 3]])


def test_transmittance_rules():
    px = np.zeros((1, 2, 4), np.uint8)
    px[0, :, 3] = [128, 64]
    img = Image("a", px, interpolation="Closest")
    sc = _mat_scene(Material("blend", alpha_image=0),
                    Material("clip", alpha_image=0, alpha_mode="CLIP", alpha_threshold=0.5),
                    Material("clip51", alpha_image=0, alpha_mode="CLIP", alpha_threshold=0.51),
                    Material("noshadow", alpha_image=0, transparent_shadow=False),
                    Material("solid", alpha=1.0),
                    Material("over", alpha=1.7), Material("neg", alpha=-0.5),
                    images=[img])
    uv = [[0.25, 0.5], [0.75, 0.5]]  # alpha 128/255, 64/255
    np.testing.assert_allclose(transmittance(sc, 0, uv), [1 - 128 / 255, 1 - 64 / 255], rtol=1e-15)
    np.testing.assert_array_equal(transmittance(sc, 1, uv), [0.0, 1.0])  # 0.502 >= 0.5 blocks
    np.testing.assert_array_equal(transmittance(sc, 2, uv), [1.0, 1.0])
    np.testing.assert_array_equal(transmittance(sc, 3, uv), [0.0, 0.0])
    np.testing.assert_array_equal(transmittance(sc, 4, uv), [0.0, 0.0])
    np.testing.assert_array_equal(transmittance(sc, -1, uv), [0.0, 0.0])
    np.testing.assert_array_equal(transmittance(sc, 5, uv), [0.0, 0.0])  # alpha clamped to [0, 1]
    np.testing.assert_array_equal(transmittance(sc, 6, uv), [1.0, 1.0])


def test_albedo():
    px = np.array([[[255, 128, 0, 255], [10, 20, 30, 255]]], np.uint8)
    images = [Image("c", px, srgb=True, interpolation="Closest"), Image("lin", px, srgb=False, interpolation="Closest")]
    sc = Scene(images=images, materials=[Material("srgb", color_image=0), Material("lin", color_image=1),
                                         Material("none", alpha=0.5)],
               instances=Instances(names=["a", "b", "c", "d"], material_ids=[0, 1, 2, -1],
                                   base_color=[[0.5, 1.0, 0.25, 1], [1, 1, 1, 1], [0.1, 0.2, 0.3, 1],
                                               [0.4, 0.5, 0.6, 1]]))
    rows = [0, 1, 2, 3, 0]
    uv = [[0.25, 0.5], [0.75, 0.5], [0.5, 0.5], [0.5, 0.5], [0.75, 0.5]]
    got = albedo(sc, rows, uv)
    base = sc.instances.base_color.astype(np.float64)[:, :3]
    want = np.array([base[0] * srgb_to_linear(px[0, 0, :3] / 255), px[0, 1, :3] / 255, base[2], base[3],
                     base[0] * srgb_to_linear(px[0, 1, :3] / 255)])
    np.testing.assert_allclose(got, want, rtol=1e-7)


# ------------------------------------------------------------------------------------------
# tracer: barycentrics
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("floor", [False, True])
def test_woop_bary_matches_woop_hit(floor):
    rng = np.random.default_rng(3)
    n = 20000
    f = np.float32
    v = rng.normal(size=(n, 3, 3)).astype(f)
    o = (rng.normal(size=(n, 3)) * 2).astype(f)
    d = (v.astype(np.float64).mean(1) + rng.normal(scale=0.3, size=(n, 3)) - o).astype(f)  # aimed near them
    tmax = rng.choice([np.inf, 0.5, 2.0], n).astype(f)
    s = woop_setup(d)
    ref = woop_hit(o, s, v[:, 0], v[:, 1], v[:, 2], tmax, floor=floor)
    hit, bary, t = woop_hit_bary(o, s, v[:, 0], v[:, 1], v[:, 2], tmax, floor=floor)
    assert (hit == ref).all() and hit.sum() > 2000
    b = bary[hit]
    assert (b >= 0).all()
    np.testing.assert_allclose(b.sum(1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(bary[~hit], 0.0)
    # the barycentric point is the ray's point at t
    p_bary = np.einsum("pc,pcj->pj", b, v[hit].astype(np.float64))
    p_ray = o[hit].astype(np.float64) + t[hit, None] * d[hit]
    scale = np.abs(v[hit]).max(axis=(1, 2)) + np.abs(o[hit]).max(1)
    assert (np.abs(p_bary - p_ray).max(1) / scale < 1e-4).mean() > 0.999
    assert (t[hit] > 0).all() and (t[hit] < tmax[hit]).all()


# ------------------------------------------------------------------------------------------
# visibility_brute on hand-made scenes
# ------------------------------------------------------------------------------------------
def _quad(name="card", uv_scale=1.0):
    """Unit square in z = 0, uvs = xy * uv_scale; diagonal x = y."""
    v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    tris = [[0, 1, 2], [0, 2, 3]]
    uvs = np.array([[v[k][:2] for k in t] for t in tris], np.float64) * uv_scale
    return Model(name, v, tris, uvs=uvs)


def _ground():
    v = [[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]]
    return Model("ground", v, [[0, 1, 2], [0, 2, 3]])


def _translate(x=0.0, y=0.0, z=0.0, s=1.0):
    m = np.eye(4)
    m[:3, :3] *= s
    m[:3, 3] = (x, y, z)
    return m


def _checker(interp="Closest"):
    i, j = np.meshgrid(np.arange(4), np.arange(4))
    px = np.full((4, 4, 4), 200, np.uint8)
    px[..., 3] = np.where((i + j) % 2 == 0, 255, 0)
    return Image("checker", px, interpolation=interp)


def _card_scene(materials, card_mats, card_z=(1.0,), images=None, casts=None, extra=None):
    """Ground (material -1) plus one card per entry of card_z (material card_mats[k])."""
    models = [_ground(), _quad()]
    n = 1 + len(card_z)
    inst = Instances(names=["ground"] + [f"card{k}" for k in range(len(card_z))], model_ids=[0] + [1] * len(card_z),
                     matrices=[np.eye(4)] + [_translate(z=z) for z in card_z],
                     material_ids=[-1] + list(card_mats),
                     casts_shadow=np.ones(n, bool) if casts is None else casts)
    return Scene(models=models, instances=inst, materials=list(materials),
                 images=[_checker()] if images is None else images)


def _cell_rays():
    """One upward ray from the ground through each checker cell, off the card's diagonal."""
    i, j = np.meshgrid(np.arange(4), np.arange(4))
    i, j = i.ravel(), j.ravel()
    o = np.stack([(i + 0.25) / 4, (j + 0.6) / 4, np.full(16, 1e-3)], 1)
    d = np.tile([0.0, 0.0, 1.0], (16, 1))
    return o, d, (i + j) % 2 == 0  # opaque cell


@pytest.mark.parametrize("mode", ["CLIP", "BLEND"])
def test_checker_card(mode):
    sc = _card_scene([Material("chk", alpha_image=0, alpha_mode=mode)], [0])
    sc.validate(require_camera=False)
    o, d, opaque = _cell_rays()
    vis = visibility_brute(sc, o, d)
    np.testing.assert_array_equal(vis, np.where(opaque, 0.0, 1.0))
    # trace_brute ignores alpha: every ray is occluded by the card
    assert trace_brute(sc, o, d).all()
    # double-sided: downward rays from above the card (stopping before the ground) agree
    o2 = o.copy()
    o2[:, 2] = 2.0
    np.testing.assert_array_equal(visibility_brute(sc, o2, -d, 1.5), vis)
    # ... and reaching the opaque ground: 0
    np.testing.assert_array_equal(visibility_brute(sc, o2, -d, 3.0), 0.0)
    # tmax short of the card: 1
    np.testing.assert_array_equal(visibility_brute(sc, o, d, 0.5), 1.0)


def test_checker_card_transformed_instance():
    """A rotated, scaled, translated card with uvs spanning 2 checker periods (REPEAT)."""
    mat = Material("chk", alpha_image=0, alpha_mode="CLIP")
    th = 0.6
    M = np.eye(4)
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    M[:3, :3] = R @ np.diag([3.0, 2.0, 1.0])
    M[:3, 3] = (1.0, -2.0, 1.5)
    sc = Scene(models=[_ground(), _quad(uv_scale=2.0)],
               instances=Instances(names=["g", "c"], model_ids=[0, 1], matrices=[np.eye(4), M], material_ids=[-1, 0]),
               materials=[mat], images=[_checker()])
    # points in card space (x, y) -> uv 2 (x, y) -> texel floor(8 x) mod 4, floor(8 y) mod 4
    rng = np.random.default_rng(5)
    xy = rng.uniform(0.01, 0.99, (400, 2))
    cell = np.floor(xy * 8)
    frac = xy * 8 - cell
    keep = (np.abs(xy[:, 0] - xy[:, 1]) > 0.01) & (np.abs(frac - 0.5) < 0.45).all(1)  # off edges, off diagonal
    xy, cell = xy[keep], cell[keep].astype(int)
    world = np.c_[xy, np.zeros(len(xy)), np.ones(len(xy))] @ M.T
    o = world[:, :3] - [0.3, 0.2, 1.0]  # slanted rays from below the card
    d = np.tile([0.3, 0.2, 1.0], (len(o), 1))
    vis = visibility_brute(sc, o, d, 2.0)
    opaque = (cell[:, 0] + cell[:, 1]) % 2 == 0
    np.testing.assert_array_equal(vis, np.where(opaque, 0.0, 1.0))
    assert opaque.any() and (~opaque).any()


def test_linear_alpha_uv_interpolation():
    """BLEND with a smooth Linear alpha gradient: visibility = 1 - alpha at the crossing's uv."""
    px = np.zeros((4, 4, 4), np.uint8)
    i, j = np.meshgrid(np.arange(4), np.arange(4))
    px[..., 3] = 20 + 40 * i + 15 * j
    img = Image("grad", px, interpolation="Linear", extension="EXTEND")
    sc = _card_scene([Material("g", alpha_image=0, uv_transform=[[0.5, 0, 0.25], [0, 1, 0]])], [0], images=[img])
    rng = np.random.default_rng(7)
    xy = rng.uniform(0.02, 0.98, (300, 2))
    xy = xy[np.abs(xy[:, 0] - xy[:, 1]) > 0.01]
    o = np.c_[xy, np.full(len(xy), 1e-3)]
    d = np.tile([0.0, 0.0, 1.0], (len(o), 1))
    vis = visibility_brute(sc, o, d)
    want = 1.0 - sample_image(img, np.c_[0.5 * xy[:, 0] + 0.25, xy[:, 1]])[:, 3]
    np.testing.assert_allclose(vis, want, atol=1e-5)
    assert want.min() < 0.6 and want.max() > 0.75


def test_stacked_blend_cards():
    sc = _card_scene([Material("half", alpha=0.5)], [0, 0], card_z=(1.0, 2.0))
    o = np.array([[0.3, 0.6, 1e-3], [0.7, 0.2, 1e-3], [5.0, 5.0, 1e-3]])
    d = np.tile([0.0, 0.0, 1.0], (3, 1))
    np.testing.assert_array_equal(visibility_brute(sc, o, d), [0.25, 0.25, 1.0])
    np.testing.assert_array_equal(visibility_brute(sc, o, d, 1.5), [0.5, 0.5, 1.0])
    # same with an image alpha of 128: (1 - 128/255)^2
    px = np.zeros((2, 2, 4), np.uint8)
    px[..., 3] = 128
    sc2 = _card_scene([Material("img", alpha_image=0)], [0, 0], card_z=(1.0, 2.0), images=[Image("a", px)])
    np.testing.assert_allclose(visibility_brute(sc2, o, d), [(1 - 128 / 255) ** 2] * 2 + [1.0], rtol=1e-12)
    # one of the two stops shadows entirely
    sc3 = _card_scene([Material("half", alpha=0.5), Material("solid")], [0, 1], card_z=(1.0, 2.0))
    np.testing.assert_array_equal(visibility_brute(sc3, o, d), [0.0, 0.0, 1.0])


def test_one_instance_crossed_twice():
    """A single model of two stacked BLEND quads (a bush of cards): both crossings multiply."""
    q = _quad()
    v = np.concatenate([q.vertices, q.vertices + [0, 0, 1]])
    card2 = Model("two", v, np.concatenate([q.triangles, q.triangles + 4]), uvs=np.concatenate([q.uvs, q.uvs]))
    px = np.zeros((1, 2, 4), np.uint8)
    px[0, :, 3] = [51, 204]  # 0.2 | 0.8
    sc = Scene(models=[card2], instances=Instances(names=["b"], model_ids=[0], matrices=[_translate(z=1)],
                                                   material_ids=[0]),
               materials=[Material("m", alpha_image=0)], images=[Image("a", px, interpolation="Closest")])
    o = np.array([[0.3, 0.6, 0.0], [0.7, 0.2, 0.0], [0.3, 0.6, 0.0]])
    d = np.tile([0.0, 0.0, 1.0], (3, 1))
    np.testing.assert_allclose(visibility_brute(sc, o, d, [np.inf, np.inf, 1.5]), [0.8 * 0.8, 0.2 * 0.2, 0.8],
                               rtol=1e-12)


def test_clip_threshold():
    px = np.zeros((2, 2, 4), np.uint8)
    px[..., 3] = 128  # 0.50196
    o = np.array([[0.3, 0.6, 1e-3]])
    d = np.array([[0.0, 0.0, 1.0]])
    for thr, want in ((0.5, 0.0), (0.502, 1.0), (0.51, 1.0), (0.3, 0.0)):
        sc = _card_scene([Material("c", alpha_image=0, alpha_mode="CLIP", alpha_threshold=thr)], [0],
                         images=[Image("a", px)])
        assert visibility_brute(sc, o, d)[0] == want, thr
    # constant alpha: 0.5 < 0.5 is false (blocks), 0.5 < 0.6 passes
    for thr, want in ((0.5, 0.0), (0.6, 1.0)):
        sc = _card_scene([Material("c", alpha=0.5, alpha_mode="CLIP", alpha_threshold=thr)], [0])
        assert visibility_brute(sc, o, d)[0] == want, thr


def test_opaque_cases():
    o, d, _ = _cell_rays()
    # transparent_shadow off: the whole card shadows
    sc = _card_scene([Material("chk", alpha_image=0, transparent_shadow=False)], [0])
    np.testing.assert_array_equal(visibility_brute(sc, o, d), 0.0)
    assert not sc.alpha_models().any()
    # no material
    np.testing.assert_array_equal(visibility_brute(_card_scene([], [-1]), o, d), 0.0)
    # a material without alpha
    np.testing.assert_array_equal(visibility_brute(_card_scene([Material("m", color_image=0)], [0]), o, d), 0.0)
    # a card that casts no shadow: lit
    sc = _card_scene([], [-1], casts=[True, False])
    np.testing.assert_array_equal(visibility_brute(sc, o, d), 1.0)


def test_misses_and_invalid_rays():
    sc = _card_scene([Material("chk", alpha_image=0)], [0])
    o = np.array([[5.0, 5.0, 1e-3], [0.3, 0.6, 1.5], [0.3, 0.6, 1e-3], [0.3, 0.6, 1e-3], [np.nan, 0, 1]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0, 0, 1.0]])
    t = np.array([np.inf, np.inf, np.inf, 0.0, np.inf])
    np.testing.assert_array_equal(visibility_brute(sc, o, d, t), 1.0)
    assert visibility_brute(Scene(), o, d).tolist() == [1.0] * 5


def test_sphere_stays_opaque():
    ball = Model("ball", [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5]], [[0, 1, 2]])
    sc = Scene(models=[ball], materials=[Material("half", alpha=0.5)],
               instances=Instances(names=["s"], model_ids=[0], matrices=[_translate(z=3)], sphere=[True],
                                   material_ids=[0]))
    o = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    d = np.tile([0.0, 0.0, 1.0], (2, 1))
    np.testing.assert_array_equal(visibility_brute(sc, o, d), [0.0, 1.0])


def test_agrees_with_trace_brute_without_alpha():
    from tests.helpers.rays import random_rays
    from tests.helpers.scenes import random_scene

    rng = np.random.default_rng(11)
    sc = random_scene(rng, n_inst=60, tri_counts=(1, 12, 60))
    # materials that do not cut: none, alpha 1, transparent shadows off
    sc.materials = [Material("solid"), Material("noshadow", alpha=0.2, transparent_shadow=False)]
    sc.instances.material_ids = rng.integers(-1, 2, len(sc.instances)).astype(np.int32)
    assert not sc.alpha_models().any()
    o, d, t = random_rays(rng, sc, 3000)
    vis = visibility_brute(sc, o, d, t)
    occ = trace_brute(sc, o, d, t)
    assert set(np.unique(vis).tolist()) <= {0.0, 1.0}
    assert ((vis == 0) == occ).all() and occ.sum() > 300 and (~occ).sum() > 300


def test_alpha_only_lightens():
    """With cutting materials a ray is never darker than 0, nor shaded unless it is occluded."""
    from tests.helpers.rays import random_rays
    from tests.helpers.scenes import random_scene

    rng = np.random.default_rng(12)
    sc = random_scene(rng, n_inst=60, tri_counts=(1, 12, 60))
    for m in sc.models:
        m.uvs = rng.uniform(-1, 2, (m.triangle_count, 3, 2)).astype(np.float32)
    sc.images = [_checker("Linear"), _img()]
    sc.materials = [Material("blend", alpha_image=0), Material("clip", alpha_image=1, alpha_mode="CLIP"),
                    Material("half", alpha=0.5)]
    sc.instances.material_ids = rng.integers(-1, 3, len(sc.instances)).astype(np.int32)
    sc.validate(require_camera=False)
    o, d, t = random_rays(rng, sc, 3000)
    vis = visibility_brute(sc, o, d, t)
    occ = trace_brute(sc, o, d, t)
    assert ((vis >= 0) & (vis <= 1)).all()
    assert (vis[~occ] == 1).all()
    frac = (vis > 0) & (vis < 1)
    assert frac.sum() > 50 and (vis[occ] == 0).sum() > 50
