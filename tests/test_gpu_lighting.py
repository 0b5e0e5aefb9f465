"""Lighting pass against the numpy reference; sRGB/PNG output; edge-aware upsample; settings."""
import dataclasses
import math
import struct
import zlib

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.frame import mask_source_pixels, read_mask
from hybrid_shadow_addon.core.gpu.lights import light_table, lighting_defines
from hybrid_shadow_addon.core.gpu.targets import create_mask_texture
from hybrid_shadow_addon.core.image import to_srgb8, write_png
from hybrid_shadow_addon.core.oracle import lighting as lighting_reference
from hybrid_shadow_addon.core.scene import Light
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.rays import interior
from tests.helpers.scenes import all_lights, basic_scene, look_at

pytestmark = [pytest.mark.gpu]

W, H = 160, 120


def gbuffer_arrays(gb):
    return {k: gb.read(k) for k in ("position", "shading_normal", "albedo", "material")}


def assert_close(img, ref, tol=1e-3):
    err = np.abs(img.astype(np.float64) - ref) / np.maximum(1.0, np.abs(ref))
    assert err.max() < tol, (err.max(), np.unravel_index(err.argmax(), err.shape))


@pytest.mark.parametrize("camera_type", ["PERSP", "ORTHO"])
def test_none_mode_matches_numpy(pass_rig, camera_type):
    lights = all_lights()
    lights[2].spot_blend = 0.4
    lights[1].color = np.float32([1.0, 0.6, 0.3])
    scene = basic_scene(lights=lights, camera_type=camera_type, with_sphere=True)
    gb = pass_rig.gbuffer(scene, W, H)
    masks = pass_rig.none(scene, gb, Settings(mode="none"))
    pass_rig.light(scene, gb, masks)
    img = pass_rig.image()
    ref = lighting_reference.shade(scene, gbuffer_arrays(gb))
    assert_close(img, ref)
    assert img[..., :3].max() > 0.05  # really lit
    # no masks at all gives the same picture
    pass_rig.light(scene, gb, None)
    assert_close(pass_rig.image(), ref)


def test_each_light_type_alone_and_masks_multiply(pass_rig):
    for light in all_lights():
        light.spot_blend = 0.0 if light.type == "SPOT" else light.spot_blend
        scene = basic_scene(lights=[light])
        gb = pass_rig.gbuffer(scene, W, H)
        pass_rig.light(scene, gb, None, Settings(specular=False))
        img = pass_rig.image()
        ref = lighting_reference.shade(scene, gbuffer_arrays(gb), use_specular=False)
        assert_close(img, ref)
        ambient = lighting_reference.shade(scene.__class__(**{**scene.__dict__, "lights": []}), gbuffer_arrays(gb))
        assert (img[..., :3] - ambient[..., :3]).max() > 0.02, light.type
    # shadow-map masks: GPU lighting with masks == numpy lighting with the same masks read back
    scene = basic_scene(lights=all_lights())
    gb = pass_rig.gbuffer(scene, W, H)
    masks = pass_rig.shadowmap(scene, gb, Settings(mode="shadowmap", shadowmap_size=512))
    pass_rig.light(scene, gb, masks)
    arrays = {k: read_mask(v) for k, v in masks.items()}
    ref = lighting_reference.shade(scene, gbuffer_arrays(gb), arrays)
    assert_close(pass_rig.image(), ref)


def _area_kinds():
    """Area lights of every kind the lighting pass compiles apart, with the define each needs."""
    m = look_at((0.5, -3.0, 4.0), (0, 0, 0))
    return [(Light("rect", "AREA", power=300.0, matrix=m, size=0.8, size_y=0.3, area_shape="RECTANGLE"),
             "HS_LIT_AREA_RECT"),
            (Light("disk", "AREA", power=300.0, matrix=m, size=0.9, area_shape="DISK"), "HS_LIT_AREA_ELLIPSE"),
            (Light("cone", "AREA", power=300.0, matrix=m, size=0.8, area_shape="SQUARE", spread=math.radians(70)),
             "HS_LIT_AREA_SPREAD"),
            (Light("dot", "AREA", power=300.0, matrix=m, size=0.0), "HS_LIT_AREA_POINT")]


def test_lighting_compiles_only_the_kinds_of_light_the_scene_has(pass_rig):
    """Each kind alone builds the variant of just that kind (``lighting_defines`` of the table)
    and matches the numpy oracle; every kind together matches it too. A kind compiled out
    contributes nothing, so a define missing from the set fails the oracle check."""
    kinds = [(light, {"SUN": "HS_LIT_SUN", "POINT": "HS_LIT_POINT", "SPOT": "HS_LIT_SPOT"}[light.type])
             for light in all_lights()[:3]] + _area_kinds()
    for light, define in kinds:
        scene = basic_scene(lights=[light])
        assert lighting_defines(light_table([light])) == {define: 1}, light.name
        gb = pass_rig.gbuffer(scene, W, H)
        pass_rig.light(scene, gb, None)
        img = pass_rig.image()
        # a spread is integrated by 8 x 8 Gauss-Legendre nodes on the GPU, 16 x 16 by the oracle
        assert_close(img, lighting_reference.shade(scene, gbuffer_arrays(gb)), 1e-2 if light.spread < 3 else 1e-3)
        ambient = lighting_reference.shade(scene.__class__(**{**scene.__dict__, "lights": []}), gbuffer_arrays(gb))
        assert (img[..., :3] - ambient[..., :3]).max() > 0.02, light.name
    lights = [k[0] for k in kinds]
    assert set(lighting_defines(light_table(lights))) == {k[1] for k in kinds}
    scene = basic_scene(lights=lights)
    gb = pass_rig.gbuffer(scene, W, H)
    pass_rig.light(scene, gb, None)
    assert_close(pass_rig.image(), lighting_reference.shade(scene, gbuffer_arrays(gb)), 1e-2)


def test_more_masked_lights_than_one_batch(pass_rig):
    lights = [Light(f"p{i}", "POINT", power=40.0 + 5 * i, matrix=np.eye(4)) for i in range(11)]
    for i, light in enumerate(lights):
        light.matrix[:3, 3] = (np.cos(i), np.sin(i), 3.0 + 0.1 * i)
    scene = basic_scene(lights=lights)
    gb = pass_rig.gbuffer(scene, W, H)
    rng = np.random.default_rng(1)
    mask_arrays = {i: rng.random((H, W)).astype(np.float32) for i in range(0, 11, 1) if i != 4}
    masks = {}
    for i, a in mask_arrays.items():
        t = create_mask_texture(pass_rig.ctx, W, H)
        t.write(np.ascontiguousarray(a[::-1]).tobytes())  # numpy top row -> GL top row
        masks[i] = t
    pass_rig.light(scene, gb, masks)
    assert pass_rig.lighting.batches == 2
    ref = lighting_reference.shade(scene, gbuffer_arrays(gb), mask_arrays)
    assert_close(pass_rig.image(), ref)
    for t in masks.values():
        t.release()


def test_each_kind_in_a_loop_of_its_own(pass_rig):
    """Sized area lights and the other lights are lit in loops of their own (masked and unmasked,
    over batches that hold both kinds): lights interleaved in the scene's order match the numpy
    oracle, whatever batch and loop they land in."""
    areas = [k[0] for k in _area_kinds()]
    points = [Light(f"p{i}", "POINT", power=30.0 + i, matrix=np.eye(4)) for i in range(9)]
    for i, light in enumerate(points):
        light.matrix[:3, 3] = (np.cos(i), np.sin(i), 3.0 + 0.1 * i)
    lights = []
    for i, light in enumerate(all_lights()[:3] + points):  # an area light after every third other light
        lights.append(light)
        if i % 3 == 2 and areas:
            lights.append(areas.pop(0))
    lights += areas
    scene = basic_scene(lights=lights)
    gb = pass_rig.gbuffer(scene, W, H)
    rng = np.random.default_rng(3)
    # unmasked: a rectangle and an ellipse among other lights (the masked batches: other lights and
    # a spread); then an area light of size 0 and a spot (the second batch: every kind)
    for unmasked in ({1, 3, 7}, {2, 15}):
        mask_arrays = {i: rng.random((H, W)).astype(np.float32) for i in range(len(lights)) if i not in unmasked}
        masks = {}
        for i, a in mask_arrays.items():
            t = create_mask_texture(pass_rig.ctx, W, H)
            t.write(np.ascontiguousarray(a[::-1]).tobytes())
            masks[i] = t
        pass_rig.light(scene, gb, masks)
        assert pass_rig.lighting.batches == 2
        img = pass_rig.image()
        # (a spread is integrated by 8 x 8 Gauss-Legendre nodes on the GPU, 16 x 16 by the oracle)
        assert_close(img, lighting_reference.shade(scene, gbuffer_arrays(gb), mask_arrays), 1e-2)
        assert img[..., :3].max() > 0.05
        for t in masks.values():
            t.release()


def test_srgb_and_png(tmp_path):
    x = np.array([[[0.0, 0.0031308, 0.5, 1.0], [2.0, -1.0, np.nan, 0.5]]], np.float32)
    out = to_srgb8(x)
    assert out.dtype == np.uint8 and out.shape == (1, 2, 4)
    assert list(out[0, 0, :3]) == [0, 10, 188] and out[0, 0, 3] == 255
    assert list(out[0, 1, :3]) == [255, 0, 0] and out[0, 1, 3] == 128
    img = np.random.default_rng(0).integers(0, 256, (5, 7, 4), dtype=np.uint8)
    p = tmp_path / "x.png"
    write_png(p, img)
    data = p.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    assert (w, h) == (7, 5)
    n = struct.unpack(">I", data[33:37])[0]
    raw = np.frombuffer(zlib.decompress(data[41:41 + n]), np.uint8).reshape(5, 1 + 7 * 4)
    assert np.array_equal(raw[:, 1:].reshape(5, 7, 4), img)


@pytest.mark.parametrize("quality", ["medium", "low"])
def test_edge_aware_upsample_beats_nearest(pass_rig, quality):
    """A low-res mask sampled from an exact full-res mask: the bilateral upsample reproduces the
    full-res mask better than nearest, especially across geometric edges."""
    scene = basic_scene(lights=all_lights()[:1], with_sphere=True)
    gb = pass_rig.gbuffer(scene, W, H)
    settings = Settings(mode="shadowmap", quality=quality, shadowmap_size=1024, pcf=0)
    full = read_mask(pass_rig.shadowmap(scene, gb, settings)[0])
    mw, mh = settings.mask_size(W, H)
    rows, cols = mask_source_pixels((mw, mh), (W, H), settings.mask_scale)
    assert rows.shape == (mh, mw)
    low = full[rows, cols].astype(np.float32)
    tex = create_mask_texture(pass_rig.ctx, mw, mh)
    tex.write(np.ascontiguousarray(low[::-1]).tobytes())
    cov = gb.coverage()
    # read_mask maps a reduced mask onto its source pixels' coverage
    assert np.array_equal(np.isnan(read_mask(tex, gb)), ~cov[rows, cols])
    up = read_mask(pass_rig.upsample({0: tex}, gb, settings)[0], gb)
    near = read_mask(pass_rig.upsample({0: tex}, gb, settings.replace(upsample="nearest"))[0], gb)
    inst = gb.read("material")[..., 2]
    edges = cov & ~interior(np.where(cov, inst, -1))
    err_up = np.abs(up - full)[cov]
    err_near = np.abs(near - full)[cov]
    assert err_up.mean() < 1.3 * err_near.mean()  # a blend vs a hard edge: no worse overall
    assert np.abs(up - full)[edges].mean() < 0.9 * np.abs(near - full)[edges].mean()
    assert np.isnan(up[~cov]).all()
    tex.release()


def test_settings_validation():
    s = Settings()
    assert s.mode == "raytrace" and s.mask_scale == 1 and s.max_shadowed_lights is None
    assert Settings(quality="low").mask_size(641, 361) == (161, 91)
    assert Settings.from_dict({"mode": "none", "pcf": 2}).pcf == 2
    bad = [dict(mode="fast"), dict(quality="ultra"), dict(max_distance=-1.0), dict(max_distance=float("nan")),
           dict(max_shadowed_lights=-1), dict(max_shadowed_lights=1.5), dict(interlace="yes"),
           dict(shadowmap_size=8), dict(pcf=-1), dict(upsample="cubic")]
    for kw in bad:
        with pytest.raises(ValueError) as ei:
            Settings(**kw)
        assert list(kw)[0] in str(ei.value) and "\n" not in str(ei.value)
    with pytest.raises(ValueError, match="unknown setting"):
        Settings.from_dict({"modes": "none"})
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.mode = "none"  # frozen


def test_light_table_in_a_uniform_block_or_a_texture(pass_rig, monkeypatch):
    """The light table in a uniform block (where it fits) and in a texture light bit-identically,
    with every kind of light, masked and unmasked; a table too big for the driver's block takes
    the texture."""
    lights = all_lights()[:3] + [k[0] for k in _area_kinds()]
    lights += [Light(f"p{i}", "POINT", power=30.0 + i, matrix=np.eye(4)) for i in range(10)]
    for i, light in enumerate(lights[-10:]):
        light.matrix[:3, 3] = (np.cos(i), np.sin(i), 3.0 + 0.1 * i)
    scene = basic_scene(lights=lights)
    gb = pass_rig.gbuffer(scene, W, H)
    rng = np.random.default_rng(2)
    masks = {}
    for i in range(0, len(lights), 2):  # every other light masked: unmasked ones in the first batch
        t = create_mask_texture(pass_rig.ctx, W, H)
        t.write(rng.random((H, W)).astype(np.float32).tobytes())
        masks[i] = t
    got = {}
    for on in (True, False):
        monkeypatch.setattr(pass_rig.lighting, "uniform_block", on)
        pass_rig.light(scene, gb, masks)
        got[on] = pass_rig.image().copy()
        assert (pass_rig.lighting._light_block(light_table(lights)) is not None) == on
    assert np.array_equal(got[True], got[False])
    assert got[True][..., :3].max() > 0.05
    # a driver whose blocks are too small for the table: the texture, the same image
    monkeypatch.setattr(pass_rig.lighting, "uniform_block", True)
    monkeypatch.setitem(pass_rig.ctx.info, "GL_MAX_UNIFORM_BLOCK_SIZE", 16 * 5 * 8)
    assert pass_rig.lighting._light_block(light_table(lights)) is None
    pass_rig.light(scene, gb, masks)
    assert np.array_equal(pass_rig.image(), got[False])
    for t in masks.values():
        t.release()
