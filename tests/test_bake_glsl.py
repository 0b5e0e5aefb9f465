"""GLSL tracer (shaders/common/scene_data.glsl) against the numpy structured tracer.

A fragment shader reads one ray per pixel from two float textures, calls ``hs_occluded`` and
writes 1/0; the result must agree with ``reference.trace_structured`` on >= 99.9% of the rays.
Runs on the session's OpenGL 4.1 context (Mesa llvmpipe here).
"""
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.oracle.tracer import bake_space, trace_structured

from test_bake_scenes import random_scene, random_rays, adversarial_scene

REPO = Path(__file__).resolve().parents[1]
SHADER_DIR = REPO / "shaders"

VERT = """
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

FRAG = """
#include "common/scene_data.glsl"
uniform sampler2D ray_o;
uniform sampler2D ray_d;
out float hit;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 o = texelFetch(ray_o, p, 0);
    vec4 d = texelFetch(ray_d, p, 0);
    hit = hs_occluded(o.xyz, d.xyz, o.w) ? 1.0 : 0.0;
}
"""


def _resolve(src: str, defines: dict) -> str:
    lines = []
    for line in src.splitlines():
        s = line.strip()
        if s.startswith("#include"):
            name = s.split('"')[1]
            lines.append(_resolve((SHADER_DIR / name).read_text(), None))
        else:
            lines.append(line)
    body = "\n".join(lines)
    if defines is None:
        return body
    head = ["#version 410 core"] + [f"#define {k} {v}" for k, v in defines.items()]
    return "\n".join(head) + "\n" + body


@pytest.fixture(scope="module")
def ctx(gl_ctx):
    return gl_ctx


def gl_trace(ctx, baked, origins, dirs, tmax):
    import moderngl

    defines = dict(baked.defines)
    prog = ctx.program(vertex_shader=_resolve(VERT, defines), fragment_shader=_resolve(FRAG, defines))
    n = len(origins)
    W = 256
    H = -(-n // W)
    o = np.zeros((H * W, 4), np.float32)
    d = np.zeros((H * W, 4), np.float32)
    o[:n, :3] = bake_space(baked, origins)
    o[:n, 3] = np.minimum(np.broadcast_to(np.asarray(tmax, np.float64), (n,)), 3.0e38)
    d[:n, :3] = dirs
    d[n:, 0] = 1.0
    res = []
    tex_o = ctx.texture((W, H), 4, o.tobytes(), dtype="f4")
    tex_d = ctx.texture((W, H), 4, d.tobytes(), dtype="f4")
    res += [tex_o, tex_d]
    unit = 0
    for t in (tex_o, tex_d):
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
    tex_o.use(0)
    tex_d.use(1)
    for k, name in enumerate(("ray_o", "ray_d")):
        if name in prog:  # an empty scene's walk needs no ray: the compiler may drop them
            prog[name] = k
    unit = 2
    for name, td in baked.textures.items():
        t = ctx.texture_array((td.width, td.height, td.layers), td.components, td.data.tobytes(), dtype=td.fmt)
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        t.use(unit)
        sname = baked.samplers[name]
        if sname in prog:
            prog[sname] = unit
        res.append(t)
        unit += 1
    for name, value in baked.uniforms.items():
        if name not in prog:
            continue
        arr = np.asarray(value)
        if arr.dtype.kind == "f":
            prog[name].write(arr.astype(np.float32).tobytes())
        else:
            prog[name].write(arr.astype(np.int32).tobytes())
    out = ctx.texture((W, H), 1, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[out])
    vbo = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "2f", "in_pos")])
    fbo.use()
    ctx.viewport = (0, 0, W, H)
    vao.render(moderngl.TRIANGLES)
    hit = np.frombuffer(fbo.read(components=1, dtype="f4"), np.float32)[:n] > 0.5
    for r in res + [out, fbo, vbo, vao, prog]:
        r.release()
    return hit


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
