"""create_context / gpu_limits / ProgramCache."""
import sys

import numpy as np
import pytest

from hybrid_shadow_addon.core.errors import GPUError
from hybrid_shadow_addon.core.gpu import context as context_mod
from hybrid_shadow_addon.core.gpu.context import create_context, gpu_limits, make_current
from hybrid_shadow_addon.core.gpu.programs import ProgramCache, ShaderError

pytestmark = [pytest.mark.blender, pytest.mark.gpu]


def test_context_and_limits(gl_ctx):
    assert create_context(gl_ctx) is gl_ctx
    lim = gpu_limits(gl_ctx)
    assert lim["gl_version_code"] >= 410
    assert lim["max_texture_size"] >= 4096
    assert lim["max_viewport_dims"][0] >= 4096
    assert lim["renderer"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="EGL checks are Linux-only")
def test_missing_egl_gives_one_line_gpu_error(monkeypatch):
    real = context_mod._load_library
    monkeypatch.setattr(context_mod, "_load_library", lambda name: False if name == "EGL" else real(name))
    with pytest.raises(GPUError) as ei:
        create_context()
    msg = str(ei.value)
    assert "\n" not in msg
    assert "libEGL.so.1" in msg
    assert "sudo apt-get install libegl1 libgl1-mesa-dri libgl1" in msg


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="EGL checks are Linux-only")
def test_missing_dri_and_creation_failure(monkeypatch):
    monkeypatch.setattr(context_mod, "_has_dri_driver", lambda: False)
    with pytest.raises(GPUError, match="libgl1-mesa-dri"):
        create_context()
    monkeypatch.undo()

    def boom(*a, **k):
        raise Exception("eglInitialize failed (0x3001)")

    monkeypatch.setattr(context_mod.moderngl, "create_standalone_context", boom)
    with pytest.raises(GPUError) as ei:
        create_context()
    assert "0x3001" in str(ei.value) and "libgl1-mesa-dri" in str(ei.value) and "\n" not in str(ei.value)


SHADER = """
#include "common/inc_a.glsl"
#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif
#ifdef FRAGMENT_SHADER
#include "common/inc_a.glsl"
out vec4 o;
void main() { o = vec4(value_a() * SCALE, 0.0, 0.0, 1.0); }
#endif
"""


@pytest.fixture()
def shader_dir(tmp_path):
    from hybrid_shadow_addon.core.gpu.programs import default_shader_dir

    (tmp_path / "common").mkdir()
    (tmp_path / "common" / "fullscreen.glsl").write_text(
        (default_shader_dir() / "common" / "fullscreen.glsl").read_text())
    (tmp_path / "common" / "inc_a.glsl").write_text('#include "common/inc_b.glsl"\n'
                                                    "float value_a() { return value_b() + 1.0; }\n")
    (tmp_path / "common" / "inc_b.glsl").write_text("float value_b() { return 0.5; }\n")
    (tmp_path / "ok.glsl").write_text(SHADER)
    (tmp_path / "broken.glsl").write_text(
        '#include "common/inc_b.glsl"\n#ifdef VERTEX_SHADER\nvoid main() { gl_Position = vec4(0); }\n#endif\n'
        "#ifdef FRAGMENT_SHADER\nout vec4 o;\nvoid main() {\n  o = vec4(undefined_thing);\n}\n#endif\n")
    (tmp_path / "broken_inc.glsl").write_text('#include "common/bad.glsl"\n#ifdef VERTEX_SHADER\n'
                                              "void main() { gl_Position = vec4(f()); }\n#endif\n")
    (tmp_path / "common" / "bad.glsl").write_text("// a comment\nfloat f() { return nope; }\n")
    return tmp_path


def test_programs_cached_by_defines_and_includes(gl_ctx, shader_dir):
    progs = ProgramCache(gl_ctx, shader_dir)
    a = progs.get("ok", {"SCALE": 2.0})
    assert progs.get("ok", {"SCALE": 2.0}) is a
    b = progs.get("ok", {"SCALE": 3.0})
    assert b is not a and len(progs) == 2
    # the result: 1.5 * SCALE rendered by a full-screen triangle
    prog, vao = progs.fullscreen("ok", {"SCALE": 3.0})
    assert prog is b
    tex = gl_ctx.texture((4, 4), 4, dtype="f4")
    fbo = gl_ctx.framebuffer([tex])
    fbo.use()
    vao.render(vertices=3)
    img = np.frombuffer(tex.read(), np.float32).reshape(4, 4, 4)
    assert np.allclose(img[..., 0], 4.5)
    fbo.release()
    tex.release()


def test_missing_shader_is_clear(gl_ctx, shader_dir):
    progs = ProgramCache(gl_ctx, shader_dir)
    with pytest.raises(ShaderError, match="shader 'nope' not found"):
        progs.get("nope")
    (shader_dir / "inc_missing.glsl").write_text('#include "common/missing.glsl"\n'
                                                 "#ifdef VERTEX_SHADER\nvoid main(){}\n#endif\n")
    with pytest.raises(ShaderError, match=r"common/missing.glsl.*inc_missing.glsl:1"):
        progs.get("inc_missing")


def test_compile_error_maps_lines(gl_ctx, shader_dir):
    progs = ProgramCache(gl_ctx, shader_dir)
    with pytest.raises(GPUError) as ei:
        progs.get("broken", {"FOO": 1})
    msg = str(ei.value)
    assert "shader 'broken'" in msg and "FOO=1" in msg
    assert "broken.glsl:8" in msg, msg
    with pytest.raises(GPUError) as ei:
        progs.get("broken_inc")
    assert "common/bad.glsl:2" in str(ei.value), str(ei.value)
    assert "broken_inc.glsl" not in str(ei.value).split("failed to build")[1], str(ei.value)


def test_two_pipelines_with_their_own_contexts_on_one_thread(loaded, gl_ctx):
    """Each standalone Pipeline works in its own context even when another was created (and so
    made current) after it on the same thread: renders interleaved give each one's images and
    masks exactly as rendered alone. (Before, the first pipeline's calls went to the newer
    context: its frames took 100x as long, with the other's objects.)"""
    import time

    from hybrid_shadow_addon.core.bake import BakeConfig, BVHConfig, bake_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    a, b = loaded("cube_on_plane"), loaded("scaling")
    st = Settings(mode="raytrace", hard=True, structure="bvh")

    def frame(p, scene):
        f = p.render(scene, st, 96, 64)
        return f.image.copy(), [f.mask_array(li) for li in f.lights]

    pa = Pipeline()
    pa.baked = bake_scene(a, BakeConfig(structure="bvh", bvh=BVHConfig(leaf_size=1)))  # (other defines than pb's)
    pa.scene_textures.upload(pa.baked)
    alone = frame(pa, a)
    pb = Pipeline()
    try:
        b_alone = frame(pb, b)
        for _ in range(2):
            t0 = time.perf_counter()
            got = frame(pa, a)
            ms = (time.perf_counter() - t0) * 1e3
            np.testing.assert_array_equal(got[0], alone[0])
            for m, m0 in zip(got[1], alone[1]):
                np.testing.assert_array_equal(m, m0)
            assert ms < 20000
            got_b = frame(pb, b)
            np.testing.assert_array_equal(got_b[0], b_alone[0])
    finally:
        pb.release()
        pa.release()
        make_current(gl_ctx)  # (the session's context, which the other tests' objects live in)
