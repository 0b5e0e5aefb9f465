"""What every pass of one OpenGL context shares: the context, the compiled programs, the model
vertex buffers, the baked scene textures and the frame's draw budget."""
from __future__ import annotations

import moderngl
import numpy as np

from ..bake.materials import bake_materials, material_signature
from .clock import GpuClock
from .geometry import ModelBufferCache
from .linking import LinkTextures
from .programs import ProgramCache
from .scene_textures import SceneTextures
from .tiles import DrawBudget


class GpuResources:
    """Owned by the :class:`~.pipeline.Pipeline` (or a test); passes borrow it and never release
    what it holds."""

    def __init__(self, ctx: moderngl.Context, programs: ProgramCache | None = None):
        self.ctx = ctx
        self.programs = programs if programs is not None else ProgramCache(ctx)
        self.models = ModelBufferCache(ctx)
        self.scene_textures = SceneTextures(ctx)
        self.linking = LinkTextures(ctx)  # light and shadow linking, apart from the bake
        self.budget = DrawBudget(ctx)  # the frame's per-draw time budget (tiled heavy draws)
        self.clock = GpuClock(ctx)  # timed spans of the choices made from GPU time
        self._own_materials = None  # (material_signature, None, {sampler: texture}) made without a bake

    def material_textures(self, scene) -> dict:
        """``{sampler name: texture}`` of the scene's image atlas and material records
        (``shaders/common/alpha.glsl``): the bake's when one is uploaded for a scene with
        materials, else made here from ``scene`` (passes run on their own, e.g. in tests)."""
        st = self.scene_textures
        sig = material_signature(scene)
        if (st.baked is not None and st.baked.materials is not None and "mat" in st.textures
                and st.baked.materials.signature == sig):
            return {"hs_mat_tex": st.textures["mat"], "hs_atlas_tex": st.textures["atlas"]}
        own = self._own_materials
        if own is None or own[0] != sig:
            self._release_own()
            mb = bake_materials(scene, 4096)
            tex = {}
            for name, td in (("hs_mat_tex", mb.mat), ("hs_atlas_tex", mb.atlas)):
                t = self.ctx.texture_array((td.width, td.height, td.layers), td.components,
                                           np.ascontiguousarray(td.data).tobytes(), dtype=td.fmt)
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
                tex[name] = t
            own = self._own_materials = (sig, None, tex)
        return own[2]

    def bind_materials(self, prog, scene, first_unit: int = 0) -> int:
        """Bind :meth:`material_textures` to ``prog`` from ``first_unit``; the next free unit."""
        unit = first_unit
        for name, tex in self.material_textures(scene).items():
            if name in prog:
                tex.use(unit)
                prog[name].value = unit
                unit += 1
        return unit

    def _release_own(self) -> None:
        if self._own_materials is not None:
            for t in self._own_materials[2].values():
                t.release()
            self._own_materials = None

    def release_scene(self) -> None:
        """Give back everything of the scene (model buffers, baked and material textures, the
        linking's); the compiled programs stay."""
        self._release_own()
        self.models.release()
        self.scene_textures.release()
        self.linking.release()

    def release(self) -> None:
        self.release_scene()
        self.clock.release()
        self.programs.release()
