"""Shadow mode ``none``: every shadowed light gets a mask of 1 (fully lit)."""
from __future__ import annotations

from ..targets import TargetCache
from .base import ShadowPass


class NoShadowPass(ShadowPass):
    """One shared all-ones R32F texture at G-buffer resolution for each shadowed light."""

    def __init__(self, gpu):
        super().__init__(gpu)
        self._ones = TargetCache(self.ctx, fill=1.0, what="mask")

    def render(self, job) -> dict:
        ones = self._ones.texture("ones", *job.size)
        return {i: ones for i in job.lights}

    def release(self) -> None:
        self._ones.release()
