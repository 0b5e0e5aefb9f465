"""See-through panes against Cycles (``see_through``: Principled Alpha 0.3 and 0.7 over a lit
checker ground with the boxes' and the panes' shadows; real bpy renders, 160x120, hard sun).

Cycles' per-light visibility through a pane is lit / unshadowed of its Diffuse Direct pass: the
light of the pane and of what lies behind it, weighted by alpha and 1 - alpha, by their albedos
(the pass is divided by the Diffuse Color) and their irradiance. One frame (the cut at 0.5)
shows one of the two surfaces per pixel; the sub-frames of stochastic transparency, weighted as
Cycles weighs them, converge to Cycles' visibility (64 samples at the pixel centre: one sample
would pick the pane or what lies behind it at random).
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W, H = 160, 120
PANES = ("Pane 0.3", "Pane 0.7")
#: Cycles samples per pixel (all at its centre): one picks the pane or what lies behind it at
#: random, as our sub-frames do; many average the two
SAMPLES = 64


@pytest.fixture(scope="module")
def panes():
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    bscene = open_scene("see_through")
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    ref = render_reference(bscene, resolution=(W, H), samples=SAMPLES)
    return scene, ref.visibility["Sun"]


def pane_pixels(scene):
    """(H, W) bool: pixels whose camera ray crosses a pane (level quads 2.8 x 3.6), 1 cm inside."""
    o, d = scene.camera.pixel_rays(W, H)
    sel = np.zeros((H, W), bool)
    for name in PANES:
        m = scene.instances.matrices[scene.instances.names.index(name)]
        t = (m[2, 3] - o[..., 2]) / d[..., 2]
        p = o + t[..., None] * d
        sel |= (t > 0) & (np.abs(p[..., 0] - m[0, 3]) < 1.39) & (np.abs(p[..., 1] - m[1, 3]) < 1.79)
    return sel


def cycles_weighted(pipeline, scene, n):
    """Our visibility of the sun as Cycles' reference measures it: lit / unshadowed of its Diffuse
    Direct pass, which sums the blended surfaces' light weighted by their alpha share, albedo
    (per channel: the pass is divided by the Diffuse Color) and irradiance. Over ``n`` sub-frames
    (one per viewport render: each's G-buffer and mask), or one frame cut at 0.5 for ``n`` 1."""
    li = [light.name for light in scene.lights].index("Sun")
    to_sun = -scene.lights[li].direction
    s = Settings(hard=True, structure="bvh", transparency_samples=n, accumulate=True)
    pipeline.reset_history()
    num = np.zeros((H, W, 3))
    den = np.zeros((H, W, 3))
    prev = np.zeros((H, W))
    for k in range(n):
        f = pipeline.render(scene, s, W, H)
        mean = np.nan_to_num(f.mask_array(li))
        mask, prev = (k + 1) * mean - k * prev, mean  # this sub-frame's (pixels covered in all)
        gb = f.gbuffer
        irr = np.maximum(gb.read("normal")[..., :3] @ to_sun, 0.0) * (gb.read("position")[..., 3] > 0)
        w = gb.read("albedo")[..., :3] * irr[..., None]
        num += w * mask[..., None]
        den += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((den > 0).all(axis=-1), (num / den).mean(axis=-1), np.nan)


def errors(mask, ref, sel):
    ok = np.isfinite(mask) & np.isfinite(ref)
    d = np.abs(mask - ref)
    return float(d[ok & sel].mean()), float(d[ok].mean()), int((ok & sel).sum())


def test_accumulated_masks_come_closer_to_cycles(pipeline, panes):
    """Over the pane pixels valid in both, the error of one frame (one surface per pixel) falls
    by more than half with 16 sub-frames, to within their stratified sampling's noise; over
    the whole image the plain masks (each sub-frame's alike) come closer too."""
    scene, ref = panes
    pipeline.set_scene(scene, "bvh")
    sel = pane_pixels(scene)
    got = {n: errors(cycles_weighted(pipeline, scene, n), ref, sel) for n in (1, 16)}
    plain = {}
    for n in (1, 16):
        f = pipeline.render(scene, Settings(hard=True, structure="bvh", transparency_samples=n), W, H)
        plain[n] = errors(f.mask_array(f.lights[0]), ref, sel)
    (one_pane, one_all, n_pane), (acc_pane, acc_all, _) = got[1], got[16]
    print(f"\nMAE against Cycles ({SAMPLES} samples), pane pixels ({n_pane}): one frame {one_pane:.4f}, "
          f"16 sub-frames {acc_pane:.4f}; all valid pixels: {one_all:.4f} -> {acc_all:.4f}; the plain "
          f"averaged masks: pane pixels {plain[1][0]:.4f} -> {plain[16][0]:.4f}, all {plain[1][1]:.4f} -> "
          f"{plain[16][1]:.4f}")
    assert n_pane > 1500
    assert one_pane > 0.04  # the cut at 0.5 shows one surface where Cycles blends two
    assert acc_pane < 0.5 * one_pane and acc_pane < 0.02
    assert acc_all < one_all
    assert plain[16][0] < plain[1][0] and plain[16][1] < plain[1][1]
