"""Upsample of reduced-resolution masks to the G-buffer's resolution: a joint bilateral filter
guided by the full-resolution G-buffer (depth via the tangent plane, normals), or the thesis'
blocky nearest upscale (3.5.1).

The ray-traced pass makes full-resolution masks at every quality (refinement), which pass
through unchanged; reduced masks reach this pass from ``quality`` medium/low with
``Settings.upsample == 'nearest'`` (the coarse rays alone, for comparisons) and from callers
that hand it one."""
from __future__ import annotations

import moderngl

from ..targets import TargetCache, draw_fullscreen, set_uniforms
from .base import Pass


class UpsamplePass(Pass):
    """``render(job) -> {light index: texture}`` at G-buffer resolution.

    Masks already at full resolution are passed through unchanged. ``settings.upsample ==
    'nearest'`` reproduces the blocky upscale for comparisons."""

    produces = "masks"
    name = "upsample"
    label = "Upsampling masks"

    def __init__(self, gpu, plane_sigma: float = 0.02, normal_power: float = 16.0):
        super().__init__(gpu)
        self.plane_sigma = plane_sigma
        self.normal_power = normal_power
        self._out = TargetCache(self.ctx, what="mask")

    def render(self, job) -> dict:
        gbuffer = job.gbuffer
        full = gbuffer.size
        out = {}
        prog, vao = self.programs.fullscreen("upsample")
        nearest = job.settings is not None and job.settings.upsample == "nearest"
        for li, tex in job.masks.items():
            if tex.size == full:
                out[li] = tex
                continue
            dst = self._out.get(li, *full)
            self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            unit = gbuffer.bind(prog)
            tex.use(unit)
            set_uniforms(prog, {"u_mask": unit, "u_scale": int(max(1, round(full[0] / tex.width))),
                                "u_plane_sigma": self.plane_sigma, "u_normal_power": self.normal_power,
                                "u_nearest": int(nearest)})
            draw_fullscreen(self.ctx, vao, dst)
            out[li] = dst.texture
        return out

    def release(self) -> None:
        self._out.release()
