"""Render targets and readback: textures the passes draw into, kept across frames, and reads back
to numpy (row 0 = top)."""
from __future__ import annotations

import moderngl
import numpy as np

from ..errors import GPUError
from .context import check_render_size, make_current

_NUMPY = {"f4": np.float32, "f2": np.float16, "f1": np.uint8, "u1": np.uint8, "i4": np.int32, "u4": np.uint32}


def create_texture(ctx: moderngl.Context, width: int, height: int, components: int = 1, dtype: str = "f4",
                   fill: float | None = None) -> moderngl.Texture:
    """A 2D texture with nearest filtering, clamped; optionally every component set to ``fill``."""
    tex = ctx.texture((int(width), int(height)), components, dtype=dtype)
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    tex.repeat_x = tex.repeat_y = False
    if fill is not None:
        tex.write(np.full((int(height), int(width), components), fill, _NUMPY[dtype]).tobytes())
    return tex


def create_mask_texture(ctx: moderngl.Context, width: int, height: int, fill: float | None = None) -> moderngl.Texture:
    """An R32F shadow-mask texture (1 lit, 0 shadowed), optionally filled with ``fill``."""
    return create_texture(ctx, width, height, 1, "f4", fill)


def read_texture(tex: moderngl.Texture) -> np.ndarray:
    """A 2D texture as float32 numpy, row 0 = TOP row (GL stores bottom-up); (H, W) for one
    component, (H, W, C) otherwise."""
    make_current(tex.ctx)
    a = np.frombuffer(tex.read(), dtype=_NUMPY[tex.dtype]).reshape(tex.height, tex.width, tex.components)
    a = a[::-1]
    a = a.astype(np.float32) / 255.0 if tex.dtype == "f1" else a.astype(np.float32)
    return a[..., 0].copy() if tex.components == 1 else np.ascontiguousarray(a)


class Target:
    """A texture and its framebuffer, drawn with :meth:`use` (binds it and sets the viewport)."""

    def __init__(self, texture: moderngl.Texture, fbo: moderngl.Framebuffer):
        self.texture = texture
        self.fbo = fbo

    @property
    def size(self) -> tuple:
        return self.texture.size

    def use(self, ctx: moderngl.Context, viewport=None) -> moderngl.Framebuffer:
        self.fbo.use()
        ctx.viewport = viewport or (0, 0, *self.texture.size)
        return self.fbo

    def release(self) -> None:
        self.fbo.release()
        self.texture.release()


class TargetCache:
    """Named render targets kept from frame to frame: :meth:`get` returns the one under ``key``,
    recreated only when its size (or format) changed. ``created`` is True after a :meth:`get`
    that made a new texture (its contents are then only ``fill``)."""

    def __init__(self, ctx: moderngl.Context, components: int = 1, dtype: str = "f4", fill: float | None = None,
                 what: str = "render target"):
        self.ctx = ctx
        self.components = components
        self.dtype = dtype
        self.fill = fill
        self.what = what
        self.created = False
        self._targets: dict = {}

    def get(self, key, width: int, height: int, components: int | None = None) -> Target:
        comps = self.components if components is None else components
        width, height = int(width), int(height)
        t = self._targets.get(key)
        self.created = False
        if t is None or t.size != (width, height) or t.texture.components != comps:
            if t is not None:
                t.release()
            check_render_size(self.ctx, width, height, self.what)
            tex = create_texture(self.ctx, width, height, comps, self.dtype, self.fill)
            try:
                fbo = self.ctx.framebuffer(color_attachments=[tex])
            except moderngl.Error as exc:  # (a texture the driver left empty: out of its memory)
                tex.release()
                raise GPUError(f"could not make a {width}x{height} {self.what} ({' '.join(str(exc).split())}): the GPU "
                               f"is out of memory; render smaller or shadow fewer lights") from None
            t = self._targets[key] = Target(tex, fbo)
            self.created = True
        return t

    def texture(self, key, width: int, height: int) -> moderngl.Texture:
        return self.get(key, width, height).texture

    def __contains__(self, key) -> bool:
        return key in self._targets

    def release(self) -> None:
        for t in self._targets.values():
            t.release()
        self._targets.clear()


def draw_fullscreen(ctx: moderngl.Context, vao, target: Target) -> None:
    """One buffer-less full-screen triangle (``shaders/common/fullscreen.glsl``) into ``target``."""
    target.use(ctx)
    vao.render(moderngl.TRIANGLES, vertices=3)


def set_uniforms(prog: moderngl.Program, values: dict) -> None:
    """Set the uniforms of ``values`` that ``prog`` keeps (the compiler drops unused ones);
    ``bytes`` values are written raw (matrices, arrays)."""
    for k, v in values.items():
        if k in prog:
            if isinstance(v, bytes):
                prog[k].write(v)
            else:
                prog[k].value = v
