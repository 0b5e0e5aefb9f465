"""Hard limits: each one stops before the GPU with one line naming the limit and the number.

The real limits need scenes of tens of millions of triangles or instances (see
``benchmarks/find_limits.py``); here each is lowered on a small scene (monkeypatched), so every
test takes well under a second and allocates next to nothing."""
import numpy as np
import pytest

from hybrid_shadow_addon.core import limits
from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.bake.structures import blas, twolevel
from hybrid_shadow_addon.core.errors import GPUError, SceneError
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import basic_scene, plate_model


def one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg
    return msg


# ------------------------------------------------------------------------------ instances --
def test_instance_limit_is_the_gbuffers_float_index():
    assert limits.MAX_INSTANCES == 2 ** 24
    f = np.float32(limits.MAX_INSTANCES)  # the last index the G-buffer tells from its neighbours
    assert f - np.float32(1) != f and np.float32(limits.MAX_INSTANCES + 1) == f


@pytest.mark.parametrize("structure", ["bvh", "grid"])
def test_too_many_instances_stop_the_bake(monkeypatch, structure):
    monkeypatch.setattr(limits, "MAX_INSTANCES", 2)
    with pytest.raises(SceneError) as exc:
        bake_scene(basic_scene(), BakeConfig(structure=structure))
    assert "3 instances; at most 2 can be rendered" in one_line(exc)


@pytest.mark.gpu
def test_too_many_instances_stop_a_frame_without_a_bake(pipeline, monkeypatch):
    scene = basic_scene()
    monkeypatch.setattr(limits, "MAX_INSTANCES", 2)
    with pytest.raises(SceneError) as exc:  # (shadow maps bake nothing: the G-buffer checks)
        pipeline.render(scene, Settings(mode="shadowmap"), 32, 24, read_image=False)
    assert "3 instances; at most 2" in one_line(exc)
    monkeypatch.setattr(limits, "MAX_INSTANCES", 3)
    pipeline.render(scene, Settings(mode="shadowmap"), 32, 24, read_image=False)


# ------------------------------------------------------------------------ BVH leaf texels --
def test_leaf_texels_counts_what_the_bake_packs():
    scene = basic_scene()
    scene.models[1] = plate_model(5)  # 50 triangles: a short last leaf
    baked = bake_scene(scene, BakeConfig(structure="bvh"))
    counts = [m.triangle_count for m in scene.models]
    expect = len(scene.instances) * blas.INST_TEXELS + twolevel.leaf_texels(counts, blas.leaf_size(baked.config))
    assert baked.accel.leaf_tail == expect


def test_leaf_texel_limit_stops_the_bake(monkeypatch):
    scene = basic_scene()
    need = len(scene.instances) * blas.INST_TEXELS + blas.LEAF_READ + twolevel.leaf_texels(
        [m.triangle_count for m in scene.models], blas.leaf_size(BakeConfig()))
    monkeypatch.setattr(twolevel, "MAX_LEAF_TEXELS", need)
    bake_scene(scene, BakeConfig(structure="bvh"))  # (exactly at the limit)
    monkeypatch.setattr(twolevel, "MAX_LEAF_TEXELS", need - 1)
    with pytest.raises(SceneError) as exc:
        bake_scene(scene, BakeConfig(structure="bvh"))
    msg = one_line(exc)
    assert f"need {need:,} BVH leaf texels; at most {need - 1:,}" in msg and "14 unique triangles" in msg


def test_leaf_texel_limit_stops_a_model_edit(monkeypatch):
    scene = basic_scene()
    baked = bake_scene(scene, BakeConfig(structure="bvh"))
    monkeypatch.setattr(twolevel, "MAX_LEAF_TEXELS", baked.accel.leaf_tail + blas.LEAF_READ + 8)
    scene.models[1] = plate_model(8)  # 128 triangles: no longer fits the cube's place
    with pytest.raises(SceneError) as exc:
        baked.update_model(scene, 1)
    assert "BVH leaf texels; at most" in one_line(exc)


def test_leaf_payload_width():
    """A leaf's payload keeps its first texel in the 28 bits above the 3 count bits, below the flag."""
    assert twolevel.MAX_LEAF_TEXELS << 3 == int(blas.LEAF_FLAG)


# ---------------------------------------------------------------------------- bake memory --
def test_bake_past_the_memory_left_stops_before_building(monkeypatch):
    monkeypatch.setattr(limits, "host_memory_bytes", lambda: limits.process_memory_bytes() + (1 << 20))
    bake_scene(basic_scene(), BakeConfig(structure="bvh"))  # (14 triangles, 3 instances: a few KB)
    monkeypatch.setattr(limits, "BAKE_BYTES_PER_TRIANGLE", 1 << 20)
    monkeypatch.setattr(twolevel, "build_blas", lambda *a, **k: pytest.fail("built past the check"))
    with pytest.raises(SceneError) as exc:
        bake_scene(basic_scene(), BakeConfig(structure="bvh"))
    assert "baking 14 unique triangles and 3 instances needs at least 0.01 GiB of memory" in one_line(exc)


def test_a_bake_out_of_memory_is_one_line(monkeypatch):
    def no_memory(*a, **k):
        raise MemoryError("Unable to allocate 12.0 GiB for an array")

    monkeypatch.setattr(twolevel, "build_blas", no_memory)
    with pytest.raises(SceneError) as exc:
        bake_scene(basic_scene(), BakeConfig(structure="bvh"))
    assert "the bake of 14 unique triangles and 3 instances ran out of memory" in one_line(exc)


# ------------------------------------------------------------------------------ GPU sizes --
@pytest.mark.gpu
def test_texture_fits_asks_the_driver(gl_ctx):
    from hybrid_shadow_addon.core.gpu import context

    side = context.gpu_limits(gl_ctx)["max_texture_size"]
    for _ in range(16):  # (errors that earlier tests left)
        if gl_ctx.error == "GL_NO_ERROR":
            break
    assert context.texture_fits(gl_ctx, 64, 64) is True
    assert context.texture_fits(gl_ctx, 64, 64, 4, "u4", layers=3) is True
    assert context.texture_fits(gl_ctx, side * 2, 1) is False
    assert gl_ctx.error == "GL_NO_ERROR"  # (a proxy query allocates nothing and leaves no error)
    if context.software_context(gl_ctx):  # llvmpipe refuses a 4 GiB RGBA32F texture of legal sides
        assert context.texture_fits(gl_ctx, side, side) is False
        assert 0 < context.largest_rows(gl_ctx, side) < side


@pytest.mark.gpu
def test_render_size_past_the_drivers_texture_stops_the_frame(pipeline, monkeypatch):
    from hybrid_shadow_addon.core.gpu import context

    monkeypatch.setattr(context, "texture_fits", lambda ctx, w, h, c=4, d="f4", layers=0: w * h <= 1000)
    before = pipeline.gbuffer_renders
    with pytest.raises(GPUError) as exc:
        pipeline.render(basic_scene(), Settings(hard=True), 40, 30, read_image=False)
    assert "render size 40x30 needs" in one_line(exc) and "at most 40x25 (" in one_line(exc)
    assert pipeline.gbuffer_renders == before


@pytest.mark.gpu
def test_scene_texture_past_the_driver_stops_the_upload(gl_ctx, monkeypatch):
    from hybrid_shadow_addon.core.gpu import scene_textures
    from hybrid_shadow_addon.core.gpu.scene_textures import SceneTextures

    small = bake_scene(basic_scene(), BakeConfig(structure="bvh"))
    st = SceneTextures(gl_ctx, buffers=False)
    try:
        st.upload(small)
        cap = max(td.width * td.height * td.layers for td in small.textures.values())
        # a driver that makes 2D arrays of at most cap - 1 texels: the largest texture no longer fits
        monkeypatch.setattr(scene_textures, "texture_fits",
                            lambda ctx, w, h, c=4, d="f4", layers=0: w * h * max(layers, 1) < cap)
        with pytest.raises(GPUError) as exc:
            st.upload(bake_scene(basic_scene(), BakeConfig(structure="bvh")))
        assert "scene texture '" in one_line(exc) and f"needs {cap:,} texels" in one_line(exc)
        assert st.baked is small and st.textures  # (stopped before anything was released or made)
    finally:
        st.release()


@pytest.mark.gpu
def test_record_textures_past_the_buffer_limit_become_arrays(gl_ctx, monkeypatch):
    from hybrid_shadow_addon.core.gpu import scene_textures
    from hybrid_shadow_addon.core.gpu.scene_textures import SceneTextures

    monkeypatch.setattr(scene_textures, "max_texels", lambda ctx: 8)
    st = SceneTextures(gl_ctx)
    try:
        st.upload(bake_scene(basic_scene(), BakeConfig(structure="bvh")))
        assert not st.using_buffers and st.textures
    finally:
        st.release()


# ---------------------------------------------------------------------------------- lights --
@pytest.mark.gpu
def test_light_limit_is_what_the_light_table_holds(gl_ctx):
    from hybrid_shadow_addon.core.gpu import context
    from hybrid_shadow_addon.core.gpu.lights import LIGHT_TEXELS

    n = context.max_lights(gl_ctx)
    assert n == context.gpu_limits(gl_ctx)["max_texture_size"] // LIGHT_TEXELS
    context.check_render_size(gl_ctx, LIGHT_TEXELS * n, 1, "light table")  # (the lighting pass's texture)
    with pytest.raises(GPUError):
        context.check_render_size(gl_ctx, LIGHT_TEXELS * (n + 1), 1, "light table")


# ---------------------------------------------------------------------------------- memory --
@pytest.mark.gpu
def test_frame_memory_past_the_machine_stops_the_frame(pipeline, monkeypatch):
    from hybrid_shadow_addon.core.gpu import context

    monkeypatch.setattr(context, "software_context", lambda ctx: True)
    monkeypatch.setattr(context, "host_memory_bytes", lambda: 1 << 20)
    before = pipeline.gbuffer_renders
    with pytest.raises(GPUError) as exc:
        pipeline.render(basic_scene(), Settings(hard=True), 160, 120, read_image=False)
    msg = one_line(exc)
    assert "a 160x120 frame with 1 shadowed lights needs at least" in msg and "this machine has 0.00 GiB" in msg
    assert pipeline.gbuffer_renders == before + 1  # (counted, but stopped before its first target)
    monkeypatch.setattr(context, "host_memory_bytes", lambda: 1 << 40)
    pipeline.render(basic_scene(), Settings(hard=True), 160, 120, read_image=False)


def test_host_memory_is_known_here():
    assert limits.host_memory_bytes() > 1 << 28
    assert 0 < limits.process_memory_bytes() < limits.host_memory_bytes()


def test_a_render_target_the_driver_leaves_empty_is_one_line(gl_ctx, monkeypatch):
    """A target whose texture the driver could not make (out of its memory: moderngl's framebuffer
    is incomplete) is one GPUError naming its size, and nothing is left half-made."""
    import moderngl

    from hybrid_shadow_addon.core.errors import GPUError
    from hybrid_shadow_addon.core.gpu import memory
    from hybrid_shadow_addon.core.gpu.targets import TargetCache

    cache = TargetCache(gl_ctx, what="mask")
    before = memory.in_use(gl_ctx)

    def incomplete(*_a, **_k):
        raise moderngl.Error("the framebuffer is not complete (INCOMPLETE_ATTACHMENT)")

    monkeypatch.setattr(gl_ctx, "framebuffer", incomplete)
    with pytest.raises(GPUError, match=r"could not make a 64x32 mask .*INCOMPLETE_ATTACHMENT.*out of memory"):
        cache.get("m", 64, 32)
    assert "m" not in cache and memory.in_use(gl_ctx) == before
