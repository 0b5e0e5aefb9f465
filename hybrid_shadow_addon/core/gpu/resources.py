"""What every pass of one OpenGL context shares: the context, the compiled programs, the model
vertex buffers and the baked scene textures."""
from __future__ import annotations

import moderngl

from .geometry import ModelBufferCache
from .programs import ProgramCache
from .scene_textures import SceneTextures


class GpuResources:
    """Owned by the :class:`~.pipeline.Pipeline` (or a test); passes borrow it and never release
    what it holds."""

    def __init__(self, ctx: moderngl.Context, programs: ProgramCache | None = None):
        self.ctx = ctx
        self.programs = programs if programs is not None else ProgramCache(ctx)
        self.models = ModelBufferCache(ctx)
        self.scene_textures = SceneTextures(ctx)

    def release(self) -> None:
        self.models.release()
        self.scene_textures.release()
        self.programs.release()
