"""A scene compiles only the shader code it needs: for each optional feature, a scene without it
builds the ray-trace program without it (``RaytracePass.last_defines`` / the frame stats'
``defines``, and the compiled program's active uniforms: code that is compiled out leaves no
uniform or sampler behind).

Light types: the ray-trace pass has one program per light *kind* (``HS_LIGHT_SUN`` for suns,
``HS_LIGHT_LOCAL`` for point, spot and area lights); the lighting pass compiles the kinds of
light in its table (``HS_LIT_*``, tested in ``test_gpu_lighting.py``);
``benchmarks/bench_variants.py`` shows a sun-only scene does not pay for the other paths.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.scene import Instances
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import VARIANT_SIZE, variant_scene

pytestmark = [pytest.mark.gpu]

W, H = VARIANT_SIZE


def trace(gl_ctx, scene, **settings):
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    settings.setdefault("structure", "grid")  # (the grid's variants; "bvh" below)
    pipe = Pipeline(gl_ctx)
    try:
        pipe.set_scene(scene)
        frame = pipe.render(scene, Settings(mode="raytrace", **settings), W, H)
        defines = dict(pipe.shadow_pass("raytrace").last_defines)
        assert frame.stats["defines"] == sorted(f"{k}={v}" for k, v in defines.items())
        prog = pipe.programs.get("raytrace", defines)
        uniforms = {name for name in prog}
        masks = [frame.mask_array(i) for i in frame.lights]
    finally:
        pipe.release()
    return defines, uniforms, masks


def test_sun_only_scene_has_no_local_light_code(gl_ctx):
    d, u, masks = trace(gl_ctx, variant_scene(("SUN",)))
    assert "HS_LIGHT_SUN" in d and "HS_LIGHT_LOCAL" not in d
    assert (masks[0][np.isfinite(masks[0])] < 0.5).any()


@pytest.mark.parametrize("kind", ["POINT", "SPOT", "AREA"])
def test_local_light_scene_has_no_sun_code(gl_ctx, kind):
    d, u, _ = trace(gl_ctx, variant_scene((kind,)))
    assert "HS_LIGHT_LOCAL" in d and "HS_LIGHT_SUN" not in d


def test_mixed_lights_compile_both_kinds(gl_ctx):
    d, _, masks = trace(gl_ctx, variant_scene(("SUN", "POINT")))
    assert "HS_LIGHT_LOCAL" in d and "HS_LIGHT_SUN" in d and len(masks) == 2


def test_meshes_only_has_no_sphere_code(gl_ctx):
    d, u, _ = trace(gl_ctx, variant_scene(meshes=True, spheres=False))
    assert "HS_HAS_MESHES" in d and "HS_HAS_SPHERES" not in d
    assert "hs_bvh_tex" in u and "hs_tri_tex" in u


def test_spheres_only_has_no_mesh_code(gl_ctx):
    d, u, masks = trace(gl_ctx, variant_scene(meshes=False, spheres=True))
    assert "HS_HAS_SPHERES" in d and "HS_HAS_MESHES" not in d
    assert "hs_bvh_tex" not in u and "hs_tri_tex" not in u  # BVH and triangle fetches compiled out
    assert (masks[0][np.isfinite(masks[0])] < 0.5).any()


def test_object_bvh_code_only_for_crowded_nodes(gl_ctx):
    d, _, _ = trace(gl_ctx, variant_scene())
    assert "HS_HAS_NODE_BVH" not in d
    crowd = variant_scene()
    rng = np.random.default_rng(5)
    m = np.tile(np.eye(4), (200, 1, 1))
    m[:, :3, :3] *= 0.05
    m[:, :3, 3] = rng.uniform((-0.5, -0.5, 1.2), (0.5, 0.5, 1.5), (200, 3))  # a swarm over the box
    crowd.instances = Instances.concatenate([crowd.instances, Instances(
        names=[f"bit{i}" for i in range(200)], model_ids=np.ones(200, int), matrices=m)])
    d, u, masks = trace(gl_ctx, crowd)
    assert "HS_HAS_NODE_BVH" in d and "hs_bvh_tex" in u
    assert (masks[0][np.isfinite(masks[0])] < 0.5).any()


def test_grid_levels_only_as_many_as_needed(gl_ctx):
    small, _, _ = trace(gl_ctx, variant_scene())
    wide, _, _ = trace(gl_ctx, variant_scene(spread=400.0))
    assert small["HS_GRID_LEVELS"] < wide["HS_GRID_LEVELS"]


def test_max_distance_and_interlace_only_when_on(gl_ctx):
    d, u, _ = trace(gl_ctx, variant_scene())
    assert "HS_MAX_DISTANCE" not in d and "u_max_distance" not in u
    assert "HS_INTERLACE" not in d and "u_offset" not in u
    d, u, _ = trace(gl_ctx, variant_scene(), max_distance=5.0)
    assert "HS_MAX_DISTANCE" in d and "u_max_distance" in u


# ---- structure "bvh": the two-level walk and nothing of the grid -------------------------------
@pytest.mark.parametrize("meshes,spheres", [(True, False), (False, True), (True, True)])
def test_bvh_structure_compiles_only_what_the_scene_has(gl_ctx, meshes, spheres):
    scene = variant_scene(meshes=meshes, spheres=spheres)
    d, u, masks = trace(gl_ctx, scene, structure="bvh")
    assert "HS_STRUCTURE_BVH" in d and "HS_GRID_LEVELS" not in d
    assert ("HS_HAS_MESHES" in d) == meshes and ("HS_HAS_SPHERES" in d) == spheres
    assert "hs_node_tex" in u and "hs_leaf_tex" in u
    assert not {"hs_grid_tex", "hs_bvh_tex", "hs_tri_tex", "hs_grid_origin"} & u  # no grid code
    _, _, grid_masks = trace(gl_ctx, scene)
    for a, b in zip(masks, grid_masks):
        assert np.array_equal(np.isnan(a), np.isnan(b)) and (a[np.isfinite(a)] == b[np.isfinite(b)]).mean() > 0.999
    assert (masks[0][np.isfinite(masks[0])] < 0.5).any()


def test_bvh_leaf_size_define_follows_the_config():
    from hybrid_shadow_addon.core.bake import BakeConfig, BVHConfig, bake_scene

    for k in (1, 3):
        d = bake_scene(variant_scene(), BakeConfig(structure="bvh", bvh=BVHConfig(leaf_size=k))).defines
        assert d["HS_BVH_LEAF_SIZE"] == k
