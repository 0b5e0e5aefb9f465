"""The deferred pipeline: bake -> G-buffer -> shadow masks -> (upsample) -> lighting.

The one GPU entry point of the CLI, the tools, the benchmarks and the engine. One
:class:`Pipeline` per OpenGL context, reused across frames: programs, model buffers and the
baked scene textures stay on the GPU. ``set_scene`` bakes (or re-bakes), ``move_instances`` and
``update_model`` apply incremental updates, ``render`` runs the passes for one
:class:`~..settings.Settings` and returns a :class:`Frame` with the image, the masks and the
timings: with :attr:`Pipeline.timing` ``"passes"`` (the default) each pass is timed up to a
``ctx.finish()`` and the GPU's counts are read; with ``"frame"`` (the viewport's) the passes run
without a wait between them, the frame's one wait is its image read, ``total_ms`` is the time up
to it, and what only the GPU counted is not read back.

:meth:`Pipeline.view` makes another pipeline over the same context, programs, model buffers and
bake (one per viewport): its passes, render targets and history (interlacing, soft-shadow
accumulation) are its own; a bake change made through any of them resets every one's history.
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import moderngl
import numpy as np

from ..bake import BakeConfig, bake_scene
from ..errors import SceneError
from ..progress import Progress
from ..settings import Settings
from . import memory
from .context import check_light_count, check_render_size, create_context, make_current, software_context
from .frame import CameraUniforms, FrameJob, read_mask
from .host_counts import counts_of
from .lights import select_shadowed_lights
from .passes import GBufferPass, LightingPass, NoShadowPass, RaytracePass, ShadowMapPass, UpsamplePass
from .passes.reproject import instance_boxes, merged_boxes
from .resources import GpuResources
from .see_through import SeeThroughAccumulation, SeeThroughScene, split_progress, sub_frame_settings, target_samples
from .targets import read_texture

#: how a frame is timed (``Pipeline.timing``): every pass apart, or the frame as a whole
TIMINGS = ("passes", "frame")
#: ``Settings.mode`` -> the shadow pass that makes its masks
SHADOW_PASSES = {"raytrace": RaytracePass, "shadowmap": ShadowMapPass, "none": NoShadowPass}


def mask_inputs(scene) -> bytes:
    """A digest of what the masks read from ``scene`` apart from the bake and the lights: each
    instance's light and shadow linking sets, casting flag, material and terminator offset."""
    inst = scene.instances
    h = hashlib.blake2b(digest_size=16)
    for name in ("light_sets", "shadow_sets", "casts_shadow", "material_ids", "terminator"):
        a = getattr(inst, name, None)
        if a is not None:
            h.update(np.ascontiguousarray(a).tobytes())
    return h.digest()


class FrameCount:
    """How many frames a pipeline has begun (or targets it has given back): a frame whose masks
    live in the pipeline's targets reads them only while this is what it was when it was made."""

    __slots__ = ("value",)

    def __init__(self):
        self.value = 0


@dataclass
class Frame:
    """One rendered frame. ``image``: float32 (H, W, 4) linear RGBA, row 0 = top. Its masks and
    G-buffer live in the pipeline's targets until the pipeline's next frame draws over them:
    :meth:`mask_array` reads them until then, and after it raises (a see-through average's
    masks are host copies, read any time)."""

    image: np.ndarray
    masks: dict  # light index -> moderngl texture at full resolution (valid until the next render)
    lights: list  # indices of the shadowed lights, in mask order
    timings: dict = field(default_factory=dict)  # ms per pass
    stats: dict = field(default_factory=dict)
    gbuffer: object = None
    mask_arrays: dict = None  # light index -> float32 mask (a see-through average), else read
    _coverage: np.ndarray = field(default=None, repr=False)
    _count: FrameCount = field(default=None, repr=False)  # the pipeline's, and its value at this frame
    _made: int = field(default=0, repr=False)

    def mask_array(self, light_index: int) -> np.ndarray:
        """float32 (H, W), row 0 = top, 1 lit / 0 shadowed, NaN where there is no geometry."""
        if self.mask_arrays is not None:
            return self.mask_arrays[light_index].copy()
        if self._count is not None and self._count.value != self._made:
            raise RuntimeError("this frame's masks were drawn over by a later frame of the same pipeline "
                               "(or its targets given back): read them before rendering again")
        if self._coverage is None:  # one G-buffer read for all the frame's masks
            self._coverage = self.gbuffer.coverage()
        return read_mask(self.masks[light_index], self.gbuffer, self._coverage)


class _Steps:
    """Counts the steps of one frame for a ``progress(done, total, label)`` callback; within a
    step, :meth:`tile` and :meth:`within` move ``done`` on by a share of the step (a float)."""

    def __init__(self, progress: Progress | None, total: int):
        self.progress = progress
        self.total = total
        self.done = 0
        self.label = ""
        self.tiles = 0  # tiles drawn in the current step

    def __call__(self, label: str) -> None:
        if self.progress is not None:
            self.progress(self.done, self.total, label)
        self.done += 1
        self.label = label
        self.tiles = 0

    def tile(self) -> None:
        """After each tile of a tiled draw: the step's share grows with its tiles (tiles / (tiles
        + 8): their number is not known ahead) and never reaches the next step."""
        self.tiles += 1
        self._report(self.tiles / (self.tiles + 8), f"{self.label} (tile {self.tiles})")

    def within(self, done: float, total: float, label: str) -> None:
        """A stage's own ``progress(done, total, label)`` inside the current step (a bake, a
        light grid's build) as a share of that step."""
        share = 0.99 * min(max(done / max(total, 1e-9), 0.0), 1.0)
        self._report(share, f"{self.label}: {label}" if self.label else label)

    def _report(self, share: float, label: str) -> None:
        if self.progress is not None:
            self.progress(max(self.done - 1, 0) + share, self.total, label)


class _SharedBake:
    """The bake of the pipelines of one context (:meth:`Pipeline.view`); ``generation`` counts
    its changes, so each pipeline knows when its history became stale."""

    def __init__(self):
        self.baked = None
        self.bake_ms = 0.0
        self.options: dict = {}  # structure -> options of its own config (e.g. {"bvh": {"wide": False}})
        self.generation = 0
        self.edits: list = []  # (generation, bake-space boxes it invalidates; None: everything)
        self.boxes = None  # (n, 2, 3) world boxes of the baked instances

    def changed(self, boxes=None) -> None:
        """A change of the bake: ``boxes`` (world) are what it can touch, None: anything."""
        self.generation += 1
        if boxes is not None and self.baked is not None:
            boxes = boxes - np.asarray(self.baked.origin, np.float64)
        self.edits.append((self.generation, boxes))
        del self.edits[:-64]

    def since(self, generation: int):
        """The bake-space boxes changed after ``generation``, None where anything may have."""
        edits = [b for g, b in self.edits if g > generation]
        if len(edits) != self.generation - generation or any(b is None for b in edits):
            return None
        return np.concatenate(edits) if edits else np.zeros((0, 2, 3))


class Pipeline:
    def __init__(self, ctx=None, *, share: Pipeline | None = None):
        if share is None:
            self.ctx = create_context(ctx)
            make_current(self.ctx)  # (a handed-in context may not be the thread's current one)
            self.gpu = GpuResources(self.ctx)
            self._bake = _SharedBake()
        else:  # a view: the context, resources and bake of ``share``; own passes and history
            self.ctx, self.gpu, self._bake = share.ctx, share.gpu, share._bake
        self._owns_gpu = share is None
        self._generation = self._bake.generation
        self._camera = None  # the last frame's camera (its CameraUniforms' values)
        self._inputs = None  # mask_inputs() of the last frame's scene
        # reuse visibility across camera moves and edits (else forget), light by light where it
        # pays (reuse_choice "auto": passes/reproject.py ReuseChoice) or always ("always")
        self.reuse = False
        self.reuse_choice = "auto"
        self._retrace = False  # retrace_once(): the next frame ignores the hard lights' history
        self.timing = "passes"  # one of TIMINGS
        self.programs = self.gpu.programs
        self.scene_textures = self.gpu.scene_textures
        self._make_passes()
        self.see_through = SeeThroughScene()
        self.gbuffer_renders = 0  # G-buffer passes rendered (a see-through frame renders several)
        self.frames_begun = FrameCount()  # (a Frame reads its masks while it is the last one)

    def _make_passes(self) -> None:
        """New passes (their targets and history made on first use)."""
        self.gbuffer_pass = GBufferPass(self.gpu)
        self.upsample = UpsamplePass(self.gpu)
        self.lighting = LightingPass(self.gpu)
        self._shadow: dict = {}  # mode -> shadow pass, created on first use
        self._st = SeeThroughAccumulation(self.ctx)  # the viewport's running see-through average

    def view(self) -> Pipeline:
        """Another pipeline sharing this one's context, programs, model buffers and bake, with
        its own passes (targets, history). Release it before this one."""
        return Pipeline(share=self)

    @property
    def baked(self):
        """The baked scene (shared with this pipeline's views), None before the first bake."""
        return self._bake.baked

    @baked.setter
    def baked(self, value) -> None:
        self._bake.baked = value

    @property
    def bake_options(self) -> dict:
        """Options of each structure's own config (:meth:`BakeConfig.of`) the bakes take, by
        structure (shared with the views; benchmarks and tests compare layouts with them, e.g.
        ``{"bvh": {"wide": True}}``: the bake otherwise chooses ``wide`` by the context, 4-wide
        nodes on a GPU only)."""
        return self._bake.options

    @property
    def bake_ms(self) -> float:
        return self._bake.bake_ms

    def shadow_pass(self, mode: str):
        """The shadow pass of ``mode`` (one of :data:`SHADOW_PASSES`)."""
        p = self._shadow.get(mode)
        if p is None:
            p = self._shadow[mode] = SHADOW_PASSES[mode](self.gpu)
        return p

    def _passes(self) -> list:
        return [self.gbuffer_pass, *self._shadow.values(), self.upsample, self.lighting]

    # -- scene ------------------------------------------------------------------------------------
    def set_scene(self, scene, structure: str | None = None, progress: Progress | None = None) -> float:
        """Bake ``scene`` with acceleration ``structure`` (``Settings.structure``; None: the
        default) and upload its textures; returns the bake time in ms. A render whose settings ask
        for another structure bakes again. ``progress`` is called through the bake; what it
        raises stops the bake and leaves the bake before it in place."""
        make_current(self.ctx)
        t0 = time.perf_counter()
        if structure is None:
            structure = Settings.structure
        # single rays walk 4-wide nodes on a GPU (a third of the dependent fetches), binary nodes
        # on a software rasteriser, whose private arrays (the wide walk's stack) cost more than
        # the fetches they save
        options = {"wide": not software_context(self.ctx)} if structure == "bvh" else {}
        options.update(self._bake.options.get(structure, {}))
        baked = bake_scene(scene, BakeConfig.of(structure, **options), progress=progress)
        self.baked = baked
        try:
            self.scene_textures.upload(baked)
        except BaseException:
            self.baked = None  # (textures half uploaded: the next render bakes again)
            raise
        finally:
            self._bake.boxes = instance_boxes(scene)
            self._bake_changed()
        self._bake.bake_ms = (time.perf_counter() - t0) * 1e3
        return self.bake_ms

    def move_instances(self, scene, indices, progress: Progress | None = None) -> None:
        """Instances ``indices`` moved (their matrices in ``scene`` already changed). Stopped
        by ``progress`` (whatever it raises), the bake is dropped: the next render bakes anew."""
        make_current(self.ctx)
        idx = np.asarray(indices, np.int64).reshape(-1)
        self._update(self.baked.update_instances, scene, indices, progress, idx)

    def update_model(self, scene, model_id: int, progress: Progress | None = None) -> None:
        """Model ``model_id`` was edited or added (``progress``: as :meth:`move_instances`)."""
        make_current(self.ctx)
        idx = np.flatnonzero(scene.instances.model_ids == int(model_id))
        self._update(self.baked.update_model, scene, model_id, progress, idx)

    def _update(self, update, scene, arg, progress, idx) -> None:
        """An incremental update of instances ``idx`` applied to the bake and its textures; a
        half-made one (an error, a cancel) drops the bake. Their old and new boxes are what it
        can touch (everything where the instances are not those of the last bake)."""
        try:
            report = update(scene, arg, progress=progress)
            self.scene_textures.apply(self.baked, report)
        except BaseException:
            self.baked = None
            self._bake_changed()
            raise
        old = self._bake.boxes
        if old is None or len(old) != len(scene.instances):
            self._bake.boxes = instance_boxes(scene)
            self._bake_changed()
            return
        new = instance_boxes(scene, idx)
        boxes = merged_boxes(old[idx], new)
        old[idx] = new
        self._bake.changed(boxes)

    def _bake_changed(self) -> None:
        """The shared bake changed: this pipeline's history now, its views' at their next render."""
        self._bake.changed(None)
        self.reset_history()

    def reset_history(self) -> None:
        """Forget all: no pass may reuse what earlier frames left (a camera move alone needs no
        call: the passes carry over what stays exact, :mod:`.passes.reproject`)."""
        for p in self._passes():
            p.reset_history()
        self._st.reset()
        self._generation = self._bake.generation

    def retrace_once(self) -> None:
        """The next frame traces every hard light's mask whole, exact, keeping it as the history
        later frames reuse (a viewport whose view came to rest after reused frames)."""
        self._retrace = True

    def reset_light(self, index: int) -> None:
        """Light ``index`` changed: its history alone is forgotten."""
        for p in self._passes():
            p.reset_light(index)
        self._st.reset()

    def _catch_up(self, scene, width: int, height: int) -> None:
        """Bring the passes' history up to the bake's edits, to what the masks read besides the
        bake (linking, casting, materials and terminator per instance: a change forgets every
        history) and to this frame's camera."""
        inputs = mask_inputs(scene)
        if inputs != self._inputs:
            if self._inputs is not None:
                self.reset_history()
            self._inputs = inputs
        if self._generation != self._bake.generation:
            boxes = self._bake.since(self._generation) if self.reuse else None
            if boxes is None:
                self.reset_history()  # (another view, or a full bake, changed it)
            else:
                for p in self._passes():
                    p.invalidate(boxes)
                self._st.reset()
                self._generation = self._bake.generation
        c = CameraUniforms.from_camera(scene.camera, width, height)
        cam = (c.clip_from_rel.tobytes(), c.cam_pos.tobytes(), c.viewplane, c.resolution, c.clip_start, c.ortho)
        if cam != self._camera and self._camera is not None:
            if self.reuse:
                for p in self._passes():
                    p.camera_moved()
                self._st.reset()  # (the see-through sub-frames average an image of the old view)
            else:
                self.reset_history()
        self._camera = cam

    # -- frame ------------------------------------------------------------------------------------
    def render(self, scene, settings: Settings | None = None, width: int | None = None,
               height: int | None = None, film_transparent: bool = False, read_image: bool = True,
               progress: Progress | None = None, max_draw_ms: float | None = None) -> Frame:
        """Run the passes. ``progress(done, total, label)`` is called before each pass and each
        shadowed light, through the implicit bake and the light grids' builds (whatever it raises
        aborts the frame: a place to cancel). ``max_draw_ms``: the heavy draws (rays, lighting)
        are drawn in tiles of about that time at most (:mod:`.tiles`; a final render's watchdog
        limit), ``progress`` called after each; None: each whole. The shadows are
        traced through the baked scene: the first render bakes ``scene``, and so does one that
        asks for another structure; for another scene call :meth:`set_scene` first (for moved
        instances and edited models, :meth:`move_instances` and :meth:`update_model`).

        With see-through surfaces in view (:mod:`.see_through`) and ``transparency_samples`` > 1
        the frame averages that many sub-frames of stochastic transparency (``accumulate``: one
        more per call, up to them; ``stats["see_through_samples"]`` counts them)."""
        make_current(self.ctx)
        settings = settings or Settings()
        if scene.camera is None:
            raise SceneError(f"scene '{scene.name}' has no camera")
        self.frames_begun.value += 1  # (the frames before this one no longer own the targets)
        width = int(width or scene.resolution[0])
        height = int(height or scene.resolution[1])
        check_render_size(self.ctx, width, height)
        check_light_count(self.ctx, len(scene.lights))
        n = target_samples(settings)
        if n > 1 and self.see_through.in_view(scene, width, height):
            return self._render_see_through(scene, settings, width, height, film_transparent, progress, n,
                                            max_draw_ms)
        return self._render_frame(scene, settings, width, height, film_transparent, read_image, progress,
                                  max_draw_ms=max_draw_ms)

    def _render_see_through(self, scene, settings, width, height, film_transparent, progress, n,
                            max_draw_ms=None) -> Frame:
        """The average of ``n`` sub-frames (all now, or with ``settings.accumulate`` one more than
        the last call's, restarting when the settings, size or film differ). A final frame's
        G-buffer (its data passes) is then drawn once more with the cut at 0.5, as Cycles writes
        its data passes at the first surface of alpha 0.5 or more, and its masks are NaN where
        that G-buffer has no geometry; the viewport's G-buffer is the last sub-frame's and its
        masks NaN where no sub-frame had geometry."""
        if self._generation != self._bake.generation:
            self.reset_history()
        sub = sub_frame_settings(settings)
        if self.shadow_pass(sub.mode).needs_bake and (self.baked is None or self.baked.structure != sub.structure):
            self.set_scene(scene, sub.structure, progress)  # (before the sub-frames: a bake resets history)
        acc = self._st
        key = (settings, width, height, bool(film_transparent))
        if acc.key != key:
            acc.reset(key)
            for p in self._passes():  # (the sub-frames' shadows start without history)
                p.reset_history()
        elif acc.count >= n and acc.frame is not None:
            return acc.frame
        todo = range(acc.count, acc.count + 1) if settings.accumulate else range(n)
        frame = None
        for i in todo:
            frame = self._render_frame(scene, sub, width, height, film_transparent, True,
                                       split_progress(progress, i - todo.start, len(todo)), alpha_sample=i,
                                       max_draw_ms=max_draw_ms)
            acc.add(frame)
        stats = dict(frame.stats, see_through_samples=acc.count, see_through_target=n)
        timings = dict(acc.timings) if not settings.accumulate else dict(frame.timings)
        gbuffer, coverage = frame.gbuffer, None
        if not settings.accumulate:  # the data passes: the surfaces of alpha >= 0.5, as Cycles' are
            job = FrameJob(scene, sub, width, height, film_transparent)
            gbuffer = self._timed(timings, "gbuffer_data", self.gbuffer_pass.render, job)
            timings["total_ms"] += timings["gbuffer_data_ms"]
            self.gbuffer_renders += 1
            coverage = gbuffer.coverage()
        out = Frame(image=(acc.image / acc.count).astype(np.float32), masks=acc.mask_textures(coverage),
                    lights=list(acc.lights), timings=timings, stats=stats, gbuffer=gbuffer,
                    mask_arrays={li: acc.mask(li, coverage) for li in acc.lights}, _count=self.frames_begun,
                    _made=self.frames_begun.value)
        acc.frame = out
        if not settings.accumulate:
            acc.reset()
        return out

    def _render_frame(self, scene, settings, width, height, film_transparent, read_image, progress,
                      alpha_sample: int | None = None, max_draw_ms: float | None = None) -> Frame:
        """One frame's passes (``alpha_sample``: a see-through sub-frame's sample index)."""
        self._catch_up(scene, width, height)
        shadow = self.shadow_pass(settings.mode)
        lights = select_shadowed_lights(scene, settings)
        step = _Steps(progress, 4 + len(lights))
        if self.reuse_choice not in ("auto", "always"):
            raise ValueError(f"reuse_choice must be 'auto' or 'always', not {self.reuse_choice!r}")
        if shadow.configure_reuse(self.reuse, self.reuse_choice == "auto", self._retrace):
            self._retrace = False
        if shadow.needs_bake and (self.baked is None or self.baked.structure != settings.structure):
            self.set_scene(scene, settings.structure, step.within if progress is not None else None)
        self._reset_gl_state()  # (a frame aborted by its progress callback may have left any)
        with self.gpu.budget.frame(max_draw_ms, step.tile if progress is not None else None,
                                   step.within if progress is not None else None):
            return self._passes_of_frame(scene, settings, shadow, step, FrameJob(
                scene, settings, width, height, film_transparent, lights=lights, alpha_sample=alpha_sample),
                read_image)

    def _passes_of_frame(self, scene, settings, shadow, step, job, read_image) -> Frame:
        """The passes of :meth:`_render_frame` over ``job``, counted by ``step``."""
        width, height = job.size
        if self.timing not in TIMINGS:
            raise ValueError(f"timing must be one of {TIMINGS}, not {self.timing!r}")
        per_pass = self.timing == "passes"
        host = counts_of(self.ctx)
        start = host.mark()
        t0 = time.perf_counter()
        clock = self.gpu.clock
        clock.collect()  # (the spans the last frame timed, waited for by its image read)
        clock.deferred = not per_pass
        self.gpu.linking.update(scene)  # (linking lives apart from the bake: an upload at most)
        self.gbuffer_renders += 1
        if shadow.light_label is not None:
            job.on_light = lambda li: step(f"{shadow.light_label}: {scene.lights[li].name}")
        timings = {}
        for p in (self.gbuffer_pass, shadow, self.upsample, self.lighting):
            if p.label is not None:
                step(p.label)
            setattr(job, p.produces, self._timed(timings, p.name, p.render, job) if per_pass else p.render(job))
            if p is shadow and shadow.light_label is None:
                step.done += len(job.lights)
        image = None
        if read_image:
            step("Reading the image")
            image = self._timed(timings, "readback", read_texture, job.image) if per_pass else read_texture(job.image)
        timings["total_ms"] = sum(timings.values()) if per_pass else (time.perf_counter() - t0) * 1e3
        shadow_stats = shadow.stats(job, counts=per_pass)
        stats = {
            "mode": settings.mode,
            "quality": settings.quality,
            "resolution": [width, height],
            "mask_resolution": shadow_stats["mask_resolution"],
            "rays": shadow_stats["rays"],
            "rays_traced": shadow_stats.get("rays_traced", 0),
            "pixels_reused": shadow_stats.get("pixels_reused", 0),
            "reuse_ways": shadow_stats.get("reuse_ways", {}),
            "pixels": shadow_stats.get("pixels", 0),
            "samples": shadow_stats.get("samples", 1),
            "accumulated_samples": shadow_stats.get("accumulated_samples"),
            "noise": shadow_stats.get("noise", {}),
            "shadowed_lights": len(job.lights),
            "lights_culled": shadow_stats.get("lights_culled", 0),
            "defines": shadow_stats["defines"],
            "gpu_memory_mb": round(memory.in_use(self.ctx) / 2**20, 1),
            "trace_path": shadow_stats.get("trace_path"),
            **host.since(start),
        }
        memory.collect(self.ctx)  # (what was dropped unreleased, and moderngl's husks of released objects)
        return Frame(image=image, masks=job.masks, lights=job.lights, timings=timings, stats=stats,
                     gbuffer=job.gbuffer,
                     _count=self.frames_begun, _made=self.frames_begun.value)

    def _reset_gl_state(self) -> None:
        ctx = self.ctx
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.blend_func = moderngl.ONE, moderngl.ZERO
        ctx.depth_func = "<"
        ctx.scissor = None

    def _timed(self, timings: dict, name: str, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        self.ctx.finish()
        timings[f"{name}_ms"] = (time.perf_counter() - t0) * 1e3
        return out

    def release_targets(self, keep_history: bool = False) -> None:
        """Give back what the frames left: every pass's render targets and history (the next
        frame makes its own again); programs, model buffers and the bake stay. ``keep_history``:
        the ray-traced pass stays whole (its masks and reuse history: the next frame of an
        animation reuses them)."""
        make_current(self.ctx)
        self.frames_begun.value += 1
        kept = self._shadow.get("raytrace") if keep_history else None
        for p in self._passes():
            if p is not kept:
                p.release()
        self._st.release()
        self._make_passes()
        if kept is not None:
            self._shadow["raytrace"] = kept

    def drop_bake(self) -> None:
        """Give back the scene: the bake's textures, the model buffers, material and linking
        textures (the next frame makes them again; a ray-traced one bakes again)."""
        make_current(self.ctx)
        self.gpu.release_scene()
        self.baked = None
        self._bake_changed()

    def release(self) -> None:
        """Release the passes' GPU objects, and the shared resources unless this is a view."""
        make_current(self.ctx)
        for p in self._passes():
            p.release()
        self._st.release()
        if self._owns_gpu:
            self.gpu.release()
        memory.collect(self.ctx)
