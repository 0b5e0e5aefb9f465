"""GLSL tracer (shaders/common/scene_data.glsl) against the numpy structured tracer.

A fragment shader reads one ray per pixel from two float textures, calls ``hs_occluded`` and
writes 1/0; the result must agree with ``reference.trace_structured`` on >= 99.9% of the rays.
Runs on the session's OpenGL 4.1 context (Mesa llvmpipe here).
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import trace_structured
from tests.helpers.glsl import gl_trace
from tests.helpers.rays import random_rays
from tests.helpers.scenes import adversarial_scene, random_scene

pytestmark = [pytest.mark.gpu]


@pytest.fixture(scope="module")
def ctx(gl_ctx):
    return gl_ctx


@pytest.mark.parametrize("structure", ["grid", "bvh"])
def test_glsl_compiles_without_optional_paths(ctx, structure):
    """Empty scene: no meshes, no spheres, one level."""
    from hybrid_shadow_addon.core.scene import Scene

    baked = bake_scene(Scene(), BakeConfig(structure=structure))
    o = np.zeros((4, 3))
    d = np.array([[0, 0, 1], [1, 0, 0], [0, 0, -1], [1, 1, 1]], float)
    assert not gl_trace(ctx, baked, o, d, np.inf).any()


@pytest.mark.parametrize("structure", ["grid", "bvh"])
@pytest.mark.parametrize("seed", [0, 1])
def test_glsl_matches_structured(ctx, seed, structure):
    rng = np.random.default_rng(100 + seed)
    scene = random_scene(rng, n_inst=300, spheres=0.3)
    baked = bake_scene(scene, BakeConfig(structure=structure))
    o, d, t = random_rays(rng, scene, 20000)
    ref = trace_structured(baked, o, d, t)
    gl = gl_trace(ctx, baked, o, d, t)
    agree = (ref == gl).mean()
    assert ref.any() and (~ref).any()
    assert agree >= 0.999, f"agreement {agree:.5f}, {int((ref != gl).sum())} rays differ"


@pytest.mark.parametrize("structure", ["grid", "bvh"])
def test_glsl_adversarial(ctx, structure):
    rng = np.random.default_rng(7)
    scene, o, d, t = adversarial_scene(rng)
    baked = bake_scene(scene, BakeConfig(structure=structure))
    ref = trace_structured(baked, o, d, t)
    gl = gl_trace(ctx, baked, o, d, t)
    assert (ref == gl).mean() >= 0.999
