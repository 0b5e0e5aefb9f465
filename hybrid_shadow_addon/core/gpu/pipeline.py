"""The deferred pipeline: bake -> G-buffer -> shadow masks -> (upsample) -> lighting.

One :class:`Pipeline` per OpenGL context, reused across frames: programs, model buffers and the
baked scene textures stay on the GPU. ``set_scene`` bakes (or re-bakes), ``move_instances`` and
``update_model`` apply incremental updates, ``render`` runs the passes for one
:class:`~..settings.Settings` and returns a :class:`Frame` with the image, the masks and the
timings (each pass is timed up to ``ctx.finish()``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..bake import bake_scene
from ..errors import SceneError
from ..settings import Settings
from .context import check_render_size, create_context
from .passes import (GBufferPass, LightingPass, NoShadowPass, ShadowMapPass, UpsamplePass, read_mask,
                     select_shadowed_lights)
from .passes.gbuffer import ModelBufferCache
from .passes.raytrace import RaytracePass
from .programs import ProgramCache
from .scene_textures import SceneTextures


@dataclass
class Frame:
    """One rendered frame. ``image``: float32 (H, W, 4) linear RGBA, row 0 = top."""

    image: np.ndarray
    masks: dict  # light index -> moderngl texture at full resolution (valid until the next render)
    lights: list  # indices of the shadowed lights, in mask order
    timings: dict = field(default_factory=dict)  # ms per pass
    stats: dict = field(default_factory=dict)
    gbuffer: object = None
    _coverage: np.ndarray = field(default=None, repr=False)

    def mask_array(self, light_index: int) -> np.ndarray:
        """float32 (H, W), row 0 = top, 1 lit / 0 shadowed, NaN where there is no geometry."""
        if self._coverage is None:  # one G-buffer read for all the frame's masks
            self._coverage = self.gbuffer.coverage()
        return read_mask(self.masks[light_index], self.gbuffer, self._coverage)


class Pipeline:
    def __init__(self, ctx=None):
        self.ctx = create_context(ctx)
        self.programs = ProgramCache(self.ctx)
        models = ModelBufferCache(self.ctx)
        self.gbuffer_pass = GBufferPass(self.ctx, self.programs, models)
        self.scene_textures = SceneTextures(self.ctx)
        self.raytrace = RaytracePass(self.ctx, self.programs, self.scene_textures)
        self.shadowmap = ShadowMapPass(self.ctx, self.programs, models)
        self.noshadow = NoShadowPass(self.ctx, self.programs)
        self.upsample = UpsamplePass(self.ctx, self.programs)
        self.lighting = LightingPass(self.ctx, self.programs)
        self.baked = None
        self.bake_ms = 0.0

    # -- scene ------------------------------------------------------------------------------------
    def set_scene(self, scene) -> float:
        """Bake ``scene`` and upload its textures; returns the bake time in ms."""
        t0 = time.perf_counter()
        self.baked = bake_scene(scene)
        self.scene_textures.upload(self.baked)
        self.raytrace.reset_history()
        self.bake_ms = (time.perf_counter() - t0) * 1e3
        return self.bake_ms

    def move_instances(self, scene, indices) -> None:
        """Instances ``indices`` moved (their matrices in ``scene`` already changed)."""
        self._apply(self.baked.update_instances(scene, indices))

    def update_model(self, scene, model_id: int) -> None:
        """Model ``model_id`` was edited or added."""
        self._apply(self.baked.update_model(scene, model_id))

    def _apply(self, report) -> None:
        self.scene_textures.apply(self.baked, report)
        self.raytrace.reset_history()

    def reset_history(self) -> None:
        """Camera, light or setting change: interlacing must not reuse older rays."""
        self.raytrace.reset_history()

    # -- frame ------------------------------------------------------------------------------------
    def render(self, scene, settings: Settings | None = None, width: int | None = None,
               height: int | None = None, film_transparent: bool = False, read_image: bool = True,
               on_step=None) -> Frame:
        """Run the passes. ``on_step(label, done, total)`` is called before each pass and each
        shadowed light (progress, and a place to cancel: whatever it raises aborts the frame)."""
        settings = settings or Settings()
        if scene.camera is None:
            raise SceneError(f"scene '{scene.name}' has no camera")
        width = int(width or scene.resolution[0])
        height = int(height or scene.resolution[1])
        check_render_size(self.ctx, width, height)
        if self.baked is None and settings.mode == "raytrace":
            self.set_scene(scene)
        ctx = self.ctx
        timings = {}
        lights = select_shadowed_lights(scene, settings)
        total = 4 + len(lights)
        done = [0]

        def step(label):
            if on_step is not None:
                on_step(label, done[0], total)
            done[0] += 1

        def on_light(li):
            kind = "Ray tracing shadows" if settings.mode == "raytrace" else "Shadow map"
            step(f"{kind}: {scene.lights[li].name}")

        def timed(name, fn, label=None):
            if label:
                step(label)
            t0 = time.perf_counter()
            out = fn()
            ctx.finish()
            timings[name] = (time.perf_counter() - t0) * 1e3
            return out

        gbuffer = timed("gbuffer_ms", lambda: self.gbuffer_pass.render(scene, width, height), "G-buffer")
        if settings.mode == "raytrace":
            masks = timed("shadow_ms", lambda: self.raytrace.render(scene, gbuffer, settings, lights, on_light))
        elif settings.mode == "shadowmap":
            masks = timed("shadow_ms", lambda: self.shadowmap.render(scene, gbuffer, settings, lights, on_light))
        else:
            masks = timed("shadow_ms", lambda: self.noshadow.render(scene, gbuffer, settings, lights))
            done[0] += len(lights)
        masks = timed("upsample_ms", lambda: self.upsample.render(masks, gbuffer, settings), "Upsampling masks")
        timed("lighting_ms", lambda: self.lighting.render(scene, gbuffer, masks, settings, film_transparent),
              "Lighting")
        image = timed("readback_ms", lambda: self.lighting.read(), "Reading the image") if read_image else None
        timings["total_ms"] = sum(timings.values())
        mw, mh = settings.mask_size(width, height) if settings.mode == "raytrace" else (width, height)
        stats = {
            "mode": settings.mode,
            "quality": settings.quality,
            "resolution": [width, height],
            "mask_resolution": [mw, mh],
            "rays": int(mw * mh * len(lights)) if settings.mode == "raytrace" else 0,
            "shadowed_lights": len(lights),
            "defines": sorted(f"{k}={v}" for k, v in self.raytrace.last_defines.items())
            if settings.mode == "raytrace" else [],
        }
        return Frame(image=image, masks=masks, lights=lights, timings=timings, stats=stats, gbuffer=gbuffer)

    def release(self) -> None:
        for p in (self.gbuffer_pass, self.raytrace, self.shadowmap, self.noshadow, self.upsample, self.lighting):
            p.release()
        self.scene_textures.release()
        self.programs.release()
