"""Shadow mode ``none``: every selected light gets a mask of 1 (fully lit)."""
from __future__ import annotations

import moderngl

from . import create_mask_texture, select_shadowed_lights


class NoShadowPass:
    """``render(scene, gbuffer, settings=None, lights=None) -> dict[int, Texture]``: one shared
    all-ones R32F texture at G-buffer resolution for each shadowed light."""

    def __init__(self, ctx: moderngl.Context, programs=None):
        self.ctx = ctx
        self._ones = None

    def render(self, scene, gbuffer, settings=None, lights=None) -> dict:
        size = (gbuffer.width, gbuffer.height)
        if self._ones is None or self._ones.size != size:
            if self._ones is not None:
                self._ones.release()
            self._ones = create_mask_texture(self.ctx, *size, fill=1.0)
        idx = select_shadowed_lights(scene, settings) if lights is None else list(lights)
        return {i: self._ones for i in idx}

    def release(self) -> None:
        if self._ones is not None:
            self._ones.release()
            self._ones = None
