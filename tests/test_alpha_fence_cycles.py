"""A chain-link fence seen from a distance (``fence_far``: wire texels smaller than the pixels)
against Cycles (real bpy renders): the camera's coverage and the shadow rays' cut read the image
at the hit, at level 0 with the Image Texture node's interpolation, as Cycles does.

1. Ray-traced ``high``, every light hard, for each interpolation (Linear, Closest, Cubic; Smart
   is Cubic): the sun's mask within 0.5 % of the valid pixels (``compare``'s mismatch), and
   within 0.05 % where the pixel centre's camera ray crosses no fractional alpha (the rest are
   pixels Cycles blends from the wire and the ground behind it, see tests/test_alpha_cycles.py).
2. The bar tells coverage read at the hit from coverage read from a mip level: the same fence
   whose alpha is read from its 4x4 reduction (about the level the colour's mip mapping picks
   there) misses it twice over.
"""
import copy

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake.materials import mip_chain
from hybrid_shadow_addon.core.scene import Image
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error
from tests.helpers.rays import mixed_pixels

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W, H = 320, 240
LIMIT_PCT = 0.5
SINGLE_SURFACE_LIMIT_PCT = 0.05
INTERPOLATIONS = ("Linear", "Closest", "Cubic")

_loaded = {}


def load(interpolation):
    """``fence_far`` with the wire image read with ``interpolation``: the exported scene and its
    Cycles visibility per light (hard), once per module."""
    if interpolation not in _loaded:
        import bpy

        from hybrid_shadow_addon.blender.cycles_reference import render_reference
        from hybrid_shadow_addon.blender.export import export_depsgraph
        from hybrid_shadow_addon.blender.load import open_scene

        bscene = open_scene(f"fence_far:interpolation={interpolation}")
        scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
        _loaded[interpolation] = scene, render_reference(bscene, resolution=(W, H))
    return _loaded[interpolation]


def sun_errors(pipeline, scene, ref):
    """(all, single-surface) :class:`mask_error` of the sun's ray-traced high mask, and the frame."""
    pipeline.set_scene(scene, "bvh")
    f = pipeline.render(scene, Settings(mode="raytrace", quality="high", structure="bvh", hard=True), W, H)
    (li,) = [i for i in f.lights if scene.lights[i].name == "Sun"]
    ours, theirs = f.mask_array(li), ref.visibility["Sun"]
    single = mask_error(np.where(mixed_pixels(scene, f), np.nan, theirs), ours)
    return mask_error(theirs, ours), single, f


@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
def test_sun_mask_matches_cycles(pipeline, interpolation):
    scene, ref = load(interpolation)
    assert [i.interpolation for i in scene.images] == [interpolation]
    e, single, f = sun_errors(pipeline, scene, ref)
    assert e.valid_pixels > 0.5 * W * H, e
    theirs = ref.visibility["Sun"]
    assert (theirs[np.isfinite(theirs)] < 0.5).sum() > 1000, "the reference shows the fence's shadow"
    fence = scene.instances.names.index("Fence")
    inst = np.round(f.gbuffer.read("material")[..., 2]).astype(np.int64)
    assert (inst == fence).sum() > 0.05 * W * H, "the fence fills a good part of the view"
    assert e.mismatch_pct <= LIMIT_PCT, f"{interpolation}: {e.mismatch_pct:.3f}% ({e.mismatch_pixels}/{e.valid_pixels})"
    assert single.valid_pixels > 0.8 * e.valid_pixels
    assert single.mismatch_pct <= SINGLE_SURFACE_LIMIT_PCT, (
        f"{interpolation}: {single.mismatch_pct:.3f}% ({single.mismatch_pixels}/{single.valid_pixels}) where the "
        "camera ray sees one surface")


def test_smart_is_read_as_cubic():
    import bpy

    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    open_scene("fence_far:interpolation=Smart")
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H))
    assert [i.interpolation for i in scene.images] == ["Cubic"]


def test_alpha_from_a_mip_level_misses_the_bar(pipeline):
    scene, ref = load("Linear")
    coarse = copy.deepcopy(scene)
    img = coarse.images[0]
    level = mip_chain(img.pixels, img.srgb, 4)[3]  # 32 -> 4 texels a diamond
    coarse.images[0] = Image(img.name, level, srgb=img.srgb, extension=img.extension, interpolation=img.interpolation)
    e, _, _ = sun_errors(pipeline, coarse, ref)
    assert e.mismatch_pct > 2 * LIMIT_PCT, e
