"""The hard suns' light-space grids on the GPU (``Settings.sun_grid``; bake:
:mod:`...bake.sungrid`, shader: ``shaders/common/scene_sungrid.glsl``).

A grid is built for a sun's direction the first time a frame needs it and kept while the bake
and that direction stay (the viewport turning a sun rebuilds it; a still sun costs nothing). The
world casters it is filed from are built once per bake (any upload or update of the scene
textures). A sun whose grid does not fit (:func:`...bake.sungrid.build_sun_grid` returns None)
keeps the two-level BVH.
"""
from __future__ import annotations

import time

import numpy as np

from ...bake.sungrid import build_sun_grid, world_casters
from ...errors import GPUError
from ..scene_textures import SceneTextures

KEEP = 4  # grids kept (suns of the scene, or recent directions of a turning sun)


class SunGrids:
    def __init__(self, gpu):
        self.ctx = gpu.ctx
        self.scene_textures = gpu.scene_textures
        self._generation = None
        self._casters = None
        self._grids: dict = {}  # direction bytes -> (SceneTextures or None, SunGrid or None)
        self.last_build_ms = 0.0  # time spent building grids (and casters) in the last frame
        self.last: dict = {}  # light name -> {"cells", "entries", "max_cell", "build_ms", "bytes"}

    @staticmethod
    def usable(baked, settings) -> bool:
        """Whether a hard sun of this bake and settings traces a grid: the two-level BVH (its
        triangle test and instance records), no alpha-cut casters (their transmittance needs the
        materials and UVs of the tree's leaves)."""
        return bool(settings.sun_grid) and baked is not None and baked.structure == "bvh" and not baked.has_alpha

    def begin_frame(self) -> None:
        self.last_build_ms = 0.0
        self.last = {}

    def get(self, scene, light, direction):
        """``(textures, grid)`` for a sun shining from ``direction`` (the shader's
        ``u_light_vec``), or None where its grid does not fit."""
        st = self.scene_textures
        if self._generation != st.generation:
            self.release()
            self._generation = st.generation
        key = np.asarray(direction, np.float32).tobytes()
        hit = self._grids.pop(key, None)
        if hit is None:
            t0 = time.perf_counter()
            if self._casters is None:
                self._casters = world_casters(scene, st.baked.origin)
            grid = build_sun_grid(self._casters, direction, st.baked.config.tex_width)
            tex = None
            if grid is not None:
                tex = SceneTextures(self.ctx, buffers=st.using_buffers)
                try:
                    tex.upload(grid)
                except GPUError:  # (larger than this GPU's textures: the tree, as for a grid that does not fit)
                    tex.release()
                    tex = grid = None
            hit = (tex, grid)
            self.last_build_ms += (time.perf_counter() - t0) * 1e3
            while len(self._grids) >= KEEP:
                old = self._grids.pop(next(iter(self._grids)))
                if old[0] is not None:
                    old[0].release()
        self._grids[key] = hit  # (most recently used last)
        tex, grid = hit
        if grid is not None:
            self.last[light.name] = {"cells": list(grid.cells), "entries": grid.entries,
                                     "max_cell": grid.max_cell, "build_ms": round(grid.build_ms, 1),
                                     "bytes": grid.nbytes}
        return None if grid is None else hit

    def release(self) -> None:
        for tex, _ in self._grids.values():
            if tex is not None:
                tex.release()
        self._grids.clear()
        self._casters = None
