"""The GLSL tracer outside the pipeline: a fragment shader that traces one ray per pixel through a
bake's textures (``shaders/common/scene_data.glsl``), for comparing with the numpy tracers."""
from pathlib import Path

import numpy as np

from hybrid_shadow_addon.core.oracle.tracer import bake_space

REPO = Path(__file__).resolve().parents[2]
SHADER_DIR = REPO / "shaders"


#: a full-screen triangle
VERT = """
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""


def ray_fragment(expression: str) -> str:
    """A fragment shader for one ray per pixel (origin ``o.xyz`` and tmax ``o.w`` from ``ray_o``,
    direction ``d.xyz`` from ``ray_d``) that writes the float ``expression``."""
    return f"""
#include "common/scene_data.glsl"
uniform sampler2D ray_o;
uniform sampler2D ray_d;
out float result;
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 o = texelFetch(ray_o, p, 0);
    vec4 d = texelFetch(ray_d, p, 0);
    result = {expression};
}}
"""


#: through ``hs_occluded``: 1 hit, 0 miss
FRAG = ray_fragment("hs_occluded(o.xyz, d.xyz, o.w) ? 1.0 : 0.0")


def resolve(src: str, defines: dict) -> str:
    """``src`` with its ``#include`` lines inlined; with ``defines``, headed by the version and them."""
    lines = []
    for line in src.splitlines():
        s = line.strip()
        if s.startswith("#include"):
            name = s.split('"')[1]
            lines.append(resolve((SHADER_DIR / name).read_text(), None))
        else:
            lines.append(line)
    body = "\n".join(lines)
    if defines is None:
        return body
    head = ["#version 410 core"] + [f"#define {k} {v}" for k, v in defines.items()]
    return "\n".join(head) + "\n" + body


def gl_rays(ctx, baked, origins, dirs, tmax, fragment: str = FRAG) -> np.ndarray:
    """One float per ray (world space) from ``fragment`` (one ray per pixel through ``baked``'s
    textures: ``ray_o`` origin and tmax, ``ray_d`` direction) on the GPU."""
    import moderngl

    defines = dict(baked.defines)
    prog = ctx.program(vertex_shader=resolve(VERT, defines), fragment_shader=resolve(fragment, defines))
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
    for k, (name, arr) in enumerate((("ray_o", o), ("ray_d", d))):
        t = ctx.texture((W, H), 4, arr.tobytes(), dtype="f4")
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        t.use(k)
        if name in prog:  # an empty scene's walk needs no ray: the compiler may drop them
            prog[name] = k
        res.append(t)
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
    values = np.frombuffer(fbo.read(components=1, dtype="f4"), np.float32)[:n].copy()
    for r in res + [out, fbo, vbo, vao, prog]:
        r.release()
    return values


def gl_trace(ctx, baked, origins, dirs, tmax):
    """Any-hit of each ray (world space) through ``baked`` on the GPU, as a bool array."""
    return gl_rays(ctx, baked, origins, dirs, tmax) > 0.5
