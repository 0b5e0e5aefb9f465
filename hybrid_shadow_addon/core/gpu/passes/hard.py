"""The ray-traced pass's visibility by plans: one ray per pixel and light, or fewer and a
refinement (hard lights, and soft lights whose plan traces all their samples at once).

- ``full`` (``high``): one ray per pixel and shadowed light.
- ``refine`` (``medium`` / ``low``): coarse rays every 2nd / 4th pixel, then refinement
  (:mod:`.refine`): pixels whose coarse neighbourhood agrees and stands for them take its
  answer, the others get their own ray, the very ray ``high`` traces, under the depth test.
- ``coarse`` (``upsample='nearest'``): the coarse mask alone, left to the upsample pass (the
  thesis' blocky look, for comparisons).
- ``interlace`` (any quality; thesis 3.5.2): one pixel of every 2x2 block per frame, traced
  as a quarter-resolution mask (a full-resolution pass in which three pixels of four only copy
  their history would keep every 8-pixel SIMD group of a software rasteriser tracing) and merged
  with the history (``shaders/interlace_merge.glsl``); pixels whose history is not up to date
  since the last :meth:`~HardVisibility.reset_history` are refined from this frame's rays, so a
  change never leaves stale shadows behind, the first frame after it is nearly exact and a still
  view is exact after four frames.

A hard light on the two-level BVH traces its light grid where :class:`.light_grid.LightGridCache`
has one (``HS_LIGHT_GRID``); its BVH time is measured otherwise, the measure a grid must pay back.

Every plan traces on one of two paths (``Settings.trace_path``), with the same masks: full-screen
draws of the fragment stage (the refinement's marks through the depth test), or on the compute
path (:attr:`HardVisibility.compute`) the queues of :mod:`.queue`, whose time follows the rays.
"""
from __future__ import annotations

import time
from contextlib import nullcontext

from ..targets import TargetCache, draw_fullscreen, set_uniforms
from .base import LightVisibility
from .light_grid import LightGridCache
from .reproject import light_key
from .trace import LightRay, RaytraceOptions, TraceProgram

#: the defines of the trace that the refinement's classify program takes over
CLASSIFY_DEFINES = ("HS_LIGHT_LOCAL", "HS_LIGHT_SUN", "HS_MAX_DISTANCE", "HS_INTERLACE", "HS_SOFT", "HS_SOFT_SHAPE",
                    "HS_TERMINATOR")


def plan_of(settings) -> str:
    """``full`` (one ray per pixel), ``refine`` (coarse rays, then refinement), ``interlace``
    (this frame's phase, refinement where history is missing) or ``coarse`` (the coarse mask
    alone, upscaled by the upsample pass: ``upsample='nearest'``, the thesis' look)."""
    if settings.interlace:
        return "interlace"
    if settings.mask_scale == 1:
        return "full"
    return "coarse" if settings.upsample == "nearest" else "refine"


class HardVisibility(LightVisibility):
    """Masks of the lights traced by the frame's plan (:func:`plan_of`), with the interlacing
    history and the hard lights' grids (:attr:`light_grids`)."""

    def __init__(self, gpu, refiner, program: TraceProgram, options: RaytraceOptions, reuse=None, queue=None):
        super().__init__(gpu)
        self.refiner = refiner
        self.queue = queue  # the compute path's RayQueue
        self.compute = False  # this frame traces on the compute path
        self.reuse = reuse  # a MaskReprojection: the full plan's hard lights reuse their history
        self.trace = program
        self.options = options
        self.light_grids = LightGridCache(gpu, eager=options.eager_light_grids)
        self._targets = TargetCache(self.ctx, fill=1.0, what="mask")  # (light, role) -> target
        self._phase = 0
        self._valid_phases = 0
        self.plan = self._last_plan = None
        self._grids_on = False  # whether this frame's hard lights may trace grids

    def reset_history(self) -> None:
        """Forget the interlacing history."""
        self._valid_phases = 0

    def _target(self, key, w, h, components: int | None = None):
        t = self._targets.get(key, w, h, components)
        if self._targets.created:
            self._valid_phases = 0
        return t

    def still(self) -> bool:
        """Interlacing: every other phase's history is up to date (a still view)."""
        return self._valid_phases | (1 << self._phase) == 15

    def begin_frame(self, job) -> None:
        """The frame's plan, the pixels with geometry counted (full resolution, and the coarse
        samples' pixels) and the refinement's grid of coarse samples."""
        gbuffer, settings = job.gbuffer, job.settings
        full = gbuffer.size
        scale = settings.mask_scale
        plan = self.plan = plan_of(settings)
        if plan != self._last_plan:
            self._valid_phases = 0
            self._last_plan = plan
        self.light_grids.eager = self.options.eager_light_grids
        self.light_grids.begin_frame()
        self._grids_on = LightGridCache.usable(self.trace.scene_textures.baked, settings)
        if not job.lights:
            return
        self.refiner.count_valid(gbuffer, full, 1, "valid")
        if plan in ("refine", "coarse"):
            self.refiner.count_valid(gbuffer, settings.mask_size(*full), scale, "coarse")
        if plan == "refine":
            self.refiner.prepare(gbuffer, scale, (scale // 2, scale // 2), False)
        elif plan == "interlace":  # (this frame's phase: one pixel of each 2x2 block)
            off = (self._phase & 1, self._phase >> 1)
            grid = (max(1, -(-(full[0] - off[0]) // 2)), max(1, -(-(full[1] - off[1]) // 2)))
            self.refiner.count_valid(gbuffer, grid, 2, "coarse", off)
            # (a still view classifies nothing: _trace merges the history alone)
            self.refiner.prepare(gbuffer, 2, off, True, geometry=not self.still())

    def attach_grid(self, job, ray: LightRay) -> None:
        """Give a hard light its grid (and its defines) where the cache has one."""
        if self._grids_on and ray.soft is None:
            ray.grid = self.light_grids.for_light(job.scene, ray.light, ray.local, ray.vec)
            if ray.grid is not None:
                ray.defines.update(ray.grid.defines)

    def light(self, job, ray: LightRay):
        timed = self._grids_on and ray.soft is None and ray.grid is None and not self.light_grids.eager
        if not timed:
            return self._trace(job, ray)
        local, vec = ray.local, ray.vec
        with self.gpu.clock.span(lambda ms: self.light_grids.note_bvh(local, vec, ms)):
            return self._trace(job, ray)  # (the light's BVH time: what a grid would have to pay back)

    def end_frame(self, job) -> None:
        self.light_grids.end_frame()
        if self.plan == "interlace":
            self._valid_phases |= 1 << self._phase
            self._phase = (self._phase + 1) % 4

    def _program(self, defines, ray, gbuffer, settings, scale):
        return self.trace.bind(defines, ray, gbuffer, settings, scale)

    def _trace_all(self, defines, ray, gbuffer, settings, scale: int, targets, uniforms=None) -> None:
        """Every texel of ``targets[0]`` traced (``targets[1]``: the codes, with ``HS_CODE_OUT``)
        by the program of ``defines`` (``uniforms``: beyond the light's): a full-screen draw,
        or on the compute path a queue of the texels that need a ray."""
        if self.compute:
            def bound(kernel):
                prog, _ = self.trace.bind_compute(defines, ray, gbuffer, settings, scale, kernel)
                set_uniforms(prog, uniforms or {})
                return prog

            self.queue.trace(lambda: bound("gen"), lambda: bound("trace"), [t.texture for t in targets],
                             targets[0].size, kind="queued")
            return
        prog, vao, _ = self._program(defines, ray, gbuffer, settings, scale)
        set_uniforms(prog, uniforms or {})
        if len(targets) == 1:
            self.gpu.budget.fullscreen(vao, targets[0])
        else:
            self.reuse.draw_fresh(vao, targets, self.gpu.budget)

    def _trace_marked(self, key, dst, defines, ray, gbuffer, settings, kind: str = "refined", extra=()) -> None:
        """The pixels the refinement (or the reuse's mark) marked, traced into ``dst`` (and
        ``extra``) at full resolution: under the depth test, or queued on the compute path."""
        if self.compute:
            self.refiner.trace_marked(
                key, dst, lambda: self.trace.bind_compute(defines, ray, gbuffer, settings, 1, "trace")[0],
                kind=kind, extra=extra)
            return
        _, vao, _ = self._program(defines, ray, gbuffer, settings, 1)
        self.refiner.refine(key, dst, vao, kind=kind, extra=extra)

    def _trace(self, job, ray: LightRay):
        gbuffer, settings, plan = job.gbuffer, job.settings, self.plan
        li, defines = ray.index, ray.defines
        full = gbuffer.size
        ctx = self.ctx
        if plan == "full" and ray.soft is None and self.reuse is not None and self.reuse.enabled:
            return self._trace_reusing(job, ray)
        if plan in ("full", "coarse"):
            scale = 1 if plan == "full" else settings.mask_scale
            size = full if plan == "full" else settings.mask_size(*full)
            out = self._target((li, "out" if plan == "full" else "coarse"), *size)
            self._trace_all(defines, ray, gbuffer, settings, scale, [out])
            return out.texture
        plain = {k: v for k, v in defines.items() if k != "HS_INTERLACE"}
        uniforms = self.trace.uniforms(ray, gbuffer, settings)
        class_defs = {k: v for k, v in defines.items() if k in CLASSIFY_DEFINES}
        class_defs.update(self.refiner.defines())
        if plan == "refine":
            scale = settings.mask_scale
            coarse = self._target((li, "coarse"), *settings.mask_size(*full))
            self._trace_all(plain, ray, gbuffer, settings, scale, [coarse])
            dst = self._target((li, "out"), *full)
            self.refiner.classify((li, "out"), dst, gbuffer, coarse.texture, class_defs, uniforms)
        else:  # interlace: this frame's phase pixel of each 2x2 block traced densely, with the history
            off = (self._phase & 1, self._phase >> 1)
            # (one size for every phase: an odd side's last texel then traces the edge pixel
            # again; a scratch target, not _target's: it carries nothing from frame to frame)
            traced = self._targets.get((li, "traced"), (full[0] + 1) // 2, (full[1] + 1) // 2)
            self._trace_all(defines, ray, gbuffer, settings, 2, [traced], {"u_offset": off})
            out = self._target((li, "out"), *full)
            hist = self._target((li, "hist"), *full)
            mprog, mvao = self.programs.fullscreen("interlace_merge")
            traced.texture.use(0)
            hist.texture.use(1)
            set_uniforms(mprog, {"u_traced": 0, "u_history": 1, "u_phase": self._phase,
                                 "u_valid_phases": self._valid_phases})
            draw_fullscreen(ctx, mvao, out)
            dst = hist
            if self.still():
                # a still view: every pixel has this frame's ray or an up-to-date history, so
                # nothing to classify or refine (what classify would write is the merge itself)
                ctx.copy_framebuffer(hist.fbo, out.fbo)
                return hist.texture
            self.refiner.classify((li, "hist"), dst, gbuffer, out.texture, class_defs, uniforms)
        key = (li, "hist" if plan == "interlace" else "out")
        self._trace_marked(key, dst, plain, ray, gbuffer, settings)
        return dst.texture

    def _trace_reusing(self, job, ray: LightRay):
        """A hard light's full-resolution mask the way :class:`.reproject.ReuseChoice` finds
        cheaper: reusing (the history that stands and rays for the other pixels, or every pixel
        traced with the codes the next frame reuses where it has none), or plainly traced."""
        gbuffer, settings, rp = job.gbuffer, job.settings, self.reuse
        li = ray.index
        key = light_key(ray.light, settings)
        way = rp.choice.way(li, key)
        timed = rp.choice.auto and rp.choice.wants_time(li, way)
        prev = now = uniforms = None
        if way == "reuse":
            prev, now = rp.history(li, "hard", key, gbuffer.size)
        if prev is not None:  # (the previous pixels first: shared by the frame's reusing lights, timed apart)
            uniforms = self.trace.uniforms(ray, gbuffer, settings)
            rp.history_map(gbuffer, ray.defines, uniforms, timed)
        noted = [timed]  # (priming the history is neither way's cost: not noted)

        def note(ms):
            if noted[0]:
                rp.timed(li, way, ms)

        with self.gpu.clock.span(note) if timed else nullcontext():
            done = self._trace_way(way, li, ray, gbuffer, settings, prev, now, uniforms, noted)
        return done.texture

    def _trace_way(self, way, li, ray, gbuffer, settings, prev, now, uniforms, noted):
        """:meth:`_trace_reusing`'s trace of light ``li`` the ``way`` chosen; its target."""
        rp = self.reuse
        if way == "plain":
            out = self._target((li, "out"), *gbuffer.size)
            self._trace_all(ray.defines, ray, gbuffer, settings, 1, [out])
            rp.plain_lights += 1
            done = out
        else:
            defines = {**ray.defines, "HS_CODE_OUT": 1}
            if prev is None:
                self._trace_all(defines, ray, gbuffer, settings, 1, list(now))
                noted[0] = False
            else:
                defs = {k: v for k, v in ray.defines.items() if k in CLASSIFY_DEFINES}
                rp.mark((li, "reuse"), gbuffer, defs, uniforms, prev, now)
                if rp.time_retrace:
                    self.ctx.finish()
                    t1 = time.perf_counter()
                self._trace_marked((li, "reuse"), now[0], defines, ray, gbuffer, settings, kind="retraced",
                                   extra=(now[1],))
                if rp.time_retrace:
                    self.ctx.finish()
                    rp.retrace_ms += (time.perf_counter() - t1) * 1e3
            done = now[0]
        return done

    def release(self) -> None:
        self.light_grids.close()
        self._targets.release()
