"""Shadow mode ``raytrace``: shadow rays (``shaders/raytrace.glsl``) through the baked scene
(:class:`~..scene_textures.SceneTextures`), full-resolution masks for every quality.

:class:`RaytracePass` coordinates; the work per light is done by one of two visibilities over
the same interface (:class:`.base.LightVisibility`):

- :class:`.hard.HardVisibility`: the plans (``full``, ``refine``, ``coarse``, ``interlace``)
  with their refinement and interlacing history, and the hard lights' grids;
- :class:`.soft.SoftVisibility`: lights with a size at ``high`` (a ``full`` plan): probes,
  refinement of the penumbrae, packets, the noise check, accumulation and the penumbra filter.
  (A soft light under another plan traces all its samples at once, as the hard side does.)

The program is built from the bake's defines (grid levels, meshes and/or spheres present) plus
``HS_MAX_DISTANCE``, ``HS_INTERLACE`` and the rest as needed (the table in
``shaders/raytrace.glsl``), so a scene compiles only the code it needs. With
``Settings.conservative`` set (``sun``: suns only, ``all``: every light) each light first gets
a conservative occupancy map (:mod:`.conservative`, ``HS_CONSERVATIVE``): receivers nearer the
light than every caster in their map column are lit without a ray, the others trace only up to
the first possible caster depth (exact: the masks do not change).

On a software rasteriser (``RaytraceOptions.cull_lights``), a light that reaches no visible
surface (a spot whose cone holds none, :mod:`.light_cull`) takes no pass of rays, at every
quality, interlaced and accumulating too (not ``upsample='nearest'``'s coarse masks); its mask,
bit-identical, is the answers without rays (``HS_NO_RAYS``), one for all such lights of the
frame. It keeps no history: whether a light is
left out depends on the G-buffer alone, and every change of it resets the history.

:meth:`RaytracePass.shadow_stats` gives a :class:`.trace.RaytraceStats`. The numpy mirror of
the rays traced here is ``core/oracle/rays.py``.
"""
from __future__ import annotations

from dataclasses import asdict

import moderngl

from ...errors import GPUError
from ..context import software_context
from ..lights import light_ray_uniforms, soft_shape
from ..programs import COMPUTE_GL
from ..targets import TargetCache, draw_fullscreen
from .base import ShadowPass
from .hard import HardVisibility
from .light_cull import LightCull, cull_candidate
from .queue import RayQueue
from .refine import Refiner
from .reproject import MaskReprojection
from .soft import SOFT_PROBES, SoftVisibility
from .trace import LightRay, RaytraceOptions, RaytraceStats, TraceProgram


class RaytracePass(ShadowPass):
    """Masks ``{light index: texture}`` at the G-buffer's resolution (the coarse masks, at
    ``settings.mask_size``, with ``upsample='nearest'``)."""

    light_label = "Ray tracing shadows"
    needs_bake = True

    def __init__(self, gpu, options: RaytraceOptions | None = None):
        super().__init__(gpu)
        self.scene_textures = gpu.scene_textures
        self.trace = TraceProgram(gpu)
        self.refiner = Refiner(gpu)
        self.queue = RayQueue(gpu) if self.ctx.version_code >= COMPUTE_GL else None
        self._software = software_context(self.ctx)
        self.refiner.queue = self.queue
        self._options = options or RaytraceOptions()
        self.reuse = MaskReprojection(gpu, self.refiner)
        self.hard = HardVisibility(gpu, self.refiner, self.trace, self._options, self.reuse, self.queue)
        self.soft = SoftVisibility(gpu, self.refiner, self.trace, self._options, self.reuse, self.queue)
        self.cull = LightCull(gpu)
        self.maps = None  # ConservativeMaps, made by the first frame with Settings.conservative on
        self.last_map_ms = 0.0  # time spent building the maps in the last render (incl. finish)
        self._scratch = TargetCache(self.ctx, fill=1.0, what="mask")  # the no-rays mask
        self.culled: list = []  # the lights of the last frame that reached no pixel (no pass of rays)
        self.last_defines: dict = {}
        self._soft_samples = 1  # samples per pixel asked of the soft lights of the last frame
        self.path = "fragment"  # the last frame's trace path (Settings.trace_path resolved)
        self._soft_lights = 0

    @property
    def options(self) -> RaytraceOptions:
        return self._options

    @options.setter
    def options(self, options: RaytraceOptions) -> None:
        self._options = self.hard.options = self.soft.options = options

    @property
    def light_grids(self):
        """The hard lights' :class:`.light_grid.LightGridCache`."""
        return self.hard.light_grids

    def configure_reuse(self, enabled: bool, auto: bool, exact: bool) -> bool:
        self.reuse.enabled, self.reuse.choice.auto, self.reuse.exact = enabled, auto, exact
        return True

    def reset_history(self) -> None:
        """Forget interlacing, accumulation and reuse history."""
        self.hard.reset_history()
        self.soft.reset_history()
        self.reuse.reset_history()

    def camera_moved(self) -> None:
        """The camera moved: interlacing starts over; the masks and sums are reprojected."""
        self.hard.reset_history()
        self.soft.camera_moved()

    def invalidate(self, boxes) -> None:
        """Objects with these old and new bounds ((n, 2, 3), bake space) changed: pixels whose
        shadow rays (a soft light's cone) can meet them trace again, the rest keep their history
        (a soft light's sums carry over as across a camera move)."""
        self.hard.reset_history()
        self.soft.camera_moved()
        self.reuse.invalidate(boxes)

    def reset_light(self, index: int) -> None:
        """Light ``index`` changed: its history alone is forgotten."""
        self.hard.reset_history()
        self.soft.reset_light(index)
        self.reuse.reset_light(index)

    def shadow_stats(self, job, counts: bool = True) -> RaytraceStats:
        mw, mh = job.settings.mask_size(*job.size)
        n = len(job.lights)
        if not counts:
            return self._stats(job, mw, mh, None, None, None)
        valid = self.refiner.count("valid") if n else 0
        reused_pixels = 0
        if self.path == "compute":  # (the texels queued: rays; the soft side's lights as below)
            reused = self.reuse.reused_lights if self.hard.plan == "full" else 0
            traced = (self.queue.count("queued") + self.refiner.count("retraced") + self.refiner.count("refined")
                      + valid * self._soft_lights)
            if reused:
                reused_pixels = self.refiner.count("kept") - reused * (mw * mh - valid)
        elif self.hard.plan == "full":
            reused = self.reuse.reused_lights
            retraced = self.refiner.count("retraced") if reused else 0
            traced = valid * (n - len(self.culled) - reused) + retraced
            # (the mark counts the background it writes too: every pixel without geometry)
            reused_pixels = self.refiner.count("kept") - reused * (mw * mh - valid) if reused else 0
        else:
            traced = self.refiner.count("coarse") * (n - len(self.culled)) + self.refiner.count("refined")
        return self._stats(job, mw, mh, int(traced), int(valid * n), int(reused_pixels))

    def _stats(self, job, mw, mh, traced, pixels, reused_pixels) -> RaytraceStats:
        return RaytraceStats(
            mask_resolution=[mw, mh], rays=int(mw * mh * len(job.lights)), rays_traced=traced, pixels=pixels,
            pixels_reused=reused_pixels,
            samples=int(max(self._soft_samples, self.soft.most_samples)),
            accumulated_samples=self.soft.accumulated, lights_culled=len(self.culled),
            reuse_ways={"reused": self.reuse.reused_lights, "plain": self.reuse.plain_lights},
            trace_path=self.path,
            noise={k: round(v, 6) for k, v in self.soft.last_noise.items()},
            defines=sorted(f"{k}={v}" for k, v in self.last_defines.items()))

    def stats(self, job, counts: bool = True) -> dict:
        return asdict(self.shadow_stats(job, counts))

    def trace_path(self, settings) -> str:
        """``compute`` or ``fragment``: ``settings.trace_path`` on this context (``auto``:
        compute where a GPU offers GL 4.3, fragment on a software rasteriser, where the compute
        path measured slower: BENCHMARKS.md, "Compute trace path"); a GPUError where compute is
        asked of a context without it."""
        if settings.trace_path == "fragment":
            return "fragment"
        if self.queue is not None:
            if settings.trace_path == "auto" and self._software:
                return "fragment"
            return "compute"
        if settings.trace_path == "compute":
            v = self.ctx.version_code
            raise GPUError(f"trace path 'compute' needs OpenGL 4.3 compute shaders; this GPU offers "
                           f"{v // 100}.{v % 100 // 10} ({self.ctx.info.get('GL_RENDERER', '?')}): "
                           "choose 'auto' or 'fragment'")
        return "fragment"

    def render(self, job) -> dict:
        scene, gbuffer, settings, lights = job.scene, job.gbuffer, job.settings, job.lights
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.last_defines = {}
        self.last_map_ms = 0.0
        self.path = self.trace_path(settings)
        self.hard.compute = self.soft.compute = self.path == "compute"
        if self.queue is not None:
            self.queue.begin_frame()
        self.refiner.begin_frame()
        self.reuse.begin_frame()
        self.hard.begin_frame(job)
        self.soft.begin_frame(job)
        maps = None
        if settings.conservative != "off":
            maps = self._conservative_maps()
            maps.start(scene, gbuffer, settings, lights)
        origin = self.scene_textures.baked.origin
        self.gpu.linking.update(scene)
        # lights that reach no pixel get the answers without rays (one shared mask), no trace;
        # on the compute path only those the soft side would trace (a hard light's queue is
        # empty there anyway, and the test's read-back would stall the frame)
        self.culled = []
        culling = self._software if self._options.cull_lights is None else self._options.cull_lights

        def tested(light) -> bool:  # (a light the pass would trace on its own)
            return self.path != "compute" or self._soft_side(light, settings)

        cull = culling and self.hard.plan != "coarse" and any(
            cull_candidate(scene.lights[li], settings.hard) and tested(scene.lights[li]) for li in lights)
        if cull:
            self.cull.prepare(gbuffer, settings, gbuffer.camera.cam_pos - origin)
        no_rays = None
        self._soft_samples = 1
        self._soft_lights = 0  # lights the soft side traced this frame
        self.trace.scene_frame = int(getattr(scene, "frame", 1))
        self.trace.smooth = any(m.normals is not None for m in scene.models)
        masks = {}
        for li in lights:
            job.light_started(li)
            light = scene.lights[li]
            local, vec = light_ray_uniforms(light, origin)
            if cull and tested(light) and not self.cull.reaches(light, vec if local else None, settings.hard):
                if no_rays is None:
                    no_rays = self._no_rays(LightRay(li, light, local, vec, None, {}), gbuffer, settings)
                masks[li] = no_rays
                self.culled.append(li)
                continue
            soft = soft_shape(light, settings.hard)
            if soft is not None:
                self._soft_samples = max(self._soft_samples, int(settings.samples))
            ray = LightRay(li, light, local, vec, soft, self.trace.defines(settings, local, soft))
            if maps is not None and soft is None and light.blocker_set < 0:
                # (a map bounds the rays to a light's centre only; it holds every caster: not
                # for a light whose blocker collection leaves some out)
                ray.cmap = maps.for_light(scene, li, local)
                if ray.cmap is not None:
                    ray.defines["HS_CONSERVATIVE"] = 1
            self.hard.attach_grid(job, ray)
            self.last_defines.update(ray.defines)
            side = self._visibility(ray, settings)
            self._soft_lights += side is self.soft
            masks[li] = side.light(job, ray)
        self.last_defines.update(self.soft.defines_used)
        self.hard.end_frame(job)
        self.soft.end_frame(job)
        self.reuse.end_frame(gbuffer)
        if maps is not None:
            self.last_map_ms = maps.last_ms
        if not settings.max_distance > 0:  # (beyond it the no-rays mask is 1: the light may shine there)
            job.dark = set(self.culled)
        return masks

    def _soft_side(self, light, settings) -> bool:
        """Whether ``light`` is traced by the soft side: a soft light of a ``full`` plan that
        takes more than the probes' samples (or accumulates)."""
        return soft_shape(light, settings.hard) is not None and self.hard.plan == "full" and (
            settings.accumulate or settings.samples > SOFT_PROBES)

    def _visibility(self, ray: LightRay, settings):
        """The soft side (:meth:`_soft_side`), or the hard side's plan."""
        return self.soft if self._soft_side(ray.light, settings) else self.hard

    def _conservative_maps(self):
        if self.maps is None:
            from .conservative import ConservativeMaps

            self.maps = ConservativeMaps(self.gpu)
        return self.maps

    def _no_rays(self, ray: LightRay, gbuffer, settings):
        """The mask of a light that no pixel needs a ray of: 1 on the background and beyond the
        max distance, 0 elsewhere (facing away, out of reach), as the trace writes it; one for
        all such lights of a frame (it depends on the G-buffer alone)."""
        defines = {**self.trace.defines(settings.replace(interlace=False), ray.local), "HS_NO_RAYS": 1}
        _, vao, _ = self.trace.bind(defines, ray, gbuffer, settings.replace(hard=True), 1)
        out = self._scratch.get(("no rays",), *gbuffer.size)
        draw_fullscreen(self.ctx, vao, out)
        return out.texture

    def release(self) -> None:
        self.hard.release()
        self.soft.release()
        self.reuse.release()
        self.cull.release()
        self.refiner.release()
        if self.queue is not None:
            self.queue.release()
        if self.maps is not None:
            self.maps.release()
        self._scratch.release()
