"""Shadow mode ``raytrace``: shadow rays (``shaders/raytrace.glsl``) through the baked scene
(:class:`~..scene_textures.SceneTextures`), full-resolution masks for every quality.

- ``high``: one ray per pixel and shadowed light.
- ``medium`` / ``low``: coarse rays every 2nd / 4th pixel, then refinement (:mod:`.refine`):
  pixels whose coarse neighbourhood agrees and stands for them take its answer, the others get
  their own ray, the very ray ``high`` traces, under the depth test (or from a compacted list,
  ``Refiner.method``). ``Settings.upsample ==
  'nearest'`` skips the refinement and leaves the coarse mask to the upsample pass (the thesis'
  blocky look, for comparisons).
- ``interlace`` (any quality; thesis 3.5.2): one pixel of every 2x2 block per frame, traced
  as a quarter-resolution mask (a full-resolution pass in which three pixels of four only copy
  their history would keep every 8-pixel SIMD group of a software rasteriser tracing) and merged
  with the history (``shaders/interlace_merge.glsl``); pixels whose history is not up to date
  since the last :meth:`reset_history` are
  refined from this frame's rays, so a change never leaves stale shadows behind, the first frame
  after it is nearly exact and a still view is exact after four frames.

The program is built from the bake's defines (grid levels, meshes and/or spheres present) plus
``HS_MAX_DISTANCE``, ``HS_INTERLACE`` and ``HS_COMPACT`` as needed, so a scene compiles only the
code it needs. With ``Settings.conservative`` set (``sun``: suns only, ``all``: every light) each
light first gets a conservative occupancy map (:mod:`.conservative`, ``HS_CONSERVATIVE``):
receivers nearer the light than every caster in their map column are lit without a ray, the
others trace only up to the first possible caster depth (exact: the masks do not change).

Lights with a size (``lights.soft_shape``, unless ``Settings.hard``) compile ``HS_SOFT``: at
``high`` a probe pass traces 1 ray per pixel, the second probe-range pass
(``shaders/soft_range.glsl`` CLASSIFY) writes the probe answer where every probe within 4
pixels saw all or none of the light and marks the other pixels in the depth buffer, the trace
then gives those alone (early depth test) the rest of their ``samples`` rays, and a
penumbra-only filter (``shaders/soft_accumulate.glsl``, narrowing as the samples add up)
follows; with ``Settings.accumulate`` (the viewport) each frame adds the sums of
``frame_samples`` rays per pixel to those of the frames before instead, until
``reset_history``. On the two-level BVH (alpha-cut casters too) a pixel's rays walk the scene as one
packet (``HS_SOFT_PACKET``, ``shaders/common/scene_packet.glsl``); a draw traces at most
``CHUNK_RAYS`` rays per pixel (more take several draws whose sums add up), since llvmpipe stops
every loop of an invocation after 65535 iterations in all. Ray by ray in several draws (the
grid), a refined pixel traces the second half of its rays only where the first left its share
strictly between 0 and 1 (``soft_accumulate.glsl`` PARTIAL marks them). With packets, a final
render checks each light's noise (``Settings.noise_target``): its sums keep those of the first
half of the samples apart (``u_split``), the masks of the two halves are filtered as masks of
half the samples and compared (NOISE), and a light estimated above the target gives its partial
pixels as many samples again.

A light that reaches no visible surface (a spot whose cone holds none, :mod:`.light_cull`)
takes no pass of rays, at every quality, interlaced and accumulating too (not ``upsample=
'nearest'``'s coarse masks); its mask, bit-identical, is the answers without rays
(``HS_NO_RAYS``), one for all such lights of the frame. It keeps no history: whether a light is
left out depends on the G-buffer alone, and every change of it resets the history.

``stats``: ``rays_traced`` counts the pixels the trace shaded (occlusion queries; facing-away
and map-decided pixels among them cost no traversal), ``pixels`` the pixels with geometry times
the shadowed lights, ``lights_culled`` the lights left out as above. The numpy mirror of the
rays traced here is ``core/oracle/rays.py``.
"""
from __future__ import annotations

import time
import zlib

import moderngl
import numpy as np

from ..lights import light_cone, light_ray_uniforms, soft_shape
from ..targets import TargetCache, draw_fullscreen, read_texture, set_uniforms
from .base import ShadowPass
from .conservative import ConservativeMaps
from .light_cull import LightCull, cull_candidate
from .light_grid import LightGrids
from .refine import Refiner


SOFT_PROBES = 1  # HS_PROBES of shaders/common/soft_probe.glsl
PACKET_MIN_RAYS = 8  # a soft pass traces its rays as packets from this many rays per pixel on
#: The most rays per pixel one draw traces, ray by ray or as one packet walk: llvmpipe stops every
#: loop of a shader invocation once all of them together have run 65535 iterations, which a
#: pixel's rays through a heavy scene reach (forest, 64 rays one by one: 1 in 7 penumbra pixels
#: of its sun), silently leaving rays untraced. More rays take more draws, whose sums add up.
CHUNK_RAYS = {"rays": 28, "packets": 64}
#: a final render's mask, filtered, is off from its exact share by about this times the mean
#: |a - b| of the masks of its two halves, each filtered alike (0.38-0.61 over the 18 soft masks of
#: forest, clusters, soft_lights and alpha_cards against 1024-sample masks; BENCHMARKS.md)
NOISE_PER_SPLIT = 0.45
PLANES_MIN_ASPECT = 1.5  # ellipse lights this elongated bound their packets by the pyramid too
PLANE_SIGMA = 0.02  # the penumbra filter's tangent-plane distance scale, relative to the view depth


def first_frame_lead(frame_samples: int) -> int:
    """Samples the viewport's first frame after a change traces beyond ``frame_samples`` in the
    penumbrae: it probes every pixel as a final render does and gives the pixels near a probe
    that saw part of the light four times the samples of a later frame (pixels elsewhere keep
    their probes' answer, and add the later frames' samples to it). At the default 4 that is 16:
    enough for a pixel's rays to walk the scene as one packet (at 8 they went one by one, and
    the frame cost more), and enough to bring `forest`'s dawn sun within 0.02 of Cycles on the
    first frame (BENCHMARKS.md "The viewport's first frame"). 0 where a frame traces no more
    samples than the probes."""
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


def pyramid_bounds(soft: dict) -> bool:
    """Whether a soft light's packets are bounded by the pyramid over its rectangle as well as
    by their cone (``HS_PACKET_PLANES``, ``shaders/common/scene_packet.glsl``): rectangles, and
    ellipses at least PLANES_MIN_ASPECT times as long as wide (a rounder ellipse's cone already
    lies almost inside the pyramid: four plane tests per node would buy nothing)."""
    if soft["shape"] == 2:
        return True
    if soft["shape"] != 3:
        return False
    lu, lv = (float(np.linalg.norm(soft[k])) for k in ("u_light_u", "u_light_v"))
    return max(lu, lv) >= PLANES_MIN_ASPECT * min(lu, lv)


def denoise_radius(samples: int) -> int:
    """Filter radius (pixels) of a soft mask with ``samples`` per pixel: 4 at 4 samples,
    shrinking as 1/sqrt(samples), 1 from 29 samples on (its range kernel narrows with the noise,
    so many samples are left almost as they are)."""
    return max(1, int(round(8.0 / np.sqrt(max(samples, 1)))))


class RaytracePass(ShadowPass):
    """Masks ``{light index: texture}`` at the G-buffer's resolution (the coarse masks, at
    ``settings.mask_size``, with ``upsample='nearest'``)."""

    light_label = "Ray tracing shadows"
    needs_bake = True

    def __init__(self, gpu):
        super().__init__(gpu)
        self.scene_textures = gpu.scene_textures
        self.maps = ConservativeMaps(gpu)
        self.light_grids = LightGrids(gpu)
        self._grid = None  # the light grid (textures, grid) bound by the programs of the current light
        self.last_map_ms = 0.0  # time spent building the maps in the last render (incl. finish)
        self._targets = TargetCache(self.ctx, fill=1.0, what="mask")  # (light, role) -> target
        self._phase = 0
        self._valid_phases = 0
        self.refiner = Refiner(gpu)
        self.cull = LightCull(gpu)
        self.cull_lights = True  # leave out the lights that reach no pixel (tests compare without)
        self.culled: list = []  # the lights of the last frame that reached no pixel (no pass of rays)
        self._plan = self._last_plan = None
        self.last_defines: dict = {}
        self.last_samples = 1  # rays per pixel of the softest light of the last frame
        self.sample_base = 0  # first sample index of this frame (accumulation advances it)
        self.split = 0  # the samples before this index also sum apart (raytrace.glsl u_split)
        self.last_noise = {}  # light name -> the last final render's noise estimate
        self._accum: dict = {}  # light -> (frames accumulated, current target index, settings key)
        self.accumulated = None  # fewest samples per pixel of the soft lights' accumulated masks
        self._scene_frame = 1  # the animation frame being rendered (seeds the sample patterns)
        self.packets = True  # soft lights: a pixel's rays walk the scene together (else ray by ray)
        self.early_stop = True  # ray by ray: a penumbra's fringe pixel may stop after half its samples
        self.loop_check = False  # tests: refined pixels whose loops hit llvmpipe's budget read HS_LOOP_SPENT

    def reset_history(self) -> None:
        """Forget interlacing and accumulation history (any camera, object, light or setting
        change)."""
        self._valid_phases = 0
        self._accum.clear()

    def defines(self, settings, local: bool, soft: dict | None = None) -> dict:
        d = dict(self.scene_textures.baked.defines)
        d.update(self.scene_textures.defines)
        d["HS_LIGHT_LOCAL" if local else "HS_LIGHT_SUN"] = 1
        if soft is not None:
            d["HS_SOFT"] = 1
            d["HS_SOFT_SHAPE"] = int(soft["shape"])
            if pyramid_bounds(soft):
                d["HS_PACKET_PLANES"] = 1
        if settings.max_distance > 0:
            d["HS_MAX_DISTANCE"] = 1
        if settings.interlace:
            d["HS_INTERLACE"] = 1
        return d

    def _target(self, key, w, h, components: int | None = None):
        t = self._targets.get(key, w, h, components)
        if self._targets.created:
            self._valid_phases = 0
        return t

    def stats(self, job) -> dict:
        mw, mh = job.settings.mask_size(*job.size)
        n = len(job.lights)
        valid = self.refiner.count("valid") if n else 0
        if self._plan == "full":
            traced = valid * (n - len(self.culled))
        else:
            traced = self.refiner.count("coarse") * (n - len(self.culled)) + self.refiner.count("refined")
        return {"mask_resolution": [mw, mh], "rays": int(mw * mh * n),
                "rays_traced": int(traced), "pixels": int(valid * n), "samples": int(self.last_samples),
                "accumulated_samples": self.accumulated, "lights_culled": len(self.culled),
                "noise": {k: round(v, 6) for k, v in self.last_noise.items()},
                "defines": sorted(f"{k}={v}" for k, v in self.last_defines.items())}

    def _plan_of(self, settings) -> str:
        """``full`` (one ray per pixel), ``refine`` (coarse rays, then refinement), ``interlace``
        (this frame's phase, refinement where history is missing) or ``coarse`` (the coarse mask
        alone, upscaled by the upsample pass: ``upsample='nearest'``, the thesis' look)."""
        if settings.interlace:
            return "interlace"
        if settings.mask_scale == 1:
            return "full"
        return "coarse" if settings.upsample == "nearest" else "refine"

    def render(self, job) -> dict:
        ctx = self.ctx
        scene, gbuffer, settings, lights = job.scene, job.gbuffer, job.settings, job.lights
        full = gbuffer.size
        scale = settings.mask_scale
        cw, ch = settings.mask_size(*full)
        plan = self._plan = self._plan_of(settings)
        if plan != self._last_plan:
            self._valid_phases = 0
            self._last_plan = plan
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.last_defines = {}
        self.last_map_ms = 0.0
        self.refiner.begin_frame()
        self.light_grids.begin_frame()
        grids = LightGrids.usable(self.scene_textures.baked, settings)
        masks = {}
        if lights:  # pixels with geometry (full resolution, and the coarse samples' pixels)
            self.refiner.count_valid(gbuffer, full, 1, "valid")
            if plan in ("refine", "coarse"):
                self.refiner.count_valid(gbuffer, (cw, ch), scale, "coarse")
            if plan == "refine":
                self.refiner.prepare(gbuffer, scale, (scale // 2, scale // 2), False)
            elif plan == "interlace":  # (this frame's phase: one pixel of each 2x2 block)
                off = (self._phase & 1, self._phase >> 1)
                grid = (max(1, -(-(full[0] - off[0]) // 2)), max(1, -(-(full[1] - off[1]) // 2)))
                self.refiner.count_valid(gbuffer, grid, 2, "coarse", off)
                # (a still view classifies nothing: _light merges the history alone)
                self.refiner.prepare(gbuffer, 2, off, True, geometry=not self._still())
        sun_maps = settings.conservative in ("sun", "all")
        local_maps = settings.conservative == "all"
        if sun_maps and lights and (local_maps or any(
                not light_ray_uniforms(scene.lights[li])[0] for li in lights)):
            t0 = time.perf_counter()
            self.maps.begin_frame(scene, gbuffer)
            self.last_map_ms += (time.perf_counter() - t0) * 1e3
        origin = self.scene_textures.baked.origin
        # lights that reach no pixel get the answers without rays (one shared mask), no trace
        self.culled = []
        cull = self.cull_lights and plan != "coarse" and any(
            cull_candidate(scene.lights[li], settings.hard) for li in lights)
        if cull:
            self.cull.prepare(gbuffer, settings, gbuffer.camera.cam_pos - origin)
        no_rays = None
        self.last_samples = 1
        self.accumulated = None
        self.last_noise = {}
        self._scene_frame = int(getattr(scene, "frame", 1))
        for li in lights:
            job.light_started(li)
            local, vec = light_ray_uniforms(scene.lights[li], origin)
            if cull and not self.cull.reaches(scene.lights[li], vec if local else None, settings.hard):
                if no_rays is None:
                    no_rays = self._no_rays(scene.lights[li], vec, local, gbuffer, settings)
                masks[li] = no_rays
                self.culled.append(li)
                continue
            soft = soft_shape(scene.lights[li], settings.hard)
            if soft is not None:
                self.last_samples = max(self.last_samples, int(settings.samples))
            defines = self.defines(settings, local, soft)
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
            self._grid = None
            if grids and soft is None:
                self._grid = self.light_grids.get(scene, scene.lights[li], local, vec)
                if self._grid is not None:
                    defines.update(self._grid[1].defines)
            self.last_defines.update(defines)
            timed = grids and soft is None and self._grid is None and not self.light_grids.eager
            if timed:  # (the light's BVH time: what a grid would have to pay back)
                ctx.finish()
                t0 = time.perf_counter()
            try:
                masks[li] = self._light(li, scene.lights[li], vec, defines, gbuffer, settings, plan, cmap)
            finally:
                self._grid = None
            if timed:
                ctx.finish()
                self.light_grids.note_bvh(local, vec, (time.perf_counter() - t0) * 1e3)
        self.light_grids.end_frame()
        if plan == "interlace":
            self._valid_phases |= 1 << self._phase
            self._phase = (self._phase + 1) % 4
        if not settings.max_distance > 0:  # (beyond it the no-rays mask is 1: the light may shine there)
            job.dark = set(self.culled)
        return masks

    def _still(self) -> bool:
        """Interlacing: every other phase's history is up to date (a still view)."""
        return self._valid_phases | (1 << self._phase) == 15

    def _no_rays(self, light, light_vec, local, gbuffer, settings):
        """The mask of a light that no pixel needs a ray of: 1 on the background and beyond the
        max distance, 0 elsewhere (facing away, out of reach), as the trace writes it; one for
        all such lights of a frame (it depends on the G-buffer alone)."""
        defines = {**self.defines(settings.replace(interlace=False), local), "HS_NO_RAYS": 1}
        _, vao, _ = self._program(defines, light, light_vec, gbuffer, settings.replace(hard=True), 1, None)
        out = self._targets.get(("no rays",), *gbuffer.size)  # (a scratch target: no history)
        draw_fullscreen(self.ctx, vao, out)
        return out.texture

    def _program(self, defines, light, light_vec, gbuffer, settings, scale, cmap):
        """The trace program of ``defines``, bound to this frame's inputs; ``(prog, vao, unit)``."""
        prog, vao = self.programs.fullscreen("raytrace", defines)
        unit = gbuffer.bind(prog)
        unit = self.scene_textures.bind(prog, unit)
        if "HS_LIGHT_GRID" in defines:
            unit = self.light_grids.bind(prog, unit, self._grid)
        if cmap is not None:
            unit = self._bind_map(prog, unit, *cmap, self.scene_textures.baked.origin)
        set_uniforms(prog, {"u_scale": int(scale), "u_full_size": (gbuffer.width, gbuffer.height)})
        set_uniforms(prog, self._light_uniforms(light, light_vec, gbuffer, settings))
        return prog, vao, unit

    def _packet_defines(self, defines, rays: int) -> dict:
        """``HS_SOFT_PACKET`` (a pixel's soft-shadow rays walk the scene together,
        ``shaders/common/scene_packet.glsl``) for a pass that traces ``rays`` rays per pixel:
        two-level BVH (each ray keeps its own transmittance through alpha-cut casters), from
        PACKET_MIN_RAYS rays on (fewer are faster one by one on llvmpipe), unless
        :attr:`packets` is off. With it ``HS_SOFT_FULL``: a refined
        pixel traces all its samples in one walk (cheaper than two halves with the ray-by-ray
        path's early stop between them, and exact)."""
        ok = self.packets and rays >= PACKET_MIN_RAYS and "HS_STRUCTURE_BVH" in defines
        return {"HS_SOFT_PACKET": 1, "HS_SOFT_FULL": 1} if ok else {}

    @staticmethod
    def _chunk(packet_defines: dict) -> int:
        """The most rays per pixel one refinement draw traces (CHUNK_RAYS)."""
        return CHUNK_RAYS["packets" if packet_defines else "rays"]

    def _soft_defines(self, defines, rays: int) -> dict:
        """A soft pass's own defines for ``rays`` rays per pixel: packets where they pay
        (:meth:`_packet_defines`, recorded in the stats) and, in tests, ``HS_LOOP_CHECK``."""
        d = self._packet_defines(defines, rays)
        self.last_defines.update(d)
        self.last_defines.pop("HS_SOFT_FULL", None)
        if self.loop_check:
            d["HS_LOOP_CHECK"] = 1
        return d

    def _chunk_draws(self, accum_defines, light, light_vec, gbuffer, settings, cmap, first: int, total: int):
        """The vaos of the draws that trace samples [first, total) of each pixel's sequence
        after ``sample_base`` as sums (``accum_defines`` hold ``HS_SOFT_ACCUM``), at most
        CHUNK_RAYS per draw: the caller adds their outputs up."""
        base = self.sample_base
        step = self._chunk(self._packet_defines(accum_defines, total - first))
        try:
            for start, n in chunk_spans(base, first, total, step):
                self.sample_base = base + start
                defs = {**accum_defines, **self._soft_defines(accum_defines, n)}
                yield self._program(defs, light, light_vec, gbuffer, settings.replace(samples=n), 1, cmap)[1]
        finally:
            self.sample_base = base

    def _light_uniforms(self, light, light_vec, gbuffer, settings) -> dict:
        axis, cone = light_cone(light)
        u = {"u_light_vec": light_vec, "u_light_axis": axis, "u_light_cone": cone,
             "u_cam_bake": tuple(float(v) for v in gbuffer.camera.cam_pos - self.scene_textures.baked.origin),
             "u_max_distance": float(settings.max_distance)}
        soft = soft_shape(light, settings.hard)
        if soft is not None:
            u.update({k: v for k, v in soft.items() if k != "shape"})
            u.update({"u_samples": int(settings.samples), "u_sample_base": int(self.sample_base),
                      "u_split": int(self.split),
                      "u_seed": self._seed(light, self._scene_frame)})
        return u

    @staticmethod
    def _seed(light, frame: int = 1) -> int:
        """The seed of a light's sample pattern in a frame of the animation: the same in every
        session, another one in each frame (each pixel's rotation of the sequence changes)."""
        return (zlib.crc32(light.name.encode("utf-8")) ^ ((int(frame) * 0x9E3779B1) & 0xFFFFFFFF)) & 0x7FFFFFFF

    def _light(self, li, light, light_vec, defines, gbuffer, settings, plan, cmap=None):
        full = gbuffer.size
        ctx = self.ctx
        if plan == "full" and "HS_SOFT" in defines and settings.accumulate:
            return self._accumulate(li, light, light_vec, defines, gbuffer, settings, cmap)
        if plan in ("full", "coarse"):
            scale = 1 if plan == "full" else settings.mask_scale
            size = full if plan == "full" else settings.mask_size(*full)
            out = self._target((li, "out" if plan == "full" else "coarse"), *size)
            probed = plan == "full" and "HS_SOFT" in defines and settings.samples > SOFT_PROBES
            if probed:
                got = self._probe_and_refine(li, light, light_vec, defines, gbuffer, settings, cmap, out)
                self.last_samples = max(self.last_samples, got)
                return self._denoise(li, out, gbuffer, denoise_radius(got), got)
            _, vao, _ = self._program(defines, light, light_vec, gbuffer, settings, scale, cmap)
            draw_fullscreen(ctx, vao, out)
            return out.texture
        plain = {k: v for k, v in defines.items() if k != "HS_INTERLACE"}
        uniforms = self._light_uniforms(light, light_vec, gbuffer, settings)
        class_defs = {k: v for k, v in defines.items() if k in ("HS_LIGHT_LOCAL", "HS_LIGHT_SUN", "HS_MAX_DISTANCE",
                                                                  "HS_INTERLACE", "HS_SOFT", "HS_SOFT_SHAPE")}
        class_defs.update(self.refiner.defines())
        if plan == "refine":
            scale = settings.mask_scale
            _, vao, _ = self._program(plain, light, light_vec, gbuffer, settings, scale, cmap)
            coarse = self._target((li, "coarse"), *settings.mask_size(*full))
            draw_fullscreen(ctx, vao, coarse)
            dst = self._target((li, "out"), *full)
            self.refiner.classify((li, "out"), dst, gbuffer, coarse.texture, class_defs, uniforms)
        else:  # interlace: this frame's phase pixel of each 2x2 block traced densely, with the history
            off = (self._phase & 1, self._phase >> 1)
            prog, vao, _ = self._program(defines, light, light_vec, gbuffer, settings, 2, cmap)
            set_uniforms(prog, {"u_offset": off})
            # (one size for every phase: an odd side's last texel then traces the edge pixel
            # again; a scratch target, not _target's: it carries nothing from frame to frame)
            traced = self._targets.get((li, "traced"), (full[0] + 1) // 2, (full[1] + 1) // 2)
            draw_fullscreen(ctx, vao, traced)
            out = self._target((li, "out"), *full)
            hist = self._target((li, "hist"), *full)
            mprog, mvao = self.programs.fullscreen("interlace_merge")
            traced.texture.use(0)
            hist.texture.use(1)
            set_uniforms(mprog, {"u_traced": 0, "u_history": 1, "u_phase": self._phase,
                                 "u_valid_phases": self._valid_phases})
            draw_fullscreen(ctx, mvao, out)
            dst = hist
            if self._still():
                # a still view: every pixel has this frame's ray or an up-to-date history, so
                # nothing to classify or refine (what classify would write is the merge itself)
                ctx.copy_framebuffer(hist.fbo, out.fbo)
                return hist.texture
            self.refiner.classify((li, "hist"), dst, gbuffer, out.texture, class_defs, uniforms)
        key = (li, "hist" if plan == "interlace" else "out")
        if self.refiner.method == "compact":
            def trace():  # (bound once the list is built: the reduction draws use the texture units too)
                return self._program({**plain, "HS_COMPACT": 1}, light, light_vec, gbuffer, settings, 1, cmap)
            self.refiner.refine_compact(key, dst, trace, gbuffer)
        else:
            _, vao, _ = self._program(plain, light, light_vec, gbuffer, settings, 1, cmap)
            self.refiner.refine(key, dst, vao)
        return dst.texture

    def _probe_and_refine(self, li, light, light_vec, defines, gbuffer, settings, cmap, out) -> None:
        """A soft light's ``settings.samples`` rays per pixel into ``out``: a few probe rays per
        pixel, then the rest only near the pixels whose probes disagree (penumbrae); elsewhere
        the probes are exact. ``defines`` with ``HS_SOFT_ACCUM``: ``out`` gets the sums (RG)."""
        ctx = self.ctx
        full = gbuffer.size
        accum = "HS_SOFT_ACCUM" in defines
        total = int(settings.samples)
        rays = total - SOFT_PROBES
        packet = self._packet_defines(defines, rays)
        # a final render's noise check (packets): the sums keep their first half's apart; a light
        # whose masks of the two halves, each filtered, differ by more than the target allows
        # gives its partial pixels as many samples again
        check = bool(packet) and not accum and float(settings.noise_target) > 0.0 and total >= 2 * SOFT_PROBES
        chunked = rays > self._chunk(packet) or check
        # ray by ray in several draws (the grid): the early stop between draws, the second half
        # only where the first left the share partial
        half = SOFT_PROBES + rays // 2 if chunked and not (accum or packet) and self.early_stop else total
        stages = [(SOFT_PROBES, half), (half, total)] if half < total else [(SOFT_PROBES, total)]
        probe_defs = {k: v for k, v in defines.items() if k != "HS_SOFT_ACCUM"}  # (the same probes either way)
        _, pvao, _ = self._program({**probe_defs, "HS_SOFT_PROBE": 1}, light, light_vec, gbuffer, settings, 1, cmap)
        probe = self._target((li, "probe"), *full, components=2)  # (sums: raytrace.glsl)
        draw_fullscreen(ctx, pvao, probe)
        # the probe ranges' second pass writes the probe answers where they stand and marks the
        # rest in the depth buffer: only those are shaded by the refinement
        sums = out
        if chunked and not accum:  # (the refinement adds up sums, divided at the end)
            sums = self._target((li, "sums4" if check else "sums"), *full, components=4 if check else 2)
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
                    for vao in self._chunk_draws(accum_defs, light, light_vec, gbuffer, settings, cmap, first, last):
                        self.refiner.draw_marked((li, "soft"), sums, vao, add=True)
            finally:
                self.split = 0
            if check:
                self.last_noise[light.name] = noise = self._noise(li, sums, gbuffer, total // 2)
                if noise > float(settings.noise_target):
                    self._mark_partial(li, sums)
                    for vao in self._chunk_draws(accum_defs, light, light_vec, gbuffer, settings, cmap,
                                                 total, 2 * total):
                        self.refiner.draw_marked((li, "soft"), sums, vao, add=True)
                    got = 2 * total
            if not accum:
                self._resolve(sums.texture, out)
            return got
        refine_defs = {**defines, "HS_SOFT_REFINE": 1, **self._soft_defines(defines, rays)}
        if not self.early_stop:
            refine_defs["HS_SOFT_FULL"] = 1
        prog, vao, unit = self._program(refine_defs, light, light_vec, gbuffer, settings, 1, cmap)
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

    def _accumulate(self, li, light, light_vec, defines, gbuffer, settings, cmap):
        """One more frame of a soft light's running sums (``Settings.accumulate``): trace
        ``frame_samples`` rays per pixel continuing each pixel's sequence, add their (weighted
        visibility, weight) sums to those of the frames before, and filter the mask they make
        within its penumbrae (the fewer its samples, the wider). The first frame after a change
        probes every pixel and gives the penumbrae ``frame_samples`` + :func:`first_frame_lead`
        samples. Converged (``samples`` reached): no rays, the mask filtered as a final
        render's is."""
        ctx = self.ctx
        full = gbuffer.size
        fs = int(settings.frame_samples)
        lead = first_frame_lead(fs)

        def traced(frames: int) -> int:  # samples per penumbra pixel after that many frames
            return lead + frames * fs if frames else 0

        key = (fs, int(settings.samples))
        n, cur, k = self._accum.get(li, (0, 0, key))
        if k != key:
            n, cur = 0, 0
        done = traced(n)
        if done < settings.samples:
            base = self.sample_base
            self.sample_base = done
            accum = {**defines, "HS_SOFT_ACCUM": 1}
            new = self._target((li, "new"), *full, components=2)
            if n == 0 and lead:  # probes everywhere, fs + lead samples in the penumbrae (at most samples)
                first = settings.replace(samples=min(fs + lead, int(settings.samples)))
                self._probe_and_refine(li, light, light_vec, accum, gbuffer, first,
                                       cmap, new)
            else:  # fs samples, in draws of at most CHUNK_RAYS whose sums add up
                for j, vao in enumerate(self._chunk_draws(accum, light, light_vec, gbuffer, settings, cmap, 0, fs)):
                    if j:
                        ctx.enable(moderngl.BLEND)
                        ctx.blend_func = moderngl.ONE, moderngl.ONE
                    draw_fullscreen(ctx, vao, new)
                    ctx.disable(moderngl.BLEND)
            self.sample_base = base
            acc_prog, acc_vao = self.programs.fullscreen("soft_accumulate", {"ACCUMULATE": 1})
            src = self._target((li, "acc", cur), *full, components=2)
            dst = self._target((li, "acc", 1 - cur), *full, components=2)
            new.texture.use(0)
            src.texture.use(1)
            set_uniforms(acc_prog, {"u_new": 0, "u_acc": 1, "u_count": float(n)})
            draw_fullscreen(ctx, acc_vao, dst)
            n, cur = n + 1, 1 - cur
            self._accum[li] = (n, cur, key)
        mean = self._target((li, "mean"), *full)
        self._resolve(self._target((li, "acc", cur), *full, components=2).texture, mean)
        got = min(traced(n), int(settings.samples))
        self.accumulated = got if self.accumulated is None else min(self.accumulated, got)
        return self._denoise(li, mean, gbuffer, denoise_radius(got), got)

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

    def _denoise(self, li, mask, gbuffer, radius: int, samples: int):
        """``mask`` filtered within its penumbrae over ``radius`` pixels (itself when 0)."""
        if radius <= 0:
            return mask.texture
        near = self._range((li, "mask"), mask.texture, gbuffer)
        prog, vao = self.programs.fullscreen("soft_accumulate", {"DENOISE": 1})
        gbuffer.bind(prog, 2)
        mask.texture.use(0)
        near.use(1)
        set_uniforms(prog, {"u_mask": 0, "u_mask_range": 1, "u_radius": int(radius), "u_plane_sigma": PLANE_SIGMA,
                            "u_samples": float(samples)})
        out = self._target((li, "denoised"), *gbuffer.size)
        draw_fullscreen(self.ctx, vao, out)
        return out.texture

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

    def release(self) -> None:
        self.light_grids.close()
        self.cull.release()
        self.refiner.release()
        self.maps.release()
        self._targets.release()
