"""The baked scene on the GPU: one texture per :class:`~..bake.TextureData`.

The record textures (every one but the materials' ``mat`` and ``atlas``) are buffer textures
(:mod:`.buffer_textures`) where the GL offers them and each fits its limit, read by the shaders
at texel i directly (``HS_TEXEL_BUFFERS``); else 2D array textures, which ``hs_texel`` addresses.
Both hold the same texels, so the masks are the same either way.

``upload(baked)`` creates (or re-creates) every texture; ``apply(baked, report)`` re-uploads only
the row ranges an incremental update changed (textures that grew are re-created whole).
``bind(prog, first_unit)`` binds the textures to consecutive units and sets the sampler and
structure uniforms a program that includes ``shaders/common/scene_data.glsl`` declares.
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..errors import GPUError
from ..limits import gib
from .buffer_textures import BufferTexture, gl_functions, max_texels
from .context import largest_fit, largest_rows, texture_fits

#: textures the shaders sample as images or share with other passes: always 2D arrays
ARRAY_ONLY = frozenset({"mat", "atlas"})


class SceneTextures:
    def __init__(self, ctx: moderngl.Context, buffers: bool | None = None):
        self.ctx = ctx
        self.textures: dict = {}
        self.baked = None
        #: record textures as buffer textures: None = where available, False = never (2D arrays),
        #: True = always (a GPUError where they are not available)
        self.buffers = buffers
        self.using_buffers = False
        self.generation = 0  # counts the uploads and updates (what is built from the bake follows it)

    @property
    def defines(self) -> dict:
        """The ``#define`` a program reading these textures needs (``HS_FETCH``)."""
        return {"HS_TEXEL_BUFFERS": 1} if self.using_buffers else {}

    def _fit_buffers(self, baked) -> bool:
        if self.buffers is False:
            return False
        limit = max_texels(self.ctx) if gl_functions() is not None else 0
        need = max((td.capacity for n, td in baked.textures.items() if n not in ARRAY_ONLY), default=0)
        ok = limit > 0 and need <= limit
        if not ok and self.buffers:
            raise GPUError("buffer textures are not available here" if limit == 0 else
                           f"a scene texture needs {need} texels; this GPU's buffer textures hold {limit}")
        return ok

    def check(self, td, buffers: bool) -> None:
        """GPUError (one line) when ``td`` does not fit this GPU as what it would be made: a 2D
        array wider, taller or of more layers than GL allows, or one the driver will not make
        (its bytes: :func:`~.context.texture_fits`, a software rasteriser's limit that it would
        otherwise fail silently). A buffer texture's texels are checked by :meth:`_fit_buffers`."""
        if buffers and td.name not in ARRAY_ONLY:
            return
        limits_2d = self.ctx.info["GL_MAX_TEXTURE_SIZE"]
        limits_layers = self.ctx.info["GL_MAX_ARRAY_TEXTURE_LAYERS"]
        if td.width > limits_2d or td.height > limits_2d or td.layers > limits_layers:
            raise GPUError(f"scene texture '{td.name}' needs {td.width}x{td.height}x{td.layers} texels; "
                           f"this GPU allows {limits_2d}x{limits_2d}x{limits_layers}")
        if texture_fits(self.ctx, td.width, td.height, td.components, td.fmt, td.layers) is False:
            if td.layers == 1:
                rows = largest_rows(self.ctx, td.width, td.components, td.fmt, 1, cap=td.height)
            else:
                rows = td.height * largest_fit(td.layers, lambda n: texture_fits(
                    self.ctx, td.width, td.height, td.components, td.fmt, n))
            fit = td.width * rows
            raise GPUError(f"scene texture '{td.name}' needs {td.capacity:,} texels ({gib(td.nbytes)}); this GPU "
                           f"makes one of at most {fit:,} ({gib(fit * (td.nbytes // max(td.capacity, 1)))})")

    def _create(self, td):
        if self.using_buffers and td.name not in ARRAY_ONLY:
            return BufferTexture(self.ctx, np.ascontiguousarray(td.data).tobytes(), td.fmt, td.components)
        self.check(td, False)
        tex = self.ctx.texture_array((td.width, td.height, td.layers), td.components,
                                     np.ascontiguousarray(td.data).tobytes(), dtype=td.fmt)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def upload(self, baked) -> None:
        buffers = self._fit_buffers(baked)  # (its errors leave the textures as they were)
        for td in baked.textures.values():
            self.check(td, buffers)
        self.release()
        self.generation += 1
        self.using_buffers = buffers
        self.baked = baked
        try:
            for name, td in baked.textures.items():
                self.textures[name] = self._create(td)
        except GPUError:
            if not buffers or self.buffers:  # (2D arrays that do not fit, or buffers asked for)
                raise
            # a GL that lists buffer textures but will not make one (a format it lacks): arrays
            self.release()
            self.buffers = False
            self.upload(baked)

    def apply(self, baked, report) -> int:
        """Re-upload what ``report`` (an ``UpdateReport``) changed; returns bytes written."""
        self.generation += 1
        if self.baked is not baked or (report.resized and self.using_buffers != self._fit_buffers(baked)):
            self.upload(baked)  # (a texture outgrew the buffer textures' limit: 2D arrays from now on)
            return sum(t.nbytes for t in baked.textures.values())
        written = 0
        textures = baked.textures
        for name in report.resized:
            old = self.textures.pop(name, None)  # (a texture the update added has none)
            if old is not None:
                old.release()
            td = textures[name]
            self.textures[name] = self._create(td)
            written += td.nbytes
        for name, layer, y0, y1 in report.ranges:
            if name in report.resized:
                continue
            td = textures[name]
            rows = np.ascontiguousarray(td.data[layer, y0:y1])
            tex = self.textures[name]
            if isinstance(tex, BufferTexture):
                tex.write(rows.tobytes(), offset=(layer * td.height + y0) * td.width * td.components * 4)
            else:
                tex.write(rows.tobytes(), viewport=(0, y0, layer, td.width, y1 - y0, 1))
            written += rows.nbytes
        return written

    def bind(self, prog: moderngl.Program, first_unit: int) -> int:
        """Bind textures from ``first_unit`` on and set uniforms; returns the next free unit."""
        unit = first_unit
        samplers = self.baked.samplers
        for name, tex in self.textures.items():
            sname = samplers[name]
            if sname in prog:
                if isinstance(tex, BufferTexture):
                    tex.use(prog, sname, unit)
                else:
                    tex.use(unit)
                    prog[sname].value = unit
                unit += 1
        for name, value in self.baked.uniforms.items():
            if name not in prog:
                continue
            arr = np.asarray(value)
            prog[name].write((arr.astype(np.float32) if arr.dtype.kind == "f" else arr.astype(np.int32)).tobytes())
        return unit

    @property
    def nbytes(self) -> int:
        return 0 if self.baked is None else sum(t.nbytes for t in self.baked.textures.values())

    def release(self) -> None:
        for tex in self.textures.values():
            tex.release()
        self.textures.clear()
        self.baked = None
        self.using_buffers = False
