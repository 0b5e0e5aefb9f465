"""Pass 2, ray traced: one shadow ray per mask texel and shadowed light (``shaders/raytrace.glsl``)
through the baked scene (:class:`~..scene_textures.SceneTextures`).

The program is built from the bake's defines (grid levels, meshes and/or spheres present) plus
``HS_MAX_DISTANCE`` and ``HS_INTERLACE`` when those settings are on, so a scene compiles only the
code it needs. Interlacing (thesis 3.5.2) traces one texel of every 2x2 block per frame; texels
whose history is not up to date since the last :meth:`reset_history` are filled from this
frame's rays (``shaders/interlace_fill.glsl``), so a change never leaves stale shadows behind
and a still view is exact after four frames.

With ``conservative`` on (``conservative_local`` extends it from suns to the other lights) each
light first gets a conservative occupancy map (:mod:`.conservative`, ``HS_CONSERVATIVE``):
receivers nearer the light than every caster in their map column are lit without a ray, the
others trace only up to the first possible caster depth. Exact: the masks equal those traced
without the map. Off by default: on llvmpipe building the map (every caster triangle through a
geometry shader) costs what the skipped rays save (``benchmarks/bench_pipeline.py --maps``).
"""
from __future__ import annotations

import time

import moderngl
import numpy as np

from . import create_mask_texture
from .conservative import ConservativeMaps


def light_ray_uniforms(light, origin=(0.0, 0.0, 0.0)) -> tuple[bool, tuple]:
    """(local, u_light_vec): a sun gives the unit direction towards it, other lights their
    position (area lights are points for now) relative to ``origin`` (the bake's)."""
    if light.type == "SUN":
        return False, tuple(float(v) for v in -light.direction)
    return True, tuple(float(v) for v in light.position - np.asarray(origin, np.float64))


def light_cone(light) -> tuple[tuple, float]:
    """(u_light_axis, u_light_cone) of a local light: where ``dot(light -> p, axis)`` is at most
    the cone value the light does not shine (as ``shaders/common/lights.glsl`` evaluates it)."""
    axis = tuple(float(v) for v in light.direction)
    if light.type == "SPOT":
        return axis, float(np.cos(light.spot_size / 2))
    if light.type == "AREA":
        return axis, 0.0
    return axis, -2.0


def offset_origins(p: np.ndarray, n: np.ndarray, slack: np.ndarray) -> np.ndarray:
    """numpy mirror of ``offset_origin`` in ``shaders/raytrace.glsl`` (float32 throughout)."""
    p = np.asarray(p, np.float32)
    n = np.asarray(n, np.float32)
    of_i = (np.float32(256.0) * n).astype(np.int32)
    bits = p.view(np.int32)
    p_i = np.where(p < 0, bits - of_i, bits + of_i).astype(np.int32).view(np.float32)
    q = np.where(np.abs(p) < np.float32(1 / 32), p + np.float32(1 / 65536) * n, p_i)
    return (q + n * np.asarray(slack, np.float32)[..., None]).astype(np.float32)


def surface_points(camera, rows, cols, depth) -> np.ndarray:
    """numpy mirror of ``surface_point`` in ``shaders/raytrace.glsl`` without the camera's
    position: camera-relative points (N, 3) of pixels (rows, cols) (row 0 = top) at G-buffer
    view ``depth``, in float32 as the shader computes them. ``camera``: ``GBuffer.camera``."""
    f = np.float32
    W, H = camera.resolution
    fx = ((np.asarray(cols) + f(0.5)) / f(W)).astype(f)
    fy = ((f(H - 1) - np.asarray(rows) + f(0.5)) / f(H)).astype(f)
    xmin, xmax, ymin, ymax = (f(v) for v in camera.viewplane)
    cs = f(camera.clip_start)
    local = np.stack([xmin * (f(1) - fx) + xmax * fx, ymin * (f(1) - fy) + ymax * fy,
                      np.full(len(fx), -cs, f)], axis=1)
    R = camera.cam_rot.astype(f)
    depth = np.asarray(depth, f)
    if camera.ortho:
        return local @ R.T + (-R[:, 2])[None] * (depth - cs)[:, None]
    return (local @ R.T) * (depth / cs)[:, None]


def shadow_rays(gbuffer, pixels, light, origin=(0.0, 0.0, 0.0)):
    """The rays ``shaders/raytrace.glsl`` traces for G-buffer pixels ``(rows, cols)``:
    ``(origins, dirs, tmax, facing)``. Origins are world space (float64: the shader's float32
    bake-space origins plus the bake's ``origin``); samples with ``facing`` False are not traced
    (mask 0)."""
    rows, cols = pixels
    origin = np.asarray(origin, np.float64)
    cam = gbuffer.camera
    depth = gbuffer.read("depth")[rows, cols]
    n = gbuffer.read("normal")[rows, cols, :3].astype(np.float32)
    p = (cam.cam_pos - origin).astype(np.float32) + surface_points(cam, rows, cols, depth)
    local, vec = light_ray_uniforms(light, origin)
    vec = np.asarray(vec, np.float32)  # (as the shader's uniform)
    to_light = vec - p if local else np.broadcast_to(vec, p.shape)
    facing = (n * to_light).sum(axis=1) > 0
    if local:
        axis, cone = light_cone(light)
        unit = to_light / np.linalg.norm(to_light, axis=1, keepdims=True)
        facing &= (-unit @ np.asarray(axis, np.float32)) > np.float32(cone)
    o = offset_origins(p, n, depth * np.float32(3.0e-6))
    if local:
        d = vec - o
        tmax = np.ones(len(o), np.float32)
    else:
        d = np.broadcast_to(vec, o.shape).copy()
        tmax = np.full(len(o), np.inf, np.float32)
    return o.astype(np.float64) + origin, d, tmax, facing


class RaytracePass:
    def __init__(self, ctx: moderngl.Context, programs, scene_textures, conservative: bool = False):
        self.ctx = ctx
        self.programs = programs
        self.scene_textures = scene_textures
        self.conservative = conservative  # build and use conservative occupancy maps (suns)
        # ... also for point/spot/area lights: exact too, but on llvmpipe the cube map costs about
        # what it saves on the forest (measured in benchmarks/bench_pipeline.py), so off by default
        self.conservative_local = False
        self.maps = ConservativeMaps(ctx, programs)
        self.last_map_ms = 0.0  # time spent building the maps in the last render (incl. finish)
        self._targets: dict = {}  # (light, role) -> texture
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
        tex = self._targets.get(key)
        if tex is None or tex.size != (w, h):
            if tex is not None:
                tex.release()
            tex = self._targets[key] = create_mask_texture(self.ctx, w, h, fill=1.0)
            self._valid_phases = 0
        return tex

    def render(self, scene, gbuffer, settings, lights, on_light=None) -> dict:
        """Masks ``{light_index: R32F texture}`` at ``settings.mask_size`` of the G-buffer;
        ``on_light(index)`` is called before each light."""
        ctx = self.ctx
        w, h = settings.mask_size(gbuffer.width, gbuffer.height)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.last_defines = {}
        self.last_map_ms = 0.0
        masks = {}
        if self.conservative and lights and (self.conservative_local or any(
                not light_ray_uniforms(scene.lights[li])[0] for li in lights)):
            t0 = time.perf_counter()
            self.maps.begin_frame(scene, gbuffer)
            self.last_map_ms += (time.perf_counter() - t0) * 1e3
        origin = self.scene_textures.baked.origin
        for li in lights:
            if on_light is not None:
                on_light(li)
            local, vec = light_ray_uniforms(scene.lights[li], origin)
            defines = self.defines(settings, local)
            cmap = None
            if self.conservative and (self.conservative_local or not local):
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
        prog["u_scale"].value = settings.mask_scale
        prog["u_full_size"].value = (gbuffer.width, gbuffer.height)
        prog["u_light_vec"].value = light_vec
        if "u_light_axis" in prog:
            prog["u_light_axis"].value, prog["u_light_cone"].value = light_cone(light)
        prog["u_cam_bake"].value = tuple(float(v) for v in gbuffer.camera.cam_pos - self.scene_textures.baked.origin)
        if settings.max_distance > 0:
            prog["u_max_distance"].value = float(settings.max_distance)
        out = self._target((li, "out"), w, h)
        if not settings.interlace:
            self._draw(vao, out, w, h)
            return out
        hist = self._target((li, "hist"), w, h)
        hist.use(unit)
        prog["u_history"].value = unit
        prog["u_phase"].value = self._phase
        prog["u_valid_phases"].value = self._valid_phases
        self._draw(vao, out, w, h)
        return self._fill(out, hist, w, h)

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
        self.maps.release()
        for tex in self._targets.values():
            tex.release()
        self._targets.clear()
