"""Pass 2, ray traced: one shadow ray per mask texel and shadowed light (``shaders/raytrace.glsl``)
through the baked scene (:class:`~..scene_textures.SceneTextures`).

The program is built from the bake's defines (grid levels, meshes and/or spheres present) plus
``HS_MAX_DISTANCE`` and ``HS_INTERLACE`` when those settings are on, so a scene compiles only the
code it needs. Interlacing (thesis 3.5.2) traces one texel of every 2x2 block per frame; texels
whose history is not up to date since the last :meth:`reset_history` are filled from this
frame's rays (``shaders/interlace_fill.glsl``), so a change never leaves stale shadows behind
and a still view is exact after four frames.
"""
from __future__ import annotations

import moderngl

from . import create_mask_texture


def light_ray_uniforms(light) -> tuple[int, tuple]:
    """(u_light_local, u_light_vec): a sun gives the unit direction towards it, other lights
    their position (area lights are points for now)."""
    if light.type == "SUN":
        return 0, tuple(float(v) for v in -light.direction)
    return 1, tuple(float(v) for v in light.position)


class RaytracePass:
    def __init__(self, ctx: moderngl.Context, programs, scene_textures):
        self.ctx = ctx
        self.programs = programs
        self.scene_textures = scene_textures
        self._targets: dict = {}  # (light, role) -> texture
        self._phase = 0
        self._valid_phases = 0
        self.last_defines: dict = {}

    def reset_history(self) -> None:
        """Forget interlacing history (any camera, object, light or setting change)."""
        self._valid_phases = 0

    def defines(self, settings) -> dict:
        d = dict(self.scene_textures.baked.defines)
        if settings.max_distance > 0:
            d["HS_MAX_DISTANCE"] = 1
        if settings.interlace:
            d["HS_INTERLACE"] = 1
        return d

    def _target(self, key, w, h):
        tex = self._targets.get(key)
        if tex is None or tex.size != (w, h):
            if tex is not None:
                tex.release()
            tex = self._targets[key] = create_mask_texture(self.ctx, w, h, fill=1.0)
            self._valid_phases = 0
        return tex

    def render(self, scene, gbuffer, settings, lights) -> dict:
        """Masks ``{light_index: R32F texture}`` at ``settings.mask_size`` of the G-buffer."""
        ctx = self.ctx
        w, h = settings.mask_size(gbuffer.width, gbuffer.height)
        defines = self.defines(settings)
        self.last_defines = defines
        prog, vao = self.programs.fullscreen("raytrace", defines)
        interlace = settings.interlace
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        unit = gbuffer.bind(prog)
        unit = self.scene_textures.bind(prog, unit)
        prog["u_scale"].value = settings.mask_scale
        prog["u_full_size"].value = (gbuffer.width, gbuffer.height)
        if settings.max_distance > 0:
            prog["u_max_distance"].value = float(settings.max_distance)
        if interlace:
            prog["u_phase"].value = self._phase
            prog["u_valid_phases"].value = self._valid_phases
            prog["u_history"].value = unit
        masks = {}
        for li in lights:
            local, vec = light_ray_uniforms(scene.lights[li])
            prog["u_light_local"].value = local
            prog["u_light_vec"].value = vec
            out = self._target((li, "out"), w, h)
            if interlace:
                hist = self._target((li, "hist"), w, h)
                hist.use(unit)
                self._draw(vao, out, w, h)
                out = self._fill(out, hist, w, h)
            else:
                self._draw(vao, out, w, h)
            masks[li] = out
        if interlace:
            self._valid_phases |= 1 << self._phase
            self._phase = (self._phase + 1) % 4
        return masks

    def _draw(self, vao, target, w, h) -> None:
        fbo = self.ctx.framebuffer(color_attachments=[target])
        fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        vao.render(moderngl.TRIANGLES, vertices=3)
        fbo.release()

    def _fill(self, traced, hist, w, h):
        """Write the finished mask into ``hist`` (read by the trace already): it is both this
        frame's result and the next frame's history."""
        prog, vao = self.programs.fullscreen("interlace_fill")
        traced.use(0)
        prog["u_traced"].value = 0
        prog["u_phase"].value = self._phase
        self._draw(vao, hist, w, h)
        return hist

    def release(self) -> None:
        for tex in self._targets.values():
            tex.release()
        self._targets.clear()
