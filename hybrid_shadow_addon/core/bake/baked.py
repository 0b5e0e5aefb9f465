"""The full bake: Scene -> BakedScene, one acceleration structure (``structures/``) plus the
materials, the bake-space origin and the configuration."""
from __future__ import annotations

import time

import numpy as np

from ..progress import Progress, reporting, stage
from .materials import MaterialBake, bake_materials
from .report import UpdateReport
from .state import BakeConfig
from .structures import AccelerationStructure, structure_class
from .textures import TextureData


def choose_origin(scene) -> np.ndarray:
    """The bake-space origin: world zero, unless the casters sit farther from it than their own
    extent — then a nearby round point (a multiple of a power of two near the extent), so that
    float32 coordinates keep their precision 100 km out as well as at home."""
    casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else []
    if len(casters) == 0:
        return np.zeros(3)
    c, r = scene.instance_spheres(casters)
    lo, hi = (c - r[:, None]).min(axis=0), (c + r[:, None]).max(axis=0)
    center, extent = (lo + hi) / 2, float((hi - lo).max())
    if not np.isfinite(center).all() or np.abs(center).max() <= max(extent, 1.0):
        return np.zeros(3)
    q = 2.0 ** np.ceil(np.log2(max(extent, 1.0)))
    return np.round(center / q) * q


class BakedScene:
    """All GPU-ready scene data: the acceleration structure's textures, defines and uniforms, and
    the materials'. Build with :func:`bake_scene`; it asks its structure (:attr:`accel`)."""

    def __init__(self, config: BakeConfig, origin: np.ndarray, accel: AccelerationStructure,
                 materials: MaterialBake | None):
        self.config: BakeConfig = config
        #: bake space = world - origin (float64 on the CPU): every texture and uniform is in it
        self.origin: np.ndarray = origin
        #: the acceleration structure the shadow rays walk
        self.accel: AccelerationStructure = accel
        #: textured / alpha-cut materials (atlas + records), None when the scene has none
        self.materials: MaterialBake | None = materials

    @property
    def structure(self) -> str:
        """The structure's registry name (``Settings.structure``)."""
        return self.accel.name

    # ------------------------------------------------------------------ public read-outs --
    @property
    def textures(self) -> dict[str, TextureData]:
        """Every texture by name, in upload order."""
        out = self.accel.textures
        if self.materials is not None:
            out = dict(out, mat=self.materials.mat, atlas=self.materials.atlas)
        return out

    @property
    def defines(self) -> dict:
        """``#define``s for shaders/common/scene_data.glsl. Flags are present only when true."""
        return self.accel.defines

    @property
    def uniforms(self) -> dict:
        """Uniform values by GLSL name (numpy arrays / Python scalars)."""
        return self.accel.uniforms

    @property
    def samplers(self) -> dict:
        """GLSL sampler uniform name of each texture."""
        return {name: f"hs_{name}_tex" for name in self.textures}

    @property
    def has_alpha(self) -> bool:
        """Some caster's material cuts its shadow: the traversal runs the any-hit alpha test."""
        return self.accel.has_alpha

    @property
    def has_meshes(self) -> bool:
        return self.accel.has_meshes

    @property
    def has_spheres(self) -> bool:
        return self.accel.has_spheres

    @property
    def stats(self) -> dict:
        """Bake timings, sizes, node counts, ... (:meth:`refresh_stats`)."""
        return self.accel.stats

    @property
    def texture_bytes(self) -> dict:
        return {k: t.nbytes for k, t in self.textures.items()}

    def refresh_stats(self) -> dict:
        """Recompute the derived entries of :attr:`stats` (the timings stay)."""
        stats = self.accel.refresh_stats()
        tex_bytes = self.texture_bytes
        stats.update({"origin": [float(x) for x in self.origin], "bytes": tex_bytes,
                      "total_bytes": int(sum(tex_bytes.values()))})
        return stats

    # -------------------------------------------------------------------------- debug ------
    def occupancy(self, points) -> np.ndarray:
        """(N,) float64: the structure's occupancy over world points ``points`` (N, >= 2) seen from
        above (:meth:`AccelerationStructure.occupancy`)."""
        xy = np.asarray(points, np.float64)[:, :2] - np.asarray(self.origin, np.float64)[:2]
        return self.accel.occupancy(xy)

    # ------------------------------------------------------------------ updates ------------
    def update_instances(self, scene, indices, progress: Progress | None = None) -> UpdateReport:
        """Instances ``indices`` moved (``scene.instances`` already holds their new matrices).
        ``progress``: as :func:`bake_scene`'s; stopped by it, the bake is half updated (drop it)."""
        return self._timed(progress, "Updating moved objects", self.accel.update_instances, scene, indices)

    def update_model(self, scene, model_id: int, progress: Progress | None = None) -> UpdateReport:
        """Mesh ``model_id`` was edited (or appended to ``scene.models``): rebuild that model's
        tree and triangles only, then re-place its instances (``progress``: as
        :meth:`update_instances`)."""
        return self._timed(progress, "Updating an edited model", self.accel.update_model, scene, model_id)

    def _timed(self, progress, label, update, *args) -> UpdateReport:
        t0 = time.perf_counter()
        with reporting(progress):
            stage(0, label)
            rep = update(*args)
        self.refresh_stats()
        rep.ms = (time.perf_counter() - t0) * 1e3
        self.stats["last_update_ms"] = rep.ms
        return rep


def bake_scene(scene, config: BakeConfig | None = None, progress: Progress | None = None) -> BakedScene:
    """Bake ``scene`` into GPU textures with the structure ``config.structure``. ``progress(done,
    total, label)`` is called through the bake's loops (:func:`..progress.checkpoint`); what it
    raises stops the bake, which then returns nothing."""
    cfg = config or BakeConfig()
    t0 = time.perf_counter()
    with reporting(progress, total=2):
        stage(0, "Baking materials")
        materials = bake_materials(scene, cfg.tex_width)
        origin = choose_origin(scene) if cfg.origin is None else np.asarray(cfg.origin, np.float64).reshape(3)
        stage(1, f"Baking the scene ({cfg.structure})")
        accel = structure_class(cfg.structure).bake(scene, cfg, origin, materials)
        baked = BakedScene(cfg, origin, accel, materials)
        accel.stats = {"bake_ms": (time.perf_counter() - t0) * 1e3, **accel.stats}
        baked.refresh_stats()
    return baked
