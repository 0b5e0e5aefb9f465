"""The two-level BVH's 4-wide layout ([wide], ``BVHConfig.wide``): the packed walk of the
numpy oracle against the binary walk and brute force, its blocks through moves and model edits,
the GLSL walk (stack overflow included) against the oracle, and the masks of both trace paths
against the binary layout's, bit for bit."""
import dataclasses

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, BVHConfig, bake_scene
from hybrid_shadow_addon.core.bake.structures.wide import STRIDE, WIDTH, WideIndex
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.oracle.tracer.wide import trace_wide, trace_wide_packed
from hybrid_shadow_addon.core.scene import Instances, Scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.bake import assert_report_covers, snapshot
from tests.helpers.rays import random_rays, terrain_rays
from tests.helpers.scenes import adversarial_scene, blob_model, random_scene, terrain_model

pytestmark = [pytest.mark.gpu]

WIDE = BakeConfig(structure="bvh", bvh=BVHConfig(wide=True))


def test_packed_walk_answers_as_binary_and_brute_with_fewer_fetches():
    """Meshes, spheres, far misses and the adversarial set: the packed walk's answers are brute
    force's; its fetches are those of the wide projection in tree order; a stack too small for
    the trees sends rays to the binary walk, with the same answers; a terrain's rays take under
    half the binary walk's dependent fetches."""
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n_inst=150)
    baked = bake_scene(scene, WIDE)
    assert "HS_BVH_WIDE" in baked.defines and "wide" in baked.textures
    assert "HS_BVH_WIDE" not in bake_scene(scene, BakeConfig(structure="bvh", bvh=BVHConfig(wide=False))).defines
    o, d, t = random_rays(rng, scene, 3000)
    st = {}
    occ = trace_wide_packed(baked, o, d, t, stats=st)
    assert (occ == trace_brute(scene, o, d, t)).all() and occ.any() and (~occ).any()
    assert st["fallbacks"] == 0 and st["max_stack"] <= 32
    assert (trace_wide_packed(baked, o, d, t, stack=5, stats=st) == occ).all() and st["fallbacks"] > 0
    scene, o, d, t = adversarial_scene(rng)
    assert (trace_wide_packed(bake_scene(scene, WIDE), o, d, t) == trace_brute(scene, o, d, t)).all()
    terrain = bake_scene(Scene(models=[terrain_model(158)], instances=Instances(names=["t"])), WIDE)
    o, d = terrain_rays(rng)
    binary = {"per_ray": True}
    ref = trace_structured(terrain, o, d, np.inf, stats=binary)
    occ = trace_wide_packed(terrain, o, d, np.inf, stats=st)
    assert (occ == ref).all() and ref.mean() > 0.5
    assert st["ray_fetches"].sum() * 2 < binary["ray_fetches"].sum()
    _, projected, _ = trace_wide(terrain, o, d, np.inf, 2, "tree")
    assert abs(int(st["ray_fetches"].sum()) - int(projected.sum())) <= len(o)  # (the root's box: once a ray)


def fresh_blocks(baked):
    """The [wide] blocks a fresh pack of the current [node] texels writes, and where."""
    acc = baked.accel
    trees = acc.models
    wide = np.zeros_like(acc.tex["wide"].linear())
    at = WideIndex(acc.tex["node"].capacity).pack(
        acc.tex["node"].linear(), wide, np.append(trees.node_start, acc.top.start),
        np.append(trees.node_start + trees.node_count, acc.top.start + acc.top.count))
    return at, wide[at]


def assert_blocks_current(baked):
    at, want = fresh_blocks(baked)
    got = baked.accel.tex["wide"].linear()[at]
    assert at.size and (got == want).all(), f"{int((got != want).any(axis=1).sum())} [wide] texels are stale"


def test_wide_blocks_follow_moves_rebuilds_and_model_edits():
    """Refits copy the moved boxes into [wide], a rebuilt top level or model tree packs its
    blocks again (in place or at the tail, the texture grown), and every changed texel lies in a
    reported row range: the blocks are always those of a fresh pack, the answers brute force's."""
    rng = np.random.default_rng(0)
    scene = random_scene(rng, n_inst=250, spheres=0.2, tri_counts=(1, 12, 40))
    baked = bake_scene(scene, WIDE)
    assert_blocks_current(baked)
    for step in range(3):
        before = snapshot(baked)
        idx = rng.choice(len(scene.instances), 12, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :3, 3] += rng.normal(scale=[3, 3, 0.5], size=(12, 3)) * (60.0 if step == 2 else 1.0)
        scene.instances.set_matrices(idx, M)
        rep = baked.update_instances(scene, idx)
        assert rep.regrid == (step == 2)
        assert_report_covers(baked, before, rep)
        assert_blocks_current(baked)
        o, d, t = random_rays(rng, scene, 600)
        assert (trace_wide_packed(baked, o, d, t) == trace_brute(scene, o, d, t)).all()
    for n_tri in (2, 3000):  # smaller: in place; bigger: at the tail (both textures grow)
        k = int(np.nonzero([m.triangle_count > 0 for m in scene.models])[0][0])
        scene.models[k] = blob_model(rng, n_tri, size=1.5)
        before = snapshot(baked)
        rep = baked.update_model(scene, k)
        assert_report_covers(baked, before, rep)
        assert_blocks_current(baked)
        o, d, t = random_rays(rng, scene, 800)
        assert (trace_wide_packed(baked, o, d, t) == trace_brute(scene, o, d, t)).all()
    assert len(baked.accel.tex["wide"].linear()) >= STRIDE * baked.accel.tex["node"].capacity + WIDTH


# ------------------------------------------------------------------------------------ GLSL --
class _Defines:
    """``baked`` with more defines (the GLSL helpers read ``defines`` and the textures)."""

    def __init__(self, baked, **more):
        self._baked, self.defines = baked, {**baked.defines, **more}

    def __getattr__(self, name):
        return getattr(self._baked, name)


@pytest.mark.parametrize("spheres", [0.0, 0.3])
def test_glsl_wide_walk_matches_the_oracle_and_overflows_to_the_binary_walk(gl_ctx, spheres):
    from tests.helpers.glsl import gl_trace

    rng = np.random.default_rng(21)
    scene = random_scene(rng, n_inst=300, spheres=spheres)
    baked = bake_scene(scene, WIDE)
    o, d, t = random_rays(rng, scene, 12000)
    st = {}
    ref = trace_wide_packed(baked, o, d, t, stats=st)
    assert ref.any() and (~ref).any()
    assert (gl_trace(gl_ctx, baked, o, d, t) == ref).all()
    small = {}
    trace_wide_packed(baked, o, d, t, stack=6, stats=small)
    assert small["fallbacks"] > 100
    assert (gl_trace(gl_ctx, _Defines(baked, HS_WIDE_STACK=6), o, d, t) == ref).all()
    terrain = bake_scene(Scene(models=[terrain_model(158)], instances=Instances(names=["t"])), WIDE)
    o, d = terrain_rays(rng, 4000)
    assert (gl_trace(gl_ctx, terrain, o, d, np.inf) == trace_wide_packed(terrain, o, d, np.inf)).all()


# ----------------------------------------------------------------------- masks, both paths --
W, H = 96, 64
MODES = {
    "high": Settings(hard=True, light_grid=False),
    "max_distance": Settings(hard=True, light_grid=False, max_distance=6.0),
    "soft": Settings(samples=16, noise_target=0.0, light_grid=False),
}


@pytest.fixture(scope="module")
def layouts(gl_ctx):
    """Pipelines baking 4-wide and binary layouts: ``{"wide": ..., "binary": ...}``."""
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    pipes = {}
    for name in ("wide", "binary"):
        pipes[name] = Pipeline(gl_ctx)
        pipes[name].bake_options["bvh"] = {"wide": name == "wide"}
    yield pipes
    for p in pipes.values():
        p.release()


@pytest.mark.blender
@pytest.mark.parametrize("name", ["forest", "alpha_cards", "linking", "soft_lights", "stiff/grazing", "stiff/thin",
                                  "stiff/far_away"])
def test_wide_masks_equal_binary_masks_on_both_paths(name, layouts, loaded):
    """Hard, cut short and soft masks (with alpha-cut casters and linking where the scene has
    them) on the compute and the fragment path: 4-wide nodes give the binary walk's masks bit for
    bit (the leaves are met in the same order)."""
    scene = loaded(name)
    for pipe in layouts.values():
        pipe.set_scene(scene)
    assert "HS_BVH_WIDE" in layouts["wide"].baked.defines
    assert "HS_BVH_WIDE" not in layouts["binary"].baked.defines
    for mode, settings in MODES.items():
        for path in ("compute", "fragment"):
            masks = {}
            for k, pipe in layouts.items():
                rt = pipe.shadow_pass("raytrace")
                rt.options = dataclasses.replace(rt.options, soft_lanes=False)
                pipe.reset_history()
                frame = pipe.render(scene, settings.replace(trace_path=path), W, H)
                assert frame.stats["trace_path"] == path
                masks[k] = {li: frame.mask_array(li) for li in frame.lights}
            assert masks["wide"].keys() == masks["binary"].keys()
            for li, a in masks["wide"].items():
                b = masks["binary"][li]
                same = (a == b) | (np.isnan(a) & np.isnan(b))
                what = f"{name} {mode} {path}: light {scene.lights[li].name}"
                assert same.all(), f"{what}: {int((~same).sum())} pixels differ"


@pytest.mark.blender
def test_wide_alpha_masks_equal_the_grids(layouts, loaded):
    """Through alpha-cut cards the 4-wide walk multiplies the transmittances as the grid's walk
    (other code) does, bit for bit: the binary walk's products, not merely its own."""
    scene = loaded("alpha_cards")
    pipe = layouts["wide"]
    masks = {}
    for structure in ("bvh", "grid"):
        pipe.set_scene(scene, structure)
        assert ("HS_BVH_WIDE" in pipe.baked.defines) == (structure == "bvh")
        frame = pipe.render(scene, MODES["high"].replace(structure=structure, trace_path="fragment"), 160, 120)
        masks[structure] = {li: frame.mask_array(li) for li in frame.lights}
    for li, a in masks["bvh"].items():
        b = masks["grid"][li]
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        assert same.all(), f"light {scene.lights[li].name}: {int((~same).sum())} pixels differ"


@pytest.mark.blender
def test_wide_masks_follow_moved_instances(layouts, loaded):
    """Instances moved a little (a refit) and far (the top level rebuilt) through the pipeline:
    the 4-wide bake's partial uploads give the binary bake's masks."""
    import copy

    scene = copy.deepcopy(loaded("forest"))
    for pipe in layouts.values():
        pipe.set_scene(scene)
    rng = np.random.default_rng(8)
    for far in (1.0, 400.0):
        idx = rng.choice(len(scene.instances), 6, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :3, 3] += rng.normal(scale=0.5, size=(6, 3)) * [far, 1.0, 0.1]
        scene.instances.set_matrices(idx, M)
        masks = {}
        for k, pipe in layouts.items():
            pipe.move_instances(scene, idx)
            frame = pipe.render(scene, MODES["high"].replace(trace_path="compute"), W, H)
            masks[k] = {li: frame.mask_array(li) for li in frame.lights}
        for li, a in masks["wide"].items():
            b = masks["binary"][li]
            assert ((a == b) | (np.isnan(a) & np.isnan(b))).all(), f"moved x{far}: light {scene.lights[li].name}"
