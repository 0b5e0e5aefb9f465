"""Alpha-cut shadows and textured albedo on ``alpha_cards`` against Cycles (real bpy renders).

1. Ray-traced ``high`` (grid and bvh), every light hard, against Cycles' per-light hard
   visibility: within 0.5 % of the valid pixels per light, with the mismatch of ``compare``
   (``tools/metrics.py``: |ours - Cycles| > 0.5 over the pixels valid in both).

   Nearly all of those mismatches sit at *mixed* pixels: the pixel centre's camera ray crosses a
   surface of fractional alpha (the one-texel bilinear ramp on a leaf's edge or a fence wire's),
   so Cycles' pixel is the alpha blend of that surface and the one behind it, while our G-buffer
   keeps one of the two (alpha >= 0.5). The reference's visibility is lit / unshadowed of the
   blend: where one of the two surfaces gets no light at all (a card or the fence lit from
   behind, ground outside the spot's cone) it is the *other* surface's visibility, so we call
   shadowed (back-facing) what Cycles calls lit. The pixels where the camera ray sees one surface
   only (found with the numpy oracle, :func:`mixed_pixels`) must agree to 0.05 %.
   Mixed pixels are a share of the cut cards' and the fence's area (the ramp is one texel of
   the image, sampled at pixel centres), not of their outline, so a higher resolution does not
   shrink them: the 0.5 % holds at the scene's own 320x240 (sun 0.30 %, spot 0.43 %) but not at
   every framing (spot 0.51 % at 160x120, 0.65 % at 640x360, see BENCHMARKS.md).
   ``alpha_cards:closest=1`` (binary alpha, Closest: no pixel blends two surfaces) holds the
   0.1 % of the other scenes with compare's own definition.
2. The G-buffer's albedo equals Cycles' Diffuse Color pass (row 0 = top in both) away from cut
   edges and silhouettes.
3. ``alpha_cards:opaque=1`` compiles no alpha code, shadows more pixels than the cut cards and
   matches Cycles within 0.1 %.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error
from tests.helpers import rays

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W, H = 320, 240
LIMIT_PCT = 0.5  # all valid pixels, as compare counts them
SINGLE_SURFACE_LIMIT_PCT = 0.05  # valid pixels whose camera ray crosses no fractional alpha
STRUCTURES = ("bvh", "grid")


def _load(arg):
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_diffuse_color, render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    bscene = open_scene(arg)
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    ref = render_reference(bscene, resolution=(W, H))  # hard lights
    albedo = render_diffuse_color(bscene, (W, H))
    return scene, ref, albedo


@pytest.fixture(scope="module")
def cards():
    """The alpha scene, its Cycles visibility per light and its Diffuse Color pass."""
    return _load("alpha_cards")


@pytest.fixture(scope="module")
def opaque_cards():
    return _load("alpha_cards:opaque=1")


@pytest.fixture(scope="module")
def binary_cards():
    return _load("alpha_cards:closest=1")


def render(pipeline, scene, structure="bvh"):
    """A ray-traced high frame of ``scene``, every light hard, baked afresh with ``structure``
    (the module's pipeline otherwise keeps the bake of the last scene)."""
    pipeline.set_scene(scene, structure)
    return pipeline.render(scene, Settings(mode="raytrace", quality="high", structure=structure, hard=True), W, H)


_mixed = {}


def mixed_pixels(scene, frame) -> np.ndarray:
    """:func:`tests.helpers.rays.mixed_pixels`, once per scene (the G-buffer does not depend on
    the structure)."""
    if id(scene) not in _mixed:
        _mixed[id(scene)] = rays.mixed_pixels(scene, frame)
    return _mixed[id(scene)]


def interior(mask: np.ndarray) -> np.ndarray:
    """``mask`` pixels whose 8 neighbours are in ``mask`` too."""
    p = np.pad(mask, 1, constant_values=False)
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out &= p[1 + dy:1 + dy + mask.shape[0], 1 + dx:1 + dx + mask.shape[1]]
    return out


# ---------------------------------------------------------------------------------------------
# 1. shadows against Cycles
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("structure", STRUCTURES)
def test_raytraced_high_matches_cycles(pipeline, cards, structure):
    scene, ref, _ = cards
    f = render(pipeline, scene, structure)
    assert "HS_HAS_ALPHA=1" in f.stats["defines"]
    mixed = mixed_pixels(scene, f)
    assert 0 < mixed.sum() < 0.05 * W * H
    names = []
    for li in f.lights:
        name = scene.lights[li].name
        names.append(name)
        ours, theirs = f.mask_array(li), ref.visibility[name]
        e = mask_error(theirs, ours)
        assert e.valid_pixels > 0.4 * W * H, (name, e)
        valid = np.isfinite(theirs) & np.isfinite(ours)
        assert (theirs[valid] < 0.5).sum() > 1000, f"{name}: the reference shows a shadow"
        assert e.mismatch_pct <= LIMIT_PCT, \
            f"{name}/{structure}: {e.mismatch_pct:.3f}% ({e.mismatch_pixels}/{e.valid_pixels})"
        single = mask_error(np.where(mixed, np.nan, theirs), ours)
        assert single.valid_pixels > 0.95 * e.valid_pixels
        assert single.mismatch_pct <= SINGLE_SURFACE_LIMIT_PCT, (
            f"{name}/{structure}: {single.mismatch_pct:.3f}% ({single.mismatch_pixels}/{single.valid_pixels}) "
            "where the camera ray sees one surface")
    assert sorted(names) == ["Spot", "Sun"]


def test_both_structures_agree(pipeline, cards):
    scene = cards[0]
    masks = {}
    for s in STRUCTURES:
        f = render(pipeline, scene, s)
        masks[s] = {li: f.mask_array(li) for li in f.lights}
    a, b = (masks[s] for s in STRUCTURES)
    assert a.keys() == b.keys()
    for li in a:
        same = (a[li] == b[li]) | (np.isnan(a[li]) & np.isnan(b[li]))
        assert same.mean() > 0.9999, (li, same.mean())


@pytest.mark.parametrize("structure", STRUCTURES)
def test_binary_alpha_matches_cycles_everywhere(pipeline, binary_cards, structure):
    scene, ref, _ = binary_cards
    f = render(pipeline, scene, structure)
    assert "HS_HAS_ALPHA=1" in f.stats["defines"]
    assert not mixed_pixels(scene, f).any()
    for li in f.lights:
        name = scene.lights[li].name
        e = mask_error(ref.visibility[name], f.mask_array(li))
        assert e.valid_pixels > 0.4 * W * H
        assert e.mismatch_pct <= 0.1, \
            f"{name}/{structure}: {e.mismatch_pct:.3f}% ({e.mismatch_pixels}/{e.valid_pixels})"


# ---------------------------------------------------------------------------------------------
# 2. albedo against Cycles' Diffuse Color
# ---------------------------------------------------------------------------------------------
def test_gbuffer_albedo_matches_cycles_diffuse_color(pipeline, cards):
    scene, _, theirs = cards
    f = render(pipeline, scene)
    albedo = f.gbuffer.read("albedo")[..., :3]
    covered = f.gbuffer.coverage()
    # row order: the G-buffer's arrays and the masks share it (row 0 = top) ...
    assert np.array_equal(np.isfinite(f.mask_array(f.lights[0])), covered)
    # ... and so does Cycles' pass (its coverage agrees but on silhouettes)
    cycles_covered = np.isfinite(theirs[..., 0])
    assert (covered != cycles_covered).mean() < 0.01
    inst = np.round(f.gbuffer.read("material")[..., 2]).astype(np.int64)
    same_instance = np.ones(covered.shape, bool)
    p = np.pad(inst, 1, constant_values=-2)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            same_instance &= p[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] == inst
    use = interior(covered & cycles_covered & ~mixed_pixels(scene, f)) & same_instance
    assert use.sum() > 0.5 * W * H
    diff = np.abs(albedo - theirs)[use]
    assert np.median(diff) < 0.01, np.percentile(diff, [50, 90, 99])
    # the leaves (colour and alpha from one image, mip-mapped here, point-sampled by Cycles)
    leaves = [i for i, n in enumerate(scene.instances.names) if n.startswith(("Card", "Leaf"))]
    leaf = use & np.isin(inst, leaves)
    assert leaf.sum() > 500
    assert np.median(np.abs(albedo - theirs)[leaf]) < 0.03
    # upside down they would not match
    flipped = np.abs(albedo[::-1] - theirs)[use & use[::-1]]
    assert np.median(flipped) > 10 * max(np.median(diff), 1e-3)


# ---------------------------------------------------------------------------------------------
# 3. the opaque variant
# ---------------------------------------------------------------------------------------------
def test_opaque_variant_compiles_no_alpha_and_shadows_more(pipeline, cards, opaque_cards):
    shadowed = {}
    for label, (scene, _, _) in (("alpha", cards), ("opaque", opaque_cards)):
        f = render(pipeline, scene)
        defines = f.stats["defines"]
        assert any(d.startswith("HS_HAS_ALPHA") for d in defines) == (label == "alpha"), (label, defines)
        shadowed[label] = {scene.lights[li].name: int((f.mask_array(li) < 0.5).sum()) for li in f.lights}
    assert shadowed["opaque"].keys() == shadowed["alpha"].keys()
    for name, n in shadowed["alpha"].items():
        assert shadowed["opaque"][name] > n * 1.05, (name, shadowed)


def test_opaque_variant_matches_cycles(pipeline, opaque_cards):
    """Without alpha no pixel blends two surfaces: the 0.1 % of the other built-in scenes."""
    scene, ref, _ = opaque_cards
    f = render(pipeline, scene)
    for li in f.lights:
        name = scene.lights[li].name
        e = mask_error(ref.visibility[name], f.mask_array(li))
        assert e.valid_pixels > 0.4 * W * H
        assert e.mismatch_pct <= 0.1, f"{name}: {e.mismatch_pct:.3f}% ({e.mismatch_pixels}/{e.valid_pixels})"
