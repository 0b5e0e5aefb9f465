"""The ray-traced pass's soft visibility at ``high``: lights with a size (``lights.soft_shape``,
unless ``Settings.hard``) whose many samples per pixel go where they matter.

A probe pass traces 1 ray per pixel, the second probe-range pass (``shaders/soft_range.glsl``
CLASSIFY) writes the probe answer where every probe within 4 pixels saw all or none of the
light and marks the other pixels in the depth buffer, the trace then gives those alone (early
depth test) the rest of their ``samples`` rays, and a penumbra-only filter
(``shaders/soft_accumulate.glsl``, narrowing as the samples add up) follows; with
``Settings.accumulate`` (the viewport) each frame adds the sums of ``frame_samples`` rays per
pixel to those of the frames before instead, until ``reset_history``. On the two-level BVH
(alpha-cut casters too) a pixel's rays walk the scene as one packet (``HS_SOFT_PACKET``,
``shaders/common/scene_packet.glsl``); a draw traces at most ``CHUNK_RAYS`` rays per pixel (more
take several draws whose sums add up), since llvmpipe stops every loop of an invocation after
65535 iterations in all. Ray by ray in several draws (the grid), a refined pixel traces the
second half of its rays only where the first left its share strictly between 0 and 1
(``soft_accumulate.glsl`` PARTIAL marks them). With packets, a final render checks each light's
noise (``Settings.noise_target``): its sums keep those of the first half of the samples apart
(``u_split``), the masks of the two halves are filtered as masks of half the samples and
compared (NOISE), and a light estimated above the target gives its partial pixels as many
samples again.

On the compute path (:attr:`SoftVisibility.compute`) the same stages run over ray queues
(:mod:`.queue`): the probes queue the pixels that need a ray, the refinement the marked ones, and
their sums are stored into (or, where the fragment stage blends, added to) RGBA32F images. On a
GPU a queued pixel's samples spread over ``HS_QUEUE_LANES`` invocations (:func:`lanes_for`),
each summing its share, the first adding the shares up in lane order; on a software rasteriser
they walk as packets, as the fragment stage's do (``RaytraceOptions.soft_lanes``). Either way a
refined pixel traces all its samples (no early stop between halves) and final renders check
their noise.
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..context import software_context
from ..targets import TargetCache, draw_fullscreen, read_texture, set_uniforms
from .base import LightVisibility
from .hard import CLASSIFY_DEFINES
from .reproject import light_key, light_pad
from .trace import LightRay, RaytraceOptions, TraceProgram

SOFT_PROBES = 1  # HS_PROBES of shaders/common/soft_probe.glsl
PACKET_MIN_RAYS = 8  # a soft pass traces its rays as packets from this many rays per pixel on
#: The most rays per pixel one draw traces, ray by ray or as one packet walk: llvmpipe stops every
#: loop of a shader invocation once all of them together have run 65535 iterations, which a
#: pixel's rays through a heavy scene reach, silently leaving rays untraced. More rays take more
#: draws, whose sums add up.
CHUNK_RAYS = {"rays": 28, "packets": 64}
#: a final render's mask, filtered, is off from its exact share by about this times the mean
#: |a - b| of the masks of its two halves, each filtered alike (fitted on the built-in scenes'
#: soft masks against many-sample masks, BENCHMARKS.md)
NOISE_PER_SPLIT = 0.45
PLANE_SIGMA = 0.02  # the penumbra filter's tangent-plane distance scale, relative to the view depth
LANES = (4, 16)  # a queued texel's lanes on the compute path: below 16 rays, and from 16 on


def first_frame_lead(frame_samples: int) -> int:
    """Samples the viewport's first frame after a change traces beyond ``frame_samples`` in the
    penumbrae: it probes every pixel as a final render does and gives the pixels near a probe
    that saw part of the light four times the samples of a later frame (pixels elsewhere keep
    their probes' answer, and add the later frames' samples to it): at the default 4, enough
    for a pixel's rays to walk the scene as one packet (BENCHMARKS.md "The viewport's first
    frame"). 0 where a frame traces no more samples than the probes."""
    return 3 * int(frame_samples) if 2 * int(frame_samples) > SOFT_PROBES else 0


def chunk_spans(base: int, first: int, total: int, step: int) -> list:
    """``(start, count)`` of the draws that trace samples [first, total) after ``base``, at most
    ``step`` (CHUNK_RAYS) each, ending on multiples of ``step`` of the sequence (base + start):
    a packet never spans two aligned blocks of 64 samples (``shaders/raytrace.glsl``), so a
    draw across such a border would walk the scene once more."""
    spans, start = [], int(first)
    while start < total:
        n = min(step - (base + start) % step, total - start)
        spans.append((start, n))
        start += n
    return spans


def lanes_for(rays: int) -> int:
    """Invocations a queued texel's ``rays`` soft samples spread over on the compute path
    (``HS_QUEUE_LANES``): 4 below 16 rays, else 16 (two variants, so few programs to compile)."""
    return LANES[0] if rays < 16 else LANES[1]


def denoise_radius(samples: int) -> int:
    """Filter radius (pixels) of a soft mask with ``samples`` per pixel: 4 at 4 samples,
    shrinking as 1/sqrt(samples), 1 from 29 samples on (its range kernel narrows with the noise,
    so many samples are left almost as they are)."""
    return max(1, int(round(8.0 / np.sqrt(max(samples, 1)))))


#: the key of the scratch targets a final frame's soft lights share
FINAL_SCRATCH = "final"


class SoftVisibility(LightVisibility):
    """Masks of the soft lights of a ``full`` plan: probes and refinement, or a frame of the
    accumulation; each filtered within its penumbrae."""

    def __init__(self, gpu, refiner, program: TraceProgram, options: RaytraceOptions, reuse=None, queue=None):
        super().__init__(gpu)
        self.refiner = refiner
        self.queue = queue  # the compute path's RayQueue
        self.compute = False  # this frame traces on the compute path
        self.reuse = reuse  # a MaskReprojection: the accumulation carries its sums across moves
        self.trace = program
        self.options = options
        self._targets = TargetCache(self.ctx, fill=1.0, what="mask")  # (light, role) -> target
        self.sample_base = 0  # first sample index of this draw (accumulation advances it)
        self.split = 0  # the samples before this index also sum apart (raytrace.glsl u_split)
        self._accum: dict = {}  # light -> (frames accumulated, current target index, key, frames since a move)
        self._moved = False  # the camera moved or objects changed since the last frame
        self.most_samples = 1  # rays per pixel of the softest light of the last frame
        self.accumulated = None  # fewest samples per pixel of the soft lights' accumulated masks
        self.last_noise: dict = {}  # light name -> the last final render's noise estimate
        self.defines_used: dict = {}  # the soft passes' own defines of the last frame (stats)

    def reset_history(self) -> None:
        """Forget the accumulation."""
        self._accum.clear()

    def camera_moved(self) -> None:
        """The camera moved or objects changed: with :attr:`reuse`, the next frame carries the
        sums that stand over (:meth:`.reproject.MaskReprojection.carry_sums`); else forget."""
        if self.reuse is None:
            self.reset_history()
        self._moved = True

    def reset_light(self, index: int) -> None:
        """Forget one light's accumulation."""
        self._accum.pop(index, None)

    def begin_frame(self, job) -> None:
        self.most_samples = 1
        self.accumulated = None
        self.last_noise = {}
        self.defines_used = {}

    def light(self, job, ray: LightRay):
        gbuffer, settings = job.gbuffer, job.settings
        if settings.accumulate:
            return self._accumulate(ray, ray.defines, gbuffer, settings)
        # a final frame keeps each light's mask alone: its scratch targets (probes, sums, ranges)
        # are the same for every light
        out = self._target((ray.index, "out"), *gbuffer.size)
        got = self._probe_and_refine(ray, ray.defines, gbuffer, settings, out, scratch=FINAL_SCRATCH)
        self.most_samples = max(self.most_samples, got)
        return self._denoise(ray.index, out, gbuffer, denoise_radius(got), got, scratch=FINAL_SCRATCH)

    def _target(self, key, w, h, components: int | None = None):
        return self._targets.get(key, w, h, components)

    def _program(self, defines, ray, gbuffer, settings):
        """The full-resolution trace of ``defines`` from this draw's ``sample_base``."""
        return self.trace.bind(defines, ray, gbuffer, settings, 1, self.sample_base, self.split)

    def _probe_and_refine(self, ray, defines, gbuffer, settings, out, scratch=None) -> int:
        """A soft light's ``settings.samples`` rays per pixel into ``out``: a few probe rays per
        pixel, then the rest only near the pixels whose probes disagree (penumbrae); elsewhere
        the probes are exact. ``defines`` with ``HS_SOFT_ACCUM``: ``out`` gets the sums (RG).
        ``scratch``: the key of the scratch targets (default: the light's own)."""
        li = ray.index if scratch is None else scratch
        full = gbuffer.size
        accum = "HS_SOFT_ACCUM" in defines
        total = int(settings.samples)
        rays = total - SOFT_PROBES
        packet = self._packet_defines(defines, rays)
        # every sample of a refined pixel (packets; the compute path's lanes), no early stop
        whole = bool(packet) or self._lanes()
        # a final render's noise check (all samples traced): the sums keep their first half's
        # apart; a light whose masks of the two halves, each filtered, differ by more than the
        # target allows gives its partial pixels as many samples again
        check = whole and not accum and float(settings.noise_target) > 0.0 and total >= 2 * SOFT_PROBES
        chunked = self.compute or rays > self._chunk(packet) or check
        # ray by ray in several draws (the grid): the early stop between draws, the second half
        # only where the first left the share partial
        half = SOFT_PROBES + rays // 2 if chunked and not (accum or whole) and self.options.early_stop else total
        stages = [(SOFT_PROBES, half), (half, total)] if half < total else [(SOFT_PROBES, total)]
        probe_defs = {k: v for k, v in defines.items() if k != "HS_SOFT_ACCUM"}  # (the same probes either way)
        probe = self._target((li, "probe"), *full, components=self._sums_components())  # (sums: raytrace.glsl)
        self._trace_all({**probe_defs, "HS_SOFT_PROBE": 1}, ray, gbuffer, settings, probe)
        # the probe ranges' second pass writes the probe answers where they stand and marks the
        # rest in the depth buffer: only those are shaded by the refinement
        sums = out
        if chunked and not accum:  # (the refinement adds up sums, divided at the end)
            sums = self._target((li, "sums4" if check else "sums"), *full,
                                components=4 if check else self._sums_components())
        self._range((li, "probe"), probe.texture, gbuffer, sums=True,
                    classify=(sums, probe.texture, accum or chunked))
        got = total
        if chunked:
            # more rays than one draw may trace (CHUNK_RAYS): draws of at most that many
            # samples each, added to the probes' sums (the viewport's frames, at once)
            accum_defs = {**defines, "HS_SOFT_ACCUM": 1}
            self.split = total // 2 if check else 0
            try:
                for j, (first, last) in enumerate(stages):
                    if j:  # (the second half: only the pixels the first left partial)
                        self._mark_partial(li, sums)
                    self._add_marked(li, sums, accum_defs, ray, gbuffer, settings, first, last)
            finally:
                self.split = 0
            if check:
                self.last_noise[ray.light.name] = noise = self._noise(li, sums, gbuffer, total // 2)
                if noise > float(settings.noise_target):
                    self._mark_partial(li, sums)
                    self._add_marked(li, sums, accum_defs, ray, gbuffer, settings, total, 2 * total)
                    got = 2 * total
            if not accum:
                self._resolve(sums.texture, out)
            return got
        refine_defs = {**defines, "HS_SOFT_REFINE": 1, **self._soft_defines(defines, rays)}
        if not self.options.early_stop:
            refine_defs["HS_SOFT_FULL"] = 1
        prog, vao, unit = self._program(refine_defs, ray, gbuffer, settings)
        probe.texture.use(unit)
        prog["u_probe"].value = unit
        self.refiner.draw_marked((li, "soft"), out, vao)
        return got

    def _resolve(self, sums, out) -> None:
        """``out`` = the shares of sums texture ``sums`` (``soft_accumulate.glsl`` RESOLVE)."""
        prog, vao = self.programs.fullscreen("soft_accumulate", {"RESOLVE": 1})
        sums.use(0)
        set_uniforms(prog, {"u_sums": 0})
        draw_fullscreen(self.ctx, vao, out)

    def _mark_partial(self, li, sums) -> None:
        """Mark the pixels whose sums give a share strictly between 0 and 1 (the others keep
        theirs): the next :meth:`Refiner.draw_marked` shades those alone."""
        prog, vao = self.programs.fullscreen("soft_accumulate", {"PARTIAL": 1})
        sums.texture.use(0)
        set_uniforms(prog, {"u_sums": 0})
        self.refiner.mark((li, "soft"), sums, vao, color=False)

    def _noise(self, li, sums, gbuffer, half: int) -> float:
        """The estimated mean absolute noise of the mask of ``2 half`` samples in ``sums``: the
        masks of its two halves, each filtered as one of ``half`` samples is, differ by a mean
        |a - b| (every other pixel of each row and column); the full mask's noise after its filter
        is about NOISE_PER_SPLIT times that (``soft_accumulate.glsl`` NOISE, per 8 x 8 block)."""
        w, h = gbuffer.size
        prog, vao = self.programs.fullscreen("soft_accumulate", {"NOISE": 1})
        sums.texture.use(0)
        set_uniforms(prog, {"u_sums": 0, "u_samples": float(half), "u_plane_sigma": PLANE_SIGMA})
        gbuffer.bind(prog, 1)
        blocks = self._target((li, "noise"), (w + 7) // 8, (h + 7) // 8, components=2)
        draw_fullscreen(self.ctx, vao, blocks)
        acc = read_texture(blocks.texture).reshape(-1, 2).astype(np.float64).sum(axis=0)
        return NOISE_PER_SPLIT * float(acc[0]) / max(float(acc[1]), 1.0)

    def _accumulate(self, ray, defines, gbuffer, settings):
        """One more frame of a soft light's running sums (``Settings.accumulate``): trace
        ``frame_samples`` rays per pixel continuing each pixel's sequence, add their (weighted
        visibility, weight) sums to those of the frames before, and filter the mask they make
        within its penumbrae (the fewer its samples, the wider). The first frame after a change
        probes every pixel and gives the penumbrae ``frame_samples`` + :func:`first_frame_lead`
        samples. Converged (``samples`` reached): no rays, the mask filtered as a final
        render's is."""
        ctx = self.ctx
        li = ray.index
        full = gbuffer.size
        fs = int(settings.frame_samples)
        lead = first_frame_lead(fs)

        def traced(frames: int) -> int:  # samples per penumbra pixel after that many frames
            return lead + frames * fs if frames else 0

        key = (fs, int(settings.samples), light_key(ray.light, settings))
        n, cur, k, since = self._accum.get(li, (0, 0, key, None))
        src, dst, carry = self._sums_targets(ray, key, gbuffer, settings, n if k == key else 0, cur)
        if k != key or src is None:
            n, since = 0, None
        elif carry:
            since = 0
        converged = traced(n) >= settings.samples and (since is None or since * fs >= settings.samples)
        sums = dst
        if converged and self._reusing():  # (the history keeps this frame's sums)
            ctx.copy_framebuffer(dst.fbo, src.fbo)
        elif converged:
            sums = src
        else:
            base = self.sample_base
            self.sample_base = traced(n)
            accum = {**defines, "HS_SOFT_ACCUM": 1}
            new = self._target((li, "new"), *full, components=self._sums_components())
            if n == 0 and lead:  # probes everywhere, fs + lead samples in the penumbrae (at most samples)
                first = settings.replace(samples=min(fs + lead, int(settings.samples)))
                self._probe_and_refine(ray, accum, gbuffer, first, new)
            elif self.compute:  # fs samples over lanes, in dispatches whose sums add up
                for j, (defs, n_rays, lanes) in enumerate(self._spans(accum, 0, fs)):
                    self._trace_all({**defs, **({"HS_SUMS_ADD": 1} if j else {})}, ray, gbuffer,
                                    settings.replace(samples=n_rays), new, lanes)
            else:  # fs samples, in draws of at most CHUNK_RAYS whose sums add up
                for j, vao in enumerate(self._chunk_draws(accum, ray, gbuffer, settings, 0, fs)):
                    if j:
                        ctx.enable(moderngl.BLEND)
                        ctx.blend_func = moderngl.ONE, moderngl.ONE
                    self.gpu.budget.fullscreen(vao, new)
                    ctx.disable(moderngl.BLEND)
            self.sample_base = base
            acc_prog, acc_vao = self.programs.fullscreen("soft_accumulate", {"ACCUMULATE": 1})
            new.texture.use(0)
            (new if src is None else src).texture.use(1)
            set_uniforms(acc_prog, {"u_new": 0, "u_acc": 1, "u_count": float(n)})
            draw_fullscreen(ctx, acc_vao, dst)
            n, cur = n + 1, 1 - cur
            since = None if since is None else since + 1
        self._accum[li] = (n, cur, key, since)
        mean = self._target((li, "mean"), *full)
        self._resolve(sums.texture, mean)
        got = min(traced(n), int(settings.samples))
        fewest = got if since is None else min(got, since * fs)  # (pixels that started over at the move)
        self.accumulated = fewest if self.accumulated is None else min(self.accumulated, fewest)
        return self._denoise(li, mean, gbuffer, denoise_radius(got), got)

    def _sums_targets(self, ray, key, gbuffer, settings, n: int, cur: int):
        """``(sums so far or None, target of this frame's sums, carried)`` of soft light ``li``.
        With :attr:`reuse` the sums live in its history: after a move the previous frame's sums
        are carried through the reprojection (pixels that do not stand start at 0). Without
        it, a ping-pong pair of this pass's targets (the same one twice where converged)."""
        full, li = gbuffer.size, ray.index
        rp = self.reuse
        if not self._reusing():
            src = self._target((li, "acc", cur), *full, components=2)
            dst = self._target((li, "acc", 1 - cur), *full, components=2)
            return (src if n else None), dst, False
        prev, now = rp.history(li, "soft", key, full)
        if prev is None or not n:
            return None, now[0], False
        if not self._moved:
            return prev[0], now[0], False
        carried = self._target((li, "carried"), *full, components=4)
        defs = {k: v for k, v in ray.defines.items() if k in CLASSIFY_DEFINES}
        rp.carry_sums(gbuffer, defs, self.trace.uniforms(ray, gbuffer, settings), light_pad(ray.light, ray.soft),
                      prev[0], carried)
        return carried, now[0], True

    def end_frame(self, job) -> None:
        self._moved = False

    def _reusing(self) -> bool:
        return self.reuse is not None and self.reuse.enabled

    def _range(self, key, tex, gbuffer, sums: bool = False, classify=None):
        """(min, max) of mask ``tex`` (``sums``: of the probe pass's sums) over the covered
        texels within 2 pixels of each (probe sums: HS_PROBE_RADIUS, 4; ``shaders/soft_range.glsl``:
        two 1D passes): an RG32F texture. ``classify`` = (target, probe sums, accumulating): the
        second pass writes the probe answers that stand into the target instead and marks the
        other pixels for :meth:`Refiner.draw_marked` (returns None)."""
        w, h = gbuffer.size
        src = tex
        for first, step in ((True, (1, 0)), (False, (0, 1))):
            defs = {}
            if first:
                defs = {"FIRST": 1, "SUMS": 1} if sums else {"FIRST": 1}
            elif classify is not None:
                defs = {"CLASSIFY": 1, "ACCUM": 1} if classify[2] else {"CLASSIFY": 1}
            prog, vao = self.programs.fullscreen("soft_range", defs)
            if first:
                gbuffer.bind(prog, 1)
            src.use(0)
            set_uniforms(prog, {"u_src": 0, "u_step": step})
            if not first and classify is not None:
                classify[1].use(1)
                set_uniforms(prog, {"u_probe": 1})
                gbuffer.bind(prog, 2)
                self.refiner.mark((key[0], "soft"), classify[0], vao)
                return None
            out = self._targets.get((key, "range", first), w, h, components=2)
            draw_fullscreen(self.ctx, vao, out)
            src = out.texture
        return src

    def _denoise(self, li, mask, gbuffer, radius: int, samples: int, scratch=None):
        """``mask`` filtered within its penumbrae over ``radius`` pixels (itself when 0), into
        light ``li``'s own target (``scratch``: the key of the ranges' targets)."""
        if radius <= 0:
            return mask.texture
        near = self._range((li if scratch is None else scratch, "mask"), mask.texture, gbuffer)
        prog, vao = self.programs.fullscreen("soft_accumulate", {"DENOISE": 1})
        gbuffer.bind(prog, 2)
        mask.texture.use(0)
        near.use(1)
        set_uniforms(prog, {"u_mask": 0, "u_mask_range": 1, "u_radius": int(radius), "u_plane_sigma": PLANE_SIGMA,
                            "u_samples": float(samples)})
        out = self._target((li, "denoised"), *gbuffer.size)
        draw_fullscreen(self.ctx, vao, out)
        return out.texture

    def _packet_defines(self, defines, rays: int) -> dict:
        """``HS_SOFT_PACKET`` (a pixel's soft-shadow rays walk the scene together,
        ``shaders/common/scene_packet.glsl``) for a pass that traces ``rays`` rays per pixel:
        structures that support them (:attr:`AccelerationStructure.supports_packets`; each ray keeps its
        own transmittance through alpha-cut casters), from
        PACKET_MIN_RAYS rays on (fewer are faster one by one on llvmpipe), unless
        :attr:`RaytraceOptions.packets` is off. With it ``HS_SOFT_FULL``: a refined
        pixel traces all its samples in one walk (cheaper than two halves with the ray-by-ray
        path's early stop between them, and exact)."""
        ok = (self.options.packets and not self._lanes() and rays >= PACKET_MIN_RAYS
              and self.gpu.scene_textures.baked.accel.supports_packets)
        return {"HS_SOFT_PACKET": 1, "HS_SOFT_FULL": 1} if ok else {}

    @staticmethod
    def _chunk(packet_defines: dict) -> int:
        """The most rays per pixel one refinement draw traces (CHUNK_RAYS)."""
        return CHUNK_RAYS["packets" if packet_defines else "rays"]

    def _soft_defines(self, defines, rays: int) -> dict:
        """A soft pass's own defines for ``rays`` rays per pixel: packets where they pay
        (:meth:`_packet_defines`, recorded in the stats), ``HS_LOOP_CHECK`` in tests and, with
        ``HS_LOOP_DROP``, where llvmpipe's loop budget can cut rays short
        (:attr:`RaytraceOptions.loop_guard`)."""
        d = self._packet_defines(defines, rays)
        self.defines_used.update({k: v for k, v in d.items() if k != "HS_SOFT_FULL"})
        guard = self.options.loop_guard
        if guard is None:
            guard = software_context(self.ctx)
        if self.options.loop_check:
            d["HS_LOOP_CHECK"] = 1
        elif guard:
            d["HS_LOOP_DROP"] = 1
        return d

    # -- the compute path: a texel's samples spread over lanes -------------------------------------
    def _lanes(self) -> bool:
        """Whether this frame's soft samples spread over lanes, ray by ray (the compute path;
        :attr:`RaytraceOptions.soft_lanes`, None: on a GPU), rather than walk as packets."""
        if not self.compute:
            return False
        lanes = self.options.soft_lanes
        return not software_context(self.ctx) if lanes is None else bool(lanes)

    def _sums_components(self) -> int:
        """Components of a sums target the trace writes (RG32F; the compute stage's sums image
        is RGBA32F)."""
        return 4 if self.compute else 2

    def _trace_all(self, defines, ray, gbuffer, settings, target, lanes: int = 1) -> None:
        """Trace every texel of ``target`` (full resolution) with ``defines``: a full-screen draw,
        or on the compute path the queue of the texels that need a ray (``lanes`` invocations
        each; ``HS_SUMS_ADD`` in ``defines``: added to the sums there)."""
        if not self.compute:
            _, vao, _ = self._program(defines, ray, gbuffer, settings)
            self.gpu.budget.fullscreen(vao, target)
            return
        defs = {**defines, **self._lane_define(lanes)}

        def bound(kernel):
            return self.trace.bind_compute(defs, ray, gbuffer, settings, 1, kernel, self.sample_base, self.split)[0]

        self.queue.trace(lambda: bound("gen"), lambda: bound("trace"), [target.texture], target.size,
                         lanes=lanes, read="HS_SUMS_ADD" in defines)

    def _add_marked(self, li, sums, accum_defines, ray, gbuffer, settings, first: int, total: int) -> None:
        """Add the sums of samples [first, total) of each pixel's sequence after ``sample_base``
        to ``sums`` where the last mark marked pixels: draws of at most CHUNK_RAYS each (their
        blend adds), or on the compute path the marked pixels queued, their samples over lanes."""
        if not self.compute:
            for vao in self._chunk_draws(accum_defines, ray, gbuffer, settings, first, total):
                self.refiner.draw_marked((li, "soft"), sums, vao, add=True)
            return
        for defs, n, lanes in self._spans(accum_defines, first, total):
            defs = {**defs, **self._lane_define(lanes), "HS_SUMS_ADD": 1}
            part = settings.replace(samples=n)

            def bound(defs=defs, part=part):
                return self.trace.bind_compute(defs, ray, gbuffer, part, 1, "trace", self.sample_base, self.split)[0]

            self.refiner.trace_marked((li, "soft"), sums, bound, kind=None, lanes=lanes, read=True)

    def _lane_define(self, lanes: int) -> dict:
        """``HS_QUEUE_LANES`` for ``lanes`` per queued texel (none for 1), recorded in the stats."""
        if lanes <= 1:
            return {}
        self.defines_used["HS_QUEUE_LANES"] = max(lanes, self.defines_used.get("HS_QUEUE_LANES", 0))
        return {"HS_QUEUE_LANES": lanes}

    def _spans(self, accum_defines, first: int, total: int):
        """``(defines, rays, lanes)`` of each draw or dispatch that traces samples [first, total)
        of each pixel's sequence after ``sample_base`` as sums, with ``sample_base`` moved to the
        span's first sample while the caller traces it (restored after the last): with
        :meth:`_lanes` each texel's rays over :func:`lanes_for` lanes, at most CHUNK_RAYS a lane
        per dispatch (llvmpipe's loop budget); else one invocation per texel, at most CHUNK_RAYS
        per draw."""
        if self._lanes():
            step, lanes = CHUNK_RAYS["rays"] * lanes_for(total - first), lanes_for
        else:
            step, lanes = self._chunk(self._packet_defines(accum_defines, total - first)), (lambda n: 1)
        base = self.sample_base
        try:
            for start, n in chunk_spans(base, first, total, step):
                self.sample_base = base + start
                yield {**accum_defines, **self._soft_defines(accum_defines, n)}, n, lanes(n)
        finally:
            self.sample_base = base

    def _chunk_draws(self, accum_defines, ray, gbuffer, settings, first: int, total: int):
        """The vaos of the draws that trace samples [first, total) of each pixel's sequence
        after ``sample_base`` as sums (``accum_defines`` hold ``HS_SOFT_ACCUM``), at most
        CHUNK_RAYS per draw: the caller adds their outputs up."""
        for defs, n, _ in self._spans(accum_defines, first, total):
            yield self._program(defs, ray, gbuffer, settings.replace(samples=n))[1]

    def release(self) -> None:
        self._targets.release()
