"""The baked scene on the GPU: one texture array per :class:`~..bake.TextureData`.

``upload(baked)`` creates (or re-creates) every texture; ``apply(baked, report)`` re-uploads only
the row ranges an incremental update changed (textures that grew are re-created whole).
``bind(prog, first_unit)`` binds the textures to consecutive units and sets the sampler and
grid uniforms a program that includes ``shaders/common/scene_data.glsl`` declares.
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..errors import GPUError


class SceneTextures:
    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.textures: dict[str, moderngl.TextureArray] = {}
        self.baked = None

    def _create(self, td) -> moderngl.TextureArray:
        limits_2d = self.ctx.info["GL_MAX_TEXTURE_SIZE"]
        limits_layers = self.ctx.info["GL_MAX_ARRAY_TEXTURE_LAYERS"]
        if td.width > limits_2d or td.height > limits_2d or td.layers > limits_layers:
            raise GPUError(f"scene texture '{td.name}' needs {td.width}x{td.height}x{td.layers} texels; "
                           f"this GPU allows {limits_2d}x{limits_2d}x{limits_layers}")
        tex = self.ctx.texture_array((td.width, td.height, td.layers), td.components,
                                     np.ascontiguousarray(td.data).tobytes(), dtype=td.fmt)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def upload(self, baked) -> None:
        self.release()
        self.baked = baked
        for name, td in baked.textures.items():
            self.textures[name] = self._create(td)

    def apply(self, baked, report) -> int:
        """Re-upload what ``report`` (an ``UpdateReport``) changed; returns bytes written."""
        if self.baked is not baked:
            self.upload(baked)
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
            self.textures[name].write(rows.tobytes(), viewport=(0, y0, layer, td.width, y1 - y0, 1))
            written += rows.nbytes
        return written

    def bind(self, prog: moderngl.Program, first_unit: int) -> int:
        """Bind textures from ``first_unit`` on and set uniforms; returns the next free unit."""
        unit = first_unit
        samplers = self.baked.samplers
        for name, tex in self.textures.items():
            sname = samplers[name]
            if sname in prog:
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
