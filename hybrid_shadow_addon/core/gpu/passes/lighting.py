"""Pass 3: deferred lighting into a linear RGBA32F image; ``to_srgb8``/``write_png`` for output.

The lighting model (units, BRDF) is documented and mirrored in numpy in
``core/lighting_reference.py``. Lights with a mask in ``masks`` are multiplied by it; the others
are unshadowed. The light table is a texture (4 RGBA32F texels per light).
"""
from __future__ import annotations

import struct
import zlib

import moderngl
import numpy as np

from ...lighting_reference import light_table
from ..context import check_render_size
from .gbuffer import read_texture

MAX_MASKS = 8  # masked lights per full-screen batch (sampler array in shaders/lighting.glsl)


class LightingPass:
    """``render(scene, gbuffer, masks=None, settings=None, film_transparent=False) -> Texture``.

    The returned RGBA32F texture is owned by the pass (overwritten by the next render);
    :meth:`read` gives it as float32 (H, W, 4), row 0 = top."""

    def __init__(self, ctx: moderngl.Context, programs):
        self.ctx = ctx
        self.programs = programs
        self._out = None
        self._fbo = None
        self._lights = None
        self.batches = 0

    def _target(self, w, h):
        if self._out is None or self._out.size != (w, h):
            if self._out is not None:
                self._fbo.release()
                self._out.release()
            check_render_size(self.ctx, w, h, "image")
            self._out = self.ctx.texture((w, h), 4, dtype="f4")
            self._out.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._fbo = self.ctx.framebuffer(color_attachments=[self._out])
        return self._fbo

    def _light_texture(self, table: np.ndarray):
        n = max(len(table), 1)
        data = np.zeros((n, 4, 4), np.float32)
        data[:len(table)] = table
        if self._lights is None or self._lights.width != 4 * n:
            if self._lights is not None:
                self._lights.release()
            self._lights = self.ctx.texture((4 * n, 1), 4, dtype="f4")
            self._lights.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._lights.write(data.tobytes())
        return self._lights

    def render(self, scene, gbuffer, masks: dict | None = None, settings=None,
               film_transparent: bool = False) -> moderngl.Texture:
        ctx = self.ctx
        masks = {int(k): v for k, v in (masks or {}).items() if 0 <= int(k) < len(scene.lights)}
        unmasked = [i for i in range(len(scene.lights)) if i not in masks]
        masked = sorted(masks)
        order = unmasked + masked
        table = light_table([scene.lights[i] for i in order]) if order else np.zeros((0, 4, 4))
        lights_tex = self._light_texture(table)
        fbo = self._target(gbuffer.width, gbuffer.height)
        fbo.use()
        ctx.viewport = (0, 0, gbuffer.width, gbuffer.height)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        prog, vao = self.programs.fullscreen("lighting")
        unit = gbuffer.bind(prog)
        lights_tex.use(unit)
        prog["u_lights"].value = unit
        unit += 1
        mask_units = list(range(unit, unit + MAX_MASKS))
        prog["u_masks"].value = mask_units
        use_spec = 1 if (settings is None or settings.specular) else 0
        common = {"u_world_color": tuple(float(c) for c in scene.world_color), "u_specular": use_spec,
                  "u_transparent": int(bool(film_transparent)),
                  "u_unmasked_begin": 0, "u_unmasked_end": len(unmasked)}
        for k, v in common.items():
            if k in prog:
                prog[k].value = v
        nb = max(1, -(-len(masked) // MAX_MASKS))
        self.batches = nb
        for b in range(nb):
            rows = list(range(len(unmasked) + b * MAX_MASKS, min(len(order), len(unmasked) + (b + 1) * MAX_MASKS)))
            for k, row in enumerate(rows):
                masks[order[row]].use(mask_units[k])
            for k in range(len(rows), MAX_MASKS):  # keep unused samplers on a valid texture
                lights_tex.use(mask_units[k])
            prog["u_masked_count"].value = len(rows)
            prog["u_masked_rows"].value = rows + [0] * (MAX_MASKS - len(rows))
            prog["u_first_batch"].value = int(b == 0)
            if b == 1:
                ctx.enable(moderngl.BLEND)
                ctx.blend_equation = moderngl.FUNC_ADD
                ctx.blend_func = moderngl.ONE, moderngl.ONE
            vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.BLEND)
        return self._out

    def read(self) -> np.ndarray:
        return read_texture(self._out)

    def release(self) -> None:
        for o in (self._fbo, self._out, self._lights):
            if o is not None:
                o.release()
        self._fbo = self._out = self._lights = None


def to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear float (H, W, 3|4) -> uint8 sRGB (standard piecewise OETF); alpha stays linear."""
    img = np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    rgb = np.clip(img[..., :3], 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    out = np.empty(img.shape, np.uint8)
    out[..., :3] = np.round(srgb * 255.0)
    if img.shape[-1] == 4:
        out[..., 3] = np.round(np.clip(img[..., 3], 0.0, 1.0) * 255.0)
    return out


def write_png(path, rgba8: np.ndarray) -> None:
    """Write uint8 (H, W, 3|4) (row 0 = top) as a PNG with zlib + struct only."""
    a = np.ascontiguousarray(rgba8, np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    h, w, c = a.shape
    color_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    raw = np.concatenate([np.zeros((h, 1), np.uint8), a.reshape(h, w * c)], axis=1).tobytes()

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)
