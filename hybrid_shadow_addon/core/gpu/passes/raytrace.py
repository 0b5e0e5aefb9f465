"""Shadow mode ``raytrace``: one shadow ray per mask texel and shadowed light
(``shaders/raytrace.glsl``) through the baked scene (:class:`~..scene_textures.SceneTextures`).

The program is built from the bake's defines (grid levels, meshes and/or spheres present) plus
``HS_MAX_DISTANCE`` and ``HS_INTERLACE`` when those settings are on, so a scene compiles only the
code it needs. Interlacing (thesis 3.5.2) traces one texel of every 2x2 block per frame; texels
whose history is not up to date since the last :meth:`reset_history` are filled from this
frame's rays (``shaders/interlace_fill.glsl``), so a change never leaves stale shadows behind
and a still view is exact after four frames.

With ``Settings.conservative`` set (``sun``: suns only, ``all``: every light) each light first
gets a conservative occupancy map (:mod:`.conservative`, ``HS_CONSERVATIVE``): receivers nearer
the light than every caster in their map column are lit without a ray, the others trace only up
to the first possible caster depth. Exact: the masks equal those traced without the map.
The numpy mirror of the rays traced here is ``core/oracle/rays.py``.
"""
from __future__ import annotations

import time

import moderngl
import numpy as np

from ..lights import light_cone, light_ray_uniforms
from ..targets import TargetCache, draw_fullscreen, set_uniforms
from .base import ShadowPass
from .conservative import ConservativeMaps


class RaytracePass(ShadowPass):
    """Masks ``{light index: texture}`` at ``settings.mask_size`` of the G-buffer."""

    light_label = "Ray tracing shadows"
    needs_bake = True

    def __init__(self, gpu):
        super().__init__(gpu)
        self.scene_textures = gpu.scene_textures
        self.maps = ConservativeMaps(gpu)
        self.last_map_ms = 0.0  # time spent building the maps in the last render (incl. finish)
        self._targets = TargetCache(self.ctx, fill=1.0, what="mask")  # (light, role) -> target
        self._phase = 0
        self._valid_phases = 0
        self.last_defines: dict = {}

    def reset_history(self) -> None:
        """Forget interlacing history (any camera, object, light or setting change)."""
        self._valid_phases = 0

    def defines(self, settings, local: bool) -> dict:
        d = dict(self.scene_textures.baked.defines)
        d["HS_LIGHT_LOCAL" if local else "HS_LIGHT_SUN"] = 1
        if settings.max_distance > 0:
            d["HS_MAX_DISTANCE"] = 1
        if settings.interlace:
            d["HS_INTERLACE"] = 1
        return d

    def _target(self, key, w, h):
        t = self._targets.get(key, w, h)
        if self._targets.created:
            self._valid_phases = 0
        return t

    def stats(self, job) -> dict:
        mw, mh = job.settings.mask_size(*job.size)
        return {"mask_resolution": [mw, mh], "rays": int(mw * mh * len(job.lights)),
                "defines": sorted(f"{k}={v}" for k, v in self.last_defines.items())}

    def render(self, job) -> dict:
        ctx = self.ctx
        scene, gbuffer, settings, lights = job.scene, job.gbuffer, job.settings, job.lights
        w, h = settings.mask_size(gbuffer.width, gbuffer.height)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.last_defines = {}
        self.last_map_ms = 0.0
        masks = {}
        sun_maps = settings.conservative in ("sun", "all")
        local_maps = settings.conservative == "all"
        if sun_maps and lights and (local_maps or any(
                not light_ray_uniforms(scene.lights[li])[0] for li in lights)):
            t0 = time.perf_counter()
            self.maps.begin_frame(scene, gbuffer)
            self.last_map_ms += (time.perf_counter() - t0) * 1e3
        origin = self.scene_textures.baked.origin
        for li in lights:
            job.light_started(li)
            local, vec = light_ray_uniforms(scene.lights[li], origin)
            defines = self.defines(settings, local)
            cmap = None
            if sun_maps and (local_maps or not local):
                ctx.finish()  # (so last_map_ms holds the maps alone, not the previous light's rays)
                t0 = time.perf_counter()
                cmap = self.maps.render(scene, li, local, light_ray_uniforms(scene.lights[li])[1])
                ctx.finish()
                self.last_map_ms += (time.perf_counter() - t0) * 1e3
                self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            if cmap is not None:
                defines["HS_CONSERVATIVE"] = 1
            self.last_defines.update(defines)
            masks[li] = self._trace(li, scene.lights[li], vec, defines, gbuffer, settings, w, h, cmap)
        if settings.interlace:
            self._valid_phases |= 1 << self._phase
            self._phase = (self._phase + 1) % 4
        return masks

    def _trace(self, li, light, light_vec, defines, gbuffer, settings, w, h, cmap=None):
        prog, vao = self.programs.fullscreen("raytrace", defines)
        unit = gbuffer.bind(prog)
        unit = self.scene_textures.bind(prog, unit)
        if cmap is not None:
            unit = self._bind_map(prog, unit, *cmap, self.scene_textures.baked.origin)
        axis, cone = light_cone(light)
        set_uniforms(prog, {
            "u_scale": settings.mask_scale, "u_full_size": (gbuffer.width, gbuffer.height),
            "u_light_vec": light_vec, "u_light_axis": axis, "u_light_cone": cone,
            "u_cam_bake": tuple(float(v) for v in gbuffer.camera.cam_pos - self.scene_textures.baked.origin),
            "u_max_distance": float(settings.max_distance)})
        out = self._target((li, "out"), w, h)
        if not settings.interlace:
            draw_fullscreen(self.ctx, vao, out)
            return out.texture
        hist = self._target((li, "hist"), w, h)
        hist.texture.use(unit)
        set_uniforms(prog, {"u_history": unit, "u_phase": self._phase, "u_valid_phases": self._valid_phases})
        draw_fullscreen(self.ctx, vao, out)
        return self._fill(out, hist)

    @staticmethod
    def _bind_map(prog, unit, tex, views, origin) -> int:
        tex.use(unit)
        prog["u_cm"].value = unit
        n = len(views.bases)
        bases = np.zeros((6, 3, 3), np.float32)
        wins = np.zeros((6, 4), np.float32)
        tiles = np.zeros((6, 4), np.float32)
        for k in range(n):
            bases[k] = views.bases[k].T  # column-major upload: rows of .T = columns
            if views.windows[k] is not None:
                wins[k] = views.windows[k]
                tiles[k] = (*views.tiles[k], 1.0)
        prog["u_cm_origin"].value = tuple(float(v) for v in np.asarray(views.origin) - origin)  # bake space
        for name, arr in (("u_cm_basis", bases), ("u_cm_win", wins), ("u_cm_tile", tiles)):
            u = prog[name]  # (the sun's program keeps only element 0 of the arrays)
            u.write(arr[:max(1, u.array_length)].tobytes())
        prog["u_cm_margin"].value = float(views.margin)
        return unit + 1

    def _fill(self, traced, hist):
        """Write the finished mask into ``hist`` (read by the trace already): it is both this
        frame's result and the next frame's history."""
        prog, vao = self.programs.fullscreen("interlace_fill")
        traced.texture.use(0)
        set_uniforms(prog, {"u_traced": 0, "u_phase": self._phase})
        draw_fullscreen(self.ctx, vao, hist)
        return hist.texture

    def release(self) -> None:
        self.maps.release()
        self._targets.release()
