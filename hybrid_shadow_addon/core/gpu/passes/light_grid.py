"""The hard lights' light-space grids on the GPU (``Settings.light_grid``; bake:
:mod:`...bake.lightgrid`, shader: ``shaders/common/scene_lightgrid.glsl``): a per-light
accelerator, :class:`LightGridCache`, owned by the ray-traced pass's hard visibility
(:mod:`.hard`), which asks it :meth:`~LightGridCache.for_light` and tells it each BVH trace's
time (:meth:`~LightGridCache.note_bvh`).

A grid costs a bake (numpy, per caster and light) and saves part of every later frame's rays,
so it is built only where it pays back: a light is traced through the two-level BVH the first
time a frame sees it as it is (after any change of the bake, or of the light's direction or
position), its time measured; when a later frame sees it unchanged, its grid is built if the
estimated build time is at most :data:`PAYBACK_FRAMES` times that BVH time (the estimate: this
machine's last build's time per caster, or :data:`BUILD_US_PER_CASTER`). A one-frame render
then never builds one; a still scene in the viewport, or an animation of the camera, builds
them from the second frame on where the rays are costly enough. Such a build runs in a
background thread (numpy, which leaves the interpreter to the render thread for most of its
work): the frames meanwhile trace the tree, and the first frame after it is done uploads and
uses the grid, so a viewport never stalls for one. ``eager``
(``RaytraceOptions.eager_light_grids``: benchmarks, tests, tools) builds at first sight, in the
frame. A grid is kept while the bake and its light stay; the world casters, and their triangle
texture shared by all grids, once per bake (any upload or update of the scene textures). Once
the grids kept hold MAX_BYTES, no more are built. A light whose grid does not fit
(:func:`...bake.lightgrid.build_sun_grid` / ``build_local_grid`` return None) keeps the BVH.
A light with a blocker collection (shadow linking) files only its blockers: its grid is kept
under its blockers too, so that a change of the collection builds another, without a bake.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ...bake.lightgrid import build_local_grid, build_sun_grid, caster_keep, tri_texture, world_casters
from ...errors import GPUError
from ...progress import run_reporting
from ...scene.linking import blockers
from ..scene_textures import SceneTextures

KEEP_EXTRA = 4  # grids kept beyond those of the last frame's lights (recent places of a moving light)
PAYBACK_FRAMES = 100  # a grid is built when it costs at most this many frames of the light's BVH rays
BUILD_US_PER_CASTER = 3.5  # the build's time per caster before this process has measured one
#: the grids' textures kept at most (bytes): past it no new grid is built (those lights keep the
#: tree), so that many lights over a big scene cannot exhaust the GPU's memory
MAX_BYTES = 1 << 30


def _result(fn, *args):
    """``fn(*args)``, or None where it ran out of memory: the light keeps the tree."""
    try:
        return fn(*args)
    except MemoryError:
        return None


@dataclass
class _TexSet:
    textures: dict
    samplers: dict
    uniforms: dict = field(default_factory=dict)


@dataclass
class LightGridHandle:
    """A light's grid ready to trace: its textures, the built :class:`...bake.lightgrid`
    grid and the textures of the triangles all grids share."""

    textures: SceneTextures
    grid: object
    triangles: SceneTextures

    @property
    def defines(self) -> dict:
        return self.grid.defines

    def bind(self, prog, unit: int) -> int:
        """Bind the grid (and the shared triangles) to ``prog`` from ``unit`` on."""
        unit = self.triangles.bind(prog, unit)
        return self.textures.bind(prog, unit)


class LightGridCache:
    """The hard lights' grids of one pass: built where they pay back (or at first sight,
    ``eager``), kept while the bake and the light stay."""

    def __init__(self, gpu, eager: bool = False):
        self.ctx = gpu.ctx
        self.scene_textures = gpu.scene_textures
        self.budget = gpu.budget  # (its progress: the frame's, for a build in the frame)
        self._generation = None
        self._casters = None
        self._tri = None  # SceneTextures of the shared triangle texture
        self._grids: dict = {}  # (kind, light vector bytes) -> (SceneTextures or None, LightGrid or None)
        self._used: set = set()  # keys the current frame used
        self.build_ms = 0.0  # time spent building grids (and casters) in the last frame
        self.eager = bool(eager)  # build at a light's first sight (benchmarks, tests), not once it pays
        self.total_build_ms = 0.0  # all builds and uploads so far (compare reports it)
        self._seen: dict = {}  # key -> ms of the light's last BVH trace in this bake
        self._pending: dict = {}  # key -> Future of a grid being built in the background
        self._pool = None
        self._us_per_caster = BUILD_US_PER_CASTER
        self.last: dict = {}  # light name -> {"cells", "entries", "max_cell", "build_ms", "bytes"}

    @staticmethod
    def usable(baked, settings) -> bool:
        """Whether the hard lights of this bake and settings trace grids: the two-level BVH (its
        triangle test and instance records), no alpha-cut casters (their transmittance needs the
        materials and UVs of the tree's leaves)."""
        return (bool(settings.light_grid) and baked is not None and baked.accel.supports_light_grids
                and not baked.has_alpha)

    def begin_frame(self) -> None:
        self.build_ms = 0.0
        self.last = {}
        self._used = set()

    def end_frame(self) -> None:
        """Forget the grids the frame did not use, beyond the KEEP_EXTRA most recent. (Builds
        start only for a light seen unchanged in two frames, so a light being dragged starts
        none.)"""
        stale = [k for k in self._grids if k not in self._used]
        for k in stale[: max(0, len(stale) - KEEP_EXTRA)]:
            tex = self._grids.pop(k)[0]
            if tex is not None:
                tex.release()

    @staticmethod
    def key(local: bool, light_vec) -> tuple:
        return (bool(local), np.asarray(light_vec, np.float32).tobytes())

    def note_bvh(self, local: bool, light_vec, ms: float) -> None:
        """A light was traced through the BVH in ``ms``: the measure its grid must pay back."""
        self._seen[self.key(local, light_vec)] = float(ms)

    def for_light(self, scene, light, local: bool, light_vec) -> LightGridHandle | None:
        """The grid of a hard light (``light_vec``: the shader's ``u_light_vec``), or None: no
        grid (yet: see the module's docstring; or it does not fit)."""
        textures = self.scene_textures
        if self._generation != textures.generation:
            self.release()
            self._generation = textures.generation
        base = self.key(local, light_vec)
        keep_inst = blockers(scene, light) if light.blocker_set >= 0 else None
        key = base if keep_inst is None else base + (np.packbits(keep_inst).tobytes(),)
        self._used.add(key)
        hit = self._grids.pop(key, None)
        if hit is None:
            fut = self._pending.get(key)
            if fut is not None:  # a build in the background: its grid once it is done
                if not fut.done():
                    return None
                del self._pending[key]
                t0 = time.perf_counter()
                hit = self._upload(_result(fut.result))
                self._spent(t0)
            else:
                if sum(g.nbytes for _, g in self._grids.values() if g is not None) >= MAX_BYTES:
                    return None
                if not self.eager:
                    if self._casters is not None:
                        n = self._casters.count
                    else:
                        inst = scene.instances
                        n = sum(scene.models[m].triangle_count for m in inst.model_ids[inst.casts_shadow].tolist())
                    seen = self._seen.get(base)
                    if seen is None or n * self._us_per_caster * 1e-3 > PAYBACK_FRAMES * seen:
                        return None
                t0 = time.perf_counter()
                if not self.eager:  # (the frames go on through the tree meanwhile)
                    if self._casters is None:
                        self._casters = world_casters(scene, textures.baked.origin)
                    if self._pool is None:
                        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="light-grid")
                    self._pending[key] = self._pool.submit(_result, *self._build_args(scene, local, light_vec,
                                                                                       keep_inst))
                    self._spent(t0)
                    return None
                # in the frame: reported to (and stopped by) the frame's progress; a stopped build
                # leaves nothing behind
                casters, grid = run_reporting(self._build_now, scene, local, light_vec, keep_inst,
                                              progress=self.budget.progress, label=f"light grid of {light.name}",
                                              expected_s=self._estimate_s(scene))
                self._casters = casters
                hit = self._upload(grid)
                self._spent(t0)
        self._grids[key] = hit  # (most recently used last)
        tex, grid = hit
        if grid is not None:
            self.last[light.name] = {"cells": list(grid.cells), "entries": grid.entries,
                                     "max_cell": grid.max_cell, "build_ms": round(grid.build_ms, 1),
                                     "bytes": grid.nbytes}
        return None if grid is None else LightGridHandle(tex, grid, self._tri)

    def _build_args(self, scene, local: bool, light_vec, keep_inst, casters=None) -> tuple:
        """(build function, its arguments) of a light's grid over ``casters`` (None: the cached)."""
        casters = self._casters if casters is None else casters
        keep = None if keep_inst is None else caster_keep(casters, keep_inst)
        build = build_local_grid if local else build_sun_grid
        return build, casters, light_vec, self.scene_textures.baked.config.tex_width, None, keep

    def _build_now(self, scene, local: bool, light_vec, keep_inst) -> tuple:
        """(casters, grid or None): the world casters (the cached ones, else made) and the grid."""
        casters = self._casters
        if casters is None:
            casters = world_casters(scene, self.scene_textures.baked.origin)
        return casters, _result(*self._build_args(scene, local, light_vec, keep_inst, casters))

    def _estimate_s(self, scene) -> float:
        """The expected build time (s) of a grid over the scene's casters."""
        inst = scene.instances
        n = self._casters.count if self._casters is not None else sum(
            scene.models[m].triangle_count for m in inst.model_ids[inst.casts_shadow].tolist())
        return max(n * self._us_per_caster * 1e-6, 1e-3)

    def _spent(self, t0: float) -> None:
        ms = (time.perf_counter() - t0) * 1e3
        self.build_ms += ms
        self.total_build_ms += ms

    def _upload(self, grid) -> tuple:
        """(textures, grid) of a built grid (None: (None, None)), the shared triangles too."""
        textures = self.scene_textures
        tex = None
        try:
            if grid is not None and self._tri is None:
                self._tri = SceneTextures(self.ctx, buffers=textures.using_buffers)
                self._tri.upload(_TexSet({"lg_tri": tri_texture(self._casters, textures.baked.config.tex_width)},
                                         {"lg_tri": "hs_lg_tri_tex"}))
            if grid is not None:
                tex = SceneTextures(self.ctx, buffers=textures.using_buffers)
                tex.upload(grid)
        except GPUError:  # (larger than this GPU's textures: the tree, as for a grid that does not fit)
            if tex is not None:
                tex.release()
            tex = grid = None
        if grid is not None and self._casters.count:
            self._us_per_caster = grid.build_ms * 1e3 / self._casters.count
        return tex, grid

    def wait(self) -> None:
        """Until the builds in the background are done (tests, benchmarks)."""
        for fut in list(self._pending.values()):
            fut.exception()

    def release(self) -> None:
        for tex, _ in self._grids.values():
            if tex is not None:
                tex.release()
        self._grids.clear()
        self._seen.clear()
        self._pending.clear()  # (a build still running finishes unseen: its bake is gone)
        if self._tri is not None:
            self._tri.release()
            self._tri = None
        self._casters = None

    def close(self) -> None:
        """Release everything and stop the background thread (the pass is going away)."""
        self.release()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
