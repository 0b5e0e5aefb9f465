"""Light and shadow linking on the GPU (``core/gpu/linking.py``, ``shaders/common/linking.glsl``).

1. A linked light's hard masks equal the numpy oracle's (``trace_brute`` with the light's
   blockers; 0 on the surfaces its receiver set leaves out), and differ from the unlinked ones.
2. In every mode (ray traced hard on both structures, with light grids, medium quality, soft
   with packets, shadow maps) a linked light's mask equals that of the same scene where only its
   blockers cast and nothing is linked, on the surfaces it lights, and is 0 on the others; the
   unlinked sun is unchanged.
3. The lighting pass gives no light of a light to the surfaces outside its receiver set (the
   numpy lighting oracle, and an image with the light off there).
4. Changing the blocker or receiver sets of the instances changes the next frame's mask with an
   upload of the membership texture, no bake; a scene without linking compiles none of it.
"""
from dataclasses import replace

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle import lighting as lighting_reference
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.oracle.tracer import trace_brute
from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Scene
from hybrid_shadow_addon.core.scene.instances import ALL_SETS
from hybrid_shadow_addon.core.scene.linking import blockers, receivers
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import cube_model, look_at, plane_model, trs

pytestmark = [pytest.mark.gpu]

W, H = 160, 120
NAMES = ["ground", "statue", "pillar", "crate"]
STATUE, PILLAR = 1, 2


def linked_scene(radius=0.0, receivers_exclude=(STATUE,), blocker_include=(PILLAR,)) -> Scene:
    """A ground, a statue, a pillar and a crate under a point light (light set 0: all but
    ``receivers_exclude``; shadow set 0: only ``blocker_include``) and an unlinked sun."""
    mats = [trs((0, 0, 0), scale=(6, 6, 1)), trs((0, 0, 0.6), scale=(0.6, 0.6, 0.6)),
            trs((-1.6, 1.2, 1.5), scale=(0.3, 0.3, 1.5)), trs((1.8, -1.0, 0.5), rot_z=0.5, scale=(0.5, 0.5, 0.5))]
    light_sets = np.full(4, ALL_SETS, np.uint64)
    for i in receivers_exclude:
        light_sets[i] = ALL_SETS & ~np.uint64(1)
    shadow_sets = np.zeros(4, np.uint64)
    for i in blocker_include:
        shadow_sets[i] = np.uint64(1)
    inst = Instances(names=list(NAMES), model_ids=[0, 1, 1, 1], matrices=np.array(mats),
                     base_color=[(0.8, 0.8, 0.8, 1)] * 4, light_sets=light_sets, shadow_sets=shadow_sets)
    lights = [Light("lamp", "POINT", power=800.0, matrix=trs((0.6, -0.4, 4.0)), radius=radius,
                    receiver_set=0, blocker_set=0),
              Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=0.5, rot_x=-0.7))]
    cam = Camera(matrix=look_at((5.0, -6.5, 5.0), (0.0, 0.3, 0.6)), lens=32.0)
    return Scene(models=[plane_model(), cube_model()], instances=inst, lights=lights, camera=cam,
                 world_color=(0.05, 0.05, 0.05), resolution=(W, H))


def unlinked_equivalent(scene: Scene, li: int | None) -> Scene:
    """``scene`` without linking where only light ``li``'s blockers cast shadows (None: every
    caster)."""
    inst = scene.instances.take(np.arange(len(scene.instances)))
    if li is not None:
        inst.casts_shadow = blockers(scene, li)
    inst.light_sets[:] = ALL_SETS
    inst.shadow_sets[:] = ALL_SETS
    lights = [replace(light, receiver_set=-1, blocker_set=-1) for light in scene.lights]
    return replace(scene, instances=inst, lights=lights)


def pixel_instances(frame) -> np.ndarray:
    mat = frame.gbuffer.read("material")
    return np.round(mat[..., 2]).astype(np.int64)


@pytest.fixture
def fresh(gl_ctx):
    p = Pipeline(gl_ctx)
    yield p
    p.release()


def oracle_mask(frame, scene, baked, li, use_linking=True):
    """The numpy verdict over every covered pixel: 1 lit, 0 shadowed, facing away or not lit."""
    mask = frame.mask_array(li)
    rows, cols = np.nonzero(~np.isnan(mask))
    o, d, tmax, facing = shadow_rays(frame.gbuffer, (rows, cols), scene.lights[li], baked.origin)
    out = np.zeros(len(o), np.float32)
    block = blockers(scene, li) if use_linking else None
    occ = trace_brute(scene, o[facing], d[facing], tmax[facing], blockers=block)
    out[facing] = np.where(occ, 0.0, 1.0)
    if use_linking:
        out[~receivers(scene, li)[pixel_instances(frame)[rows, cols]]] = 0.0
    return (rows, cols), out


@pytest.mark.parametrize("structure", ["bvh", "grid"])
def test_hard_masks_equal_the_oracle(fresh, structure):
    scene = linked_scene()
    fresh.set_scene(scene, structure)
    frame = fresh.render(scene, Settings(hard=True, mode="raytrace", structure=structure), W, H)
    assert "HS_LINKING=1" in frame.stats["defines"]
    for li in frame.lights:
        px, ref = oracle_mask(frame, scene, fresh.baked, li)
        got = frame.mask_array(li)[px]
        assert (got != ref).sum() <= 0.001 * len(ref), (scene.lights[li].name, int((got != ref).sum()))
    # the lamp's linking changes its mask: the statue neither lit nor casting, the crate not casting
    px, unlinked = oracle_mask(frame, scene, fresh.baked, 0, use_linking=False)
    got = frame.mask_array(0)[px]
    assert (got != unlinked).sum() > 0.02 * len(got)
    statue = pixel_instances(frame)[px] == STATUE
    assert statue.sum() > 100 and (got[statue] == 0).all()


MODES = {
    "bvh": Settings(hard=True, mode="raytrace", structure="bvh", light_grid=False),
    "grid": Settings(hard=True, mode="raytrace", structure="grid"),
    "light grids": Settings(hard=True, mode="raytrace", structure="bvh"),
    "medium": Settings(hard=True, mode="raytrace", quality="medium"),
    "soft": Settings(mode="raytrace", samples=16),
    "shadow map": Settings(hard=True, mode="shadowmap", shadowmap_size=1024),
}


@pytest.mark.parametrize("mode", list(MODES))
def test_every_mode_equals_the_scene_of_the_blockers(gl_ctx, mode):
    settings = MODES[mode]
    scene = linked_scene(radius=0.3 if mode == "soft" else 0.0)
    masks = {}
    variants = (("linked", scene), ("plain", unlinked_equivalent(scene, 0)), ("full", unlinked_equivalent(scene, None)))
    for key, s in variants:
        p = Pipeline(gl_ctx)
        try:
            rp = p.shadow_pass("raytrace")
            rp.options = replace(rp.options, eager_light_grids=True)
            p.set_scene(s, settings.structure)
            frame = p.render(s, settings, W, H)
            if mode == "light grids":
                assert rp.hard.light_grids.last.get("lamp"), "the lamp traces its grid"
            masks[key] = {li: frame.mask_array(li) for li in frame.lights}
            inst = pixel_instances(frame)
        finally:
            p.release()
    lit = receivers(scene, 0)[inst]
    linked, ref = masks["linked"][0], masks["plain"][0]
    cov = ~np.isnan(ref)
    assert np.array_equal(np.nan_to_num(linked[cov & lit], nan=-1), np.nan_to_num(ref[cov & lit], nan=-1)), mode
    assert (linked[cov & ~lit] == 0).all() and (cov & ~lit).sum() > 100
    # the sun is not linked: every caster shadows it (the statue's shadow is not the pillar's alone)
    np.testing.assert_array_equal(masks["linked"][1], masks["full"][1])
    assert np.nansum(masks["linked"][1] != masks["plain"][1]) > 100


def test_lighting_leaves_out_what_a_light_does_not_light(fresh):
    scene = linked_scene()
    fresh.set_scene(scene)
    frame = fresh.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    gb = {k: frame.gbuffer.read(k) for k in ("position", "shading_normal", "albedo", "material")}
    masks = {li: frame.mask_array(li) for li in frame.lights}
    ref = lighting_reference.shade(scene, gb, masks)
    err = np.abs(frame.image.astype(np.float64) - ref) / np.maximum(1.0, np.abs(ref))
    assert err.max() < 1e-3
    # the statue is lit by the sun and the world alone: as an image whose lamp is off there
    statue = pixel_instances(frame) == STATUE
    no_lamp = lighting_reference.shade(replace(scene, lights=scene.lights[1:]), gb, {0: masks[1]})
    np.testing.assert_allclose(frame.image[statue][:, :3], no_lamp[statue][:, :3], rtol=1e-3, atol=1e-4)
    unlinked = lighting_reference.shade(unlinked_equivalent(scene, 0), gb, {0: np.ones_like(masks[0]), 1: masks[1]})
    assert np.abs(unlinked[statue] - no_lamp[statue]).max() > 0.05  # (the lamp faces the statue)


def test_unlit_light_is_dropped_from_unmasked_lights_too(fresh):
    scene = linked_scene()
    scene.lights[0].use_shadow = False  # (an unshadowed light: lit in the lighting pass's first loop)
    fresh.set_scene(scene)
    frame = fresh.render(scene, Settings(hard=True, mode="raytrace"), W, H)
    gb = {k: frame.gbuffer.read(k) for k in ("position", "shading_normal", "albedo", "material")}
    ref = lighting_reference.shade(scene, gb, {li: frame.mask_array(li) for li in frame.lights})
    assert np.abs(frame.image.astype(np.float64) - ref).max() < 1e-3


@pytest.mark.parametrize("mode", ["raytrace", "shadowmap"])
def test_changing_the_collections_updates_without_a_bake(fresh, mode):
    scene = linked_scene()
    settings = Settings(hard=True, mode=mode)
    fresh.set_scene(scene)
    first = fresh.render(scene, settings, W, H)
    before = first.mask_array(0)
    baked, uploads = fresh.baked, fresh.gpu.linking.uploads
    # the crate joins the blocker collection; the statue is lit again
    scene.instances.shadow_sets[3] = np.uint64(1)
    scene.instances.light_sets[STATUE] = ALL_SETS
    frame = fresh.render(scene, settings, W, H)
    after = frame.mask_array(0)
    assert fresh.baked is baked, "no bake"
    assert fresh.gpu.linking.uploads == uploads + 1
    inst = pixel_instances(frame)
    assert (after[inst == STATUE] > 0).sum() > 50 and (before[inst == STATUE] == 0).all()
    newly = (before == 1) & (after == 0)
    assert newly.sum() > 30, "the crate's shadow appears"
    # as a pipeline that bakes the changed scene afresh
    other = Pipeline(fresh.ctx)
    try:
        other.set_scene(scene)
        again = other.render(scene, settings, W, H).mask_array(0)
    finally:
        other.release()
    np.testing.assert_array_equal(np.nan_to_num(after, nan=-1), np.nan_to_num(again, nan=-1))


def test_a_scene_without_linking_compiles_none_of_it(fresh):
    scene = linked_scene()
    plain = unlinked_equivalent(scene, 0)
    plain.instances.casts_shadow[:] = True
    fresh.set_scene(plain)
    frame = fresh.render(plain, Settings(hard=True, mode="raytrace"), W, H)
    assert not any("HS_LINKING" in d for d in frame.stats["defines"])
    assert fresh.gpu.linking.uploads == 0
