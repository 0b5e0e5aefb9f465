"""Edge-aware upsample of reduced-resolution masks (Settings.quality medium/low) to the
G-buffer's resolution: a joint bilateral filter guided by the full-resolution G-buffer (depth
via the tangent plane, normals), instead of the thesis' blocky nearest upscale (3.5.1)."""
from __future__ import annotations

import moderngl

from . import create_mask_texture


class UpsamplePass:
    """``render(masks, gbuffer, settings=None) -> dict[int, Texture]`` at G-buffer resolution.

    Masks already at full resolution are passed through unchanged. ``settings.upsample ==
    'nearest'`` reproduces the blocky upscale for comparisons."""

    def __init__(self, ctx: moderngl.Context, programs, plane_sigma: float = 0.02, normal_power: float = 16.0):
        self.ctx = ctx
        self.programs = programs
        self.plane_sigma = plane_sigma
        self.normal_power = normal_power
        self._out: dict = {}

    def _target(self, key, w, h):
        tex = self._out.get(key)
        if tex is None or tex.size != (w, h):
            if tex is not None:
                tex.release()
            tex = self._out[key] = create_mask_texture(self.ctx, w, h)
        return tex

    def render(self, masks: dict, gbuffer, settings=None) -> dict:
        ctx = self.ctx
        full = (gbuffer.width, gbuffer.height)
        out = {}
        prog, vao = self.programs.fullscreen("upsample")
        nearest = settings is not None and settings.upsample == "nearest"
        for li, tex in masks.items():
            if tex.size == full:
                out[li] = tex
                continue
            scale = max(1, round(full[0] / tex.width))
            dst = self._target(li, *full)
            fbo = ctx.framebuffer(color_attachments=[dst])
            fbo.use()
            ctx.viewport = (0, 0, *full)
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            unit = gbuffer.bind(prog)
            tex.use(unit)
            prog["u_mask"].value = unit
            prog["u_scale"].value = int(scale)
            for k, v in (("u_plane_sigma", self.plane_sigma), ("u_normal_power", self.normal_power),
                         ("u_nearest", int(nearest))):
                if k in prog:
                    prog[k].value = v
            vao.render(moderngl.TRIANGLES, vertices=3)
            fbo.release()
            out[li] = dst
        return out

    def release(self) -> None:
        for t in self._out.values():
            t.release()
        self._out.clear()
