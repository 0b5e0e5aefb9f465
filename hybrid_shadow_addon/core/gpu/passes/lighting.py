"""Deferred lighting into a linear RGBA32F image.

The lighting model (units in :mod:`..lights`, BRDF in ``shaders/common/lights.glsl``) has a
numpy mirror in ``core/oracle/lighting.py``. Lights with a mask are multiplied by it; the others
are unshadowed; those the shadow pass found to light no pixel (``job.dark``) are left out. The
light table (``LIGHT_TEXELS`` RGBA32F texels per light) is a uniform block where it fits the
driver's block size (a light's row is the same for every pixel, and a uniform block is read
once per lane group where a texture is read once per lane), else a texture; the program is the
variant of the kinds of light in it (:func:`..lights.lighting_defines`). Sized area lights are
lit in loops of their own, after the others (the table is ordered so: unmasked lights, then the
masked ones in batches, each group with its sized area lights last): a SIMD rasteriser runs both
sides of a branch on a light's kind, so one loop for all would cost every light the area light's
polygon (BENCHMARKS.md, "The frame around the rays").
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..lights import LIGHT_TEXELS, light_table, lighting_defines, sized_area
from ..targets import TargetCache, set_uniforms
from .base import Pass

MAX_MASKS = 8  # masked lights per full-screen batch (sampler array in shaders/lighting.glsl)


class LightingPass(Pass):
    """``render(job) -> Texture``: the RGBA32F image of ``job``'s G-buffer and masks, owned by
    the pass (overwritten by the next render)."""

    produces = "image"
    name = "lighting"
    label = "Lighting"

    def __init__(self, gpu):
        super().__init__(gpu)
        self._out = TargetCache(self.ctx, components=4, what="image")
        self._lights = TargetCache(self.ctx, components=4, what="light table")
        self.batches = 0
        self.lights_drawn = 0  # lights the last render lit (all but the dark ones)
        self.uniform_block = True  # the light table in a uniform block where it fits (tests compare)
        self._block = None

    def _light_texture(self, table: np.ndarray):
        n = max(len(table), 1)
        data = np.zeros((n, LIGHT_TEXELS, 4), np.float32)
        data[:len(table)] = table
        tex = self._lights.texture("lights", LIGHT_TEXELS * n, 1)
        tex.write(data.tobytes())
        return tex

    def _light_block(self, table: np.ndarray):
        """``(defines, buffer)`` of the table in a uniform block (``HS_LIGHT_ROWS`` texels, for
        a light count rounded up to a power of two from 8: few program variants), or ``None``
        where it does not fit the driver's block size (or :attr:`uniform_block` is off)."""
        if not self.uniform_block:
            return None
        cap = 8
        while cap < len(table):
            cap *= 2
        rows = LIGHT_TEXELS * cap
        if 16 * rows > int(self.ctx.info.get("GL_MAX_UNIFORM_BLOCK_SIZE", 16384) or 16384):
            return None
        data = np.zeros((cap, LIGHT_TEXELS, 4), np.float32)
        data[:len(table)] = table
        if self._block is None or self._block.size != data.nbytes:
            if self._block is not None:
                self._block.release()
            self._block = self.ctx.buffer(reserve=data.nbytes, dynamic=True)
        self._block.write(data.tobytes())
        return {"HS_LIGHT_ROWS": rows}, self._block

    def render(self, job) -> moderngl.Texture:
        ctx = self.ctx
        scene, gbuffer, settings = job.scene, job.gbuffer, job.settings
        masks = {int(k): v for k, v in (job.masks or {}).items() if 0 <= int(k) < len(scene.lights)}
        dark = set(getattr(job, "dark", ()) or ()) & set(masks)  # (they would add 0 at every pixel)
        full = light_table(list(scene.lights)) if scene.lights else np.zeros((0, LIGHT_TEXELS, 4))
        area = sized_area(full)
        # each kind in a loop of its own (shaders/lighting.glsl): the unmasked lights other than
        # sized area lights, then those; the masked ones likewise, cut into batches of MAX_MASKS
        unmasked = sorted((i for i in range(len(scene.lights)) if i not in masks), key=lambda i: bool(area[i]))
        masked = sorted(set(masks) - dark, key=lambda i: (bool(area[i]), i))
        order = unmasked + masked
        split = sum(1 for i in unmasked if not area[i])
        self.lights_drawn = len(order)
        table = full[order] if order else np.zeros((0, LIGHT_TEXELS, 4))
        block = self._light_block(table)
        lights_tex = self._light_texture(table) if block is None else None
        out = self._out.get("image", *gbuffer.size)
        out.use(ctx)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        defines = lighting_defines(table)
        self.gpu.linking.update(scene)
        defines.update(self.gpu.linking.defines)
        if block is not None:
            defines.update(block[0])
            block[1].bind_to_uniform_block(0)
        use_spec = 1 if (settings is None or settings.specular) else 0
        common = {"u_world_color": tuple(float(c) for c in scene.world_color), "u_specular": use_spec,
                  "u_transparent": int(bool(job.film_transparent)),
                  "u_unmasked_split": split, "u_unmasked_end": len(unmasked)}
        nb = max(1, -(-len(masked) // MAX_MASKS))
        self.batches = nb
        for b in range(nb):
            rows = list(range(len(unmasked) + b * MAX_MASKS, min(len(order), len(unmasked) + (b + 1) * MAX_MASKS)))
            variant = {**defines, "HS_MASKS": len(rows), "HS_MASKS_POINT": sum(1 for r in rows if not area[order[r]])}
            if b == 0:
                variant["HS_FIRST_BATCH"] = 1
                if split:
                    variant["HS_UNMASKED_POINT"] = 1
                if split < len(unmasked):
                    variant["HS_UNMASKED_AREA"] = 1
            prog, vao = self.programs.fullscreen("lighting", variant)
            unit = gbuffer.bind(prog)
            if block is not None:
                if "HsLights" in prog:  # (a scene without lights compiles none of it out)
                    prog["HsLights"].binding = 0
            else:
                lights_tex.use(unit)
                set_uniforms(prog, {"u_lights": unit})
                unit += 1
            unit = self.gpu.linking.bind_lights(prog, unit, [scene.lights[i] for i in order])
            for k, row in enumerate(rows):
                masks[order[row]].use(unit + k)
            set_uniforms(prog, common)
            for name, values in (("u_masks", list(range(unit, unit + MAX_MASKS))),
                                 ("u_masked_rows", rows + [0] * (MAX_MASKS - len(rows)))):
                if name in prog:  # (the compiler keeps the array up to its last element in use)
                    n = prog[name].array_length
                    prog[name].value = values[:n] if n > 1 else values[0]
            if b == 1:
                ctx.enable(moderngl.BLEND)
                ctx.blend_equation = moderngl.FUNC_ADD
                ctx.blend_func = moderngl.ONE, moderngl.ONE
            self.gpu.budget.draw(vao, gbuffer.size)
        ctx.disable(moderngl.BLEND)
        return out.texture

    def release(self) -> None:
        self._out.release()
        self._lights.release()
        if self._block is not None:
            self._block.release()
            self._block = None
