"""The thesis' hierarchical grid (structure ``"grid"``): a 2D grid of levels over the casters'
bounding spheres, each node listing its casters (crowded nodes with an object BVH over them),
over per-model BVHs and de-indexed triangles. Texel layouts: ``shaders/common/scene_grid.glsl``,
section names cited below as [grid], [grid_index], [object], [model], [bvh], [tri].

Crowded grid nodes (more than ``GridConfig.object_bvh_threshold`` objects) also get an *object BVH*
in [bvh] (after the model BVHs): a stackless tree over the bake-space boxes of their objects'
stored spheres, leaves of ``object_leaf_size`` consecutive [grid_index] entries (the node's list is
kept in the tree's Morton leaf order). ``place_object_bvhs`` (:mod:`.grid_update`) builds them,
vectorised over nodes.

Alpha-cut shadows (some caster's material cuts its shadow, ``Scene.alpha_models``): two more
textures, [uv] (the UVs of the alpha models' triangles, mirroring [tri]: ``UV_TEXELS`` per
triangle record) and [object_mat] (per instance 1 + its material when the walk must run the
any-hit alpha test on it, else 0), and ``HS_HAS_ALPHA``. Opaque scenes have neither.
"""
from __future__ import annotations

import time

import numpy as np

from ...limits import check_instance_count
from ...progress import checkpoint
from .. import grid as _grid
from ..bvh import build_bvhs
from ..materials import model_uvs
from ..textures import (
    BVH_TEXELS,
    EMPTY_HEIGHT,
    GRID_TEXELS,
    INDEX_TEXELS,
    MAX_ROWS_LOG2,
    MODEL_TEXELS,
    OBJECT_TEXELS,
    REL_EPS,
    SPHERE_FLAG,
    TRI_TEXELS,
    TextureData,
    f32_bits,
    f32_up,
    texel_rows,
)
from .base import AccelerationStructure
from .grid_state import UV_TEXELS, GridModels, GridState, InstanceState, TextureSet, new_texture
from .grid_update import GridUpdates


def stored_radius(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """World radius as stored/tested: enlarged so rounding never culls (float32, rounded up)."""
    return f32_up(r * (1.0 + REL_EPS) + REL_EPS * np.abs(c).max(axis=1) + 1e-30)


class HierarchicalGrid(GridUpdates, AccelerationStructure):
    """The hierarchical grid over per-model BVHs (see the module docstring)."""

    name = "grid"
    label = "Hierarchical Grid"
    description = "The thesis' hierarchical 2D grid over the instances, a BVH per model"
    glsl_include = "common/scene_grid.glsl"

    def __init__(self, config, origin, materials):
        super().__init__(config, origin, materials)
        self.tex: TextureSet = TextureSet.empty(config.tex_width)
        self.models: GridModels = GridModels.empty()
        self.instances: InstanceState = InstanceState.empty()
        self.grid: GridState = GridState.empty()

    @classmethod
    def bake(cls, scene, config, origin, materials) -> HierarchicalGrid:
        structure = cls(config, origin, materials)
        cfg = config
        tex = structure.tex
        n = len(scene.instances)
        check_instance_count(n)
        models = list(scene.models)
        m_count = len(models)

        # models: BVH + triangles, once per model ---------------------------------------------
        t_models = time.perf_counter()
        build = build_bvhs(models, cfg.grid.leaf_size)
        structure.models = GridModels.from_build(build)
        tex.bvh_tail = int(build.node_count.sum())
        tex.tri_tail = int(build.tri_count.sum())
        tex.model = new_texture("model", m_count * MODEL_TEXELS, cfg.tex_width)
        tex.bvh = new_texture("bvh", tex.bvh_tail * BVH_TEXELS, cfg.tex_width)
        tex.tri = new_texture("tri", tex.tri_tail * TRI_TEXELS, cfg.tex_width)
        if tex.bvh_tail:
            structure._write_bvh_block(build, 0, tex.bvh_tail, 0, tex.tri_tail, 0, 0)
        structure.write_models(np.arange(m_count), scene)
        if structure.materials is not None and structure.materials.cuts_shadows:
            uvm = scene.alpha_models()
            if uvm.any():  # alpha-cut shadows: [uv] mirrors [tri], [object_mat] below
                structure.models.uv = uvm.copy()
                tex.uv = new_texture("uv", tex.tri_tail * UV_TEXELS, cfg.tex_width)
                slots = structure.models
                for m in np.nonzero(uvm)[0].tolist():
                    checkpoint()
                    ts, tc = int(build.tri_start[m]), int(build.tri_count[m])
                    structure.write_model_uvs(scene, m, build.tri_src[ts:ts + tc], int(slots.tri_start[m]))
        t_bvh = time.perf_counter() - t_models

        # objects ------------------------------------------------------------------------------
        t_objects = time.perf_counter()
        structure.instances = InstanceState.empty(n)
        tex.object = new_texture("object", n * OBJECT_TEXELS, cfg.tex_width)
        if tex.uv is not None:
            tex.object_mat = new_texture("object_mat", n, cfg.tex_width)
        if n:
            structure.write_objects(scene, np.arange(n))
        t_obj = time.perf_counter() - t_objects

        # grid ---------------------------------------------------------------------------------
        t_grid0 = time.perf_counter()
        structure.build_grid(scene)
        t_grid = time.perf_counter() - t_grid0
        structure.stats = {
            "bvh_ms": t_bvh * 1e3,
            "objects_ms": t_obj * 1e3,
            "grid_ms": t_grid * 1e3,
        }
        return structure

    # ----------------------------------------------------------------------- read-outs --
    @property
    def textures(self) -> dict[str, TextureData]:
        return self.tex.as_dict()

    @property
    def has_alpha(self) -> bool:
        """(``HS_HAS_ALPHA``: the UVs are baked, and some mesh caster has triangles to test)."""
        return self.tex.uv is not None and self.has_meshes

    @property
    def layout(self) -> _grid.GridLayout:
        return self.grid.layout

    @property
    def defines(self) -> dict:
        """``#define``s for scene_grid.glsl. Flags are present only when true (``#ifdef``)."""
        w = self.config.tex_width
        d = {
            "HS_STRUCTURE_GRID": 1,
            "HS_GRID_LEVELS": int(self.layout.levels),
            "HS_TEX_WIDTH": int(w),
            "HS_TEX_WIDTH_LOG2": int(w).bit_length() - 1,
            "HS_TEX_ROWS_LOG2": MAX_ROWS_LOG2,
            "HS_BVH_LEAF_SIZE": int(self.config.grid.leaf_size),
        }
        if self.has_meshes:
            d["HS_HAS_MESHES"] = 1
        if self.has_spheres:
            d["HS_HAS_SPHERES"] = 1
        if (self.grid.obvh >= 0).any():
            d["HS_HAS_NODE_BVH"] = 1
        if self.has_alpha:
            d["HS_HAS_ALPHA"] = 1
        return d

    @property
    def uniforms(self) -> dict:
        """Uniform values by GLSL name (numpy arrays / Python scalars)."""
        lay = self.layout
        return {
            "hs_grid_origin": lay.origin.astype(np.float32),
            "hs_node_size": lay.node_sizes.astype(np.float32),
            "hs_level_dims": lay.dims.astype(np.int32),
            "hs_level_offset": lay.level_offset.astype(np.int32),
            "hs_level_count": self.grid.level_count.astype(np.int32),
            "hs_outside_node": int(lay.outside_node),
            "hs_scene_max_height": float(self.scene_max_height),
        }

    @property
    def has_meshes(self) -> bool:
        inst = self.instances
        c = inst.node >= 0
        if not c.any():
            return False
        tri = self.models.tri_count[inst.model[c]] > 0
        return bool((tri & ~inst.sphere[c]).any())

    @property
    def has_spheres(self) -> bool:
        return bool((self.instances.sphere & (self.instances.node >= 0)).any())

    @property
    def scene_max_height(self) -> float:
        nonempty = self.grid.count > 0
        if not nonempty.any():
            return float(EMPTY_HEIGHT)
        return float(self.grid.maxh[nonempty].max())

    def refresh_stats(self) -> dict:
        """Recompute the derived entries of :attr:`stats` (the timings stay)."""
        lay = self.layout
        counts = self.grid.count
        obvh = self.grid.obvh
        models = self.models
        s = self.stats
        s.update({
            "instances": int(len(self.instances)),
            "casters": int((self.instances.node >= 0).sum()),
            "models": int(len(models)),
            "triangles": int(models.tri_count.sum()),
            "bvh_nodes": int(models.node_count.sum()),
            "bvh_max_depth": int(models.depth.max()) if len(models.depth) else 0,
            "grid_levels": int(lay.levels),
            "grid_base_node_size": float(lay.base_size),
            "grid_origin": [float(x) for x in lay.origin],
            "grid_dims": lay.dims.tolist(),
            "grid_nodes": int(lay.n_nodes),
            "grid_nodes_nonempty": int((counts > 0).sum()),
            "objects_per_level": self.grid.level_count.tolist(),
            "outside_objects": int(counts[lay.outside_node]),
            "max_objects_per_node": int(counts.max()) if len(counts) else 0,
            "object_bvh_nodes": int((obvh >= 0).sum()),
            "object_bvh_objects": int(counts[obvh >= 0].sum()),
            "alpha_models": int(models.uv.sum()) if models.uv is not None else 0,  # UVs in [uv]
        })
        return s

    def occupancy(self, xy: np.ndarray) -> np.ndarray:
        """The casters held by the grid nodes of every level over each point, plus the outside
        node's (every ray tests those)."""
        lay, counts = self.layout, self.grid.count
        nodes = lay.nodes_at(np.asarray(xy, np.float64).reshape(-1, 2))  # (levels, N), -1 outside
        total = np.where(nodes >= 0, counts[np.maximum(nodes, 0)], 0).sum(axis=0, dtype=np.float64)
        return total + (counts[lay.outside_node] if lay.outside_node < len(counts) else 0)

    # ------------------------------------------------------------------ writers ------------
    def write_objects(self, scene, idx: np.ndarray) -> None:
        """[object] texels of instances ``idx`` (+ spheres kept for the grid), in bake space."""
        inst = scene.instances
        objects = self.instances
        c, r = scene.instance_spheres(idx)
        c = c - self.origin
        rs = stored_radius(c, r)
        objects.center[idx] = c
        objects.radius[idx] = r
        objects.top[idx] = c[:, 2] + rs
        rec = self.tex.object.records(OBJECT_TEXELS)
        block = np.empty((len(idx), 16), np.float32)
        inv = inst.inverse[idx, :3, :].copy()  # world -> model, then bake space -> model:
        inv[:, :, 3] += inv[:, :, :3] @ self.origin  # M^-1 T(origin), in float64
        block[:, 0:12] = inv.reshape(len(idx), 12)
        block[:, 12:15] = c
        block[:, 15] = rs
        rec[idx] = block
        objects.model[idx] = inst.model_ids[idx]
        objects.sphere[idx] = inst.sphere[idx]
        if self.tex.object_mat is not None:
            self.tex.object_mat.linear()[idx, 0] = self.alpha_slots(scene, idx)

    # ------------------------------------------------------------------ alpha-cut shadows --
    def alpha_slots(self, scene, idx: np.ndarray) -> np.ndarray:
        """[object_mat] of instances ``idx``: 1 + material index when the instance's material
        cuts its shadow and its model's UVs are in [uv] (never for analytic spheres), else 0."""
        inst = scene.instances
        idx = np.asarray(idx, np.int64)
        slot = self.materials.instance_slots(inst.material_ids[idx])
        mid = inst.model_ids[idx]
        ok = self.models.uv[mid] & ~inst.sphere[idx]
        return np.where(ok, slot, 0).astype(np.uint32)

    def write_model_uvs(self, scene, m: int, tri_src: np.ndarray, tri_base: int) -> None:
        """[uv] records of model ``m`` at [tri] records ``tri_base ..``: its UVs in the stored
        triangle order ``tri_src`` (``BVHBuild.tri_src``), zeros when its UVs are not kept."""
        tc = len(tri_src)
        block = np.zeros((tc, UV_TEXELS * 4), np.float32)
        if self.models.uv[m] and tc:
            block[:, :6] = model_uvs(scene.models[m])[np.asarray(tri_src, np.int64)].reshape(tc, 6)
        self.tex.uv.records(UV_TEXELS)[tri_base:tri_base + tc] = block

    def ensure_model_uvs(self, scene, idx: np.ndarray) -> list:
        """Instances ``idx`` may have been given an alpha-cut material since the bake: store the
        UVs of their models that [uv] lacks (their triangles as stored: the model BVH built
        again gives the same order). Returns the [uv] row ranges written."""
        if self.tex.uv is None or self.materials is None:
            return []
        inst = scene.instances
        idx = np.asarray(idx, np.int64)
        slot = self.materials.instance_slots(inst.material_ids[idx])
        mid = inst.model_ids[idx]
        need = np.unique(mid[(slot > 0) & ~inst.sphere[idx] & ~self.models.uv[mid]])
        ranges = []
        w = self.config.tex_width
        for m in need.tolist():
            self.models.uv[m] = True
            tc = int(self.models.tri_count[m])
            if not tc:
                continue
            src = build_bvhs([scene.models[m]], self.config.grid.leaf_size).tri_src
            t0 = int(self.models.tri_start[m])
            self.write_model_uvs(scene, m, src, t0)
            ranges += texel_rows("uv", t0 * UV_TEXELS, (t0 + tc) * UV_TEXELS, w)
        return ranges

    def index_code(self, obj: np.ndarray) -> np.ndarray:
        objects = self.instances
        return objects.model[obj].astype(np.uint32) | np.where(objects.sphere[obj], SPHERE_FLAG, np.uint32(0))

    def write_nodes(self, nodes: np.ndarray) -> None:
        """[grid] texels of global node ids ``nodes`` from the node arrays."""
        grid = self.grid
        lin = self.tex.grid.linear()
        lin[nodes, 0] = grid.offset[nodes]
        lin[nodes, 1] = grid.count[nodes]
        mh = np.where(grid.count[nodes] > 0, grid.maxh[nodes], 0.0)
        h = np.where(grid.count[nodes] > 0, f32_up(mh + REL_EPS * np.abs(mh)), EMPTY_HEIGHT)
        lin[nodes, 2] = f32_bits(h)
        lin[nodes, 3] = np.where(grid.obvh[nodes] >= 0, grid.obvh[nodes] + 1, 0)

    def write_models(self, ids: np.ndarray, scene) -> None:
        """[model] texels of model ids ``ids``."""
        slots = self.models
        rec = self.tex.model.records(MODEL_TEXELS)
        for m in np.asarray(ids).tolist():
            model = scene.models[m]
            sph = np.array([*model.sphere_center, model.sphere_radius], np.float64)
            s = np.concatenate([sph[:3].astype(np.float32), f32_up(sph[3:])])
            rec[m, 0:4] = f32_bits(s)
            rec[m, 4:8] = [slots.node_start[m], slots.node_count[m], slots.tri_start[m], slots.tri_count[m]]

    def write_bvh(self, build, node_base: int, tri_base: int, local_model: int) -> None:
        """[bvh] and [tri] records of one model of ``build`` at absolute ``node_base``/``tri_base``."""
        ns, nc = int(build.node_start[local_model]), int(build.node_count[local_model])
        ts, tc = int(build.tri_start[local_model]), int(build.tri_count[local_model])
        self._write_bvh_block(build, ns, nc, ts, tc, node_base, tri_base)

    def _write_bvh_block(self, build, ns, nc, ts, tc, node_base, tri_base) -> None:
        sl = slice(ns, ns + nc)
        rec = self.tex.bvh.records(BVH_TEXELS)
        block = np.empty((nc, 8), np.uint32)
        block[:, 0:3] = f32_bits(build.node_min[sl])
        block[:, 3] = build.escape[sl] - ns + node_base
        block[:, 4:7] = f32_bits(build.node_max[sl])
        lc = build.leaf_count[sl]
        block[:, 7] = np.where(lc > 0, ((build.leaf_start[sl] - ts + tri_base) << 3) | lc, 0)
        rec[node_base:node_base + nc] = block
        trec = self.tex.tri.records(TRI_TEXELS)
        trec[tri_base:tri_base + tc] = build.tris[ts:ts + tc].reshape(tc, 9)

    # ------------------------------------------------------------------ grid ---------------
    def build_grid(self, scene) -> None:
        """(Re)build the grid and its index list from the instance spheres."""
        cfg, objects, tex = self.config, self.instances, self.tex
        casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else np.zeros(0, np.int64)
        lay = _grid.plan_grid(objects.center[casters], objects.radius[casters], cfg.grid.base_node_size,
                              cfg.grid.max_level0_nodes)
        node = _grid.place(lay, objects.center[casters], objects.radius[casters])
        n_nodes = lay.n_nodes
        counts = np.bincount(node, minlength=n_nodes).astype(np.int64)
        cap = _grid.node_capacity(counts, cfg.grid.index_slack)
        offset = np.concatenate([[0], np.cumsum(cap)[:-1]]).astype(np.int64)
        used = int(cap.sum())
        order = np.argsort(node, kind="stable")
        sn = node[order]
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(len(sn)) - first[sn]
        slot = offset[sn] + rank
        objects.node[:] = -1
        objects.slot[:] = -1
        objects.node[casters[order]] = sn
        objects.slot[casters[order]] = slot
        maxh = np.full(n_nodes, -np.inf)
        if len(sn):
            starts = np.nonzero(np.concatenate([[True], sn[1:] != sn[:-1]]))[0]
            maxh[sn[starts]] = np.maximum.reduceat(objects.top[casters[order]], starts)
        level_count = np.bincount(lay.node_level(node), minlength=lay.levels + 1)[: lay.levels].astype(np.int64)
        # object BVHs of crowded nodes: one contiguous [bvh] region after the model BVHs (every
        # [bvh] record past the last model allocation belonged to the previous grid: reclaimed)
        ends = self.models.node_start + self.models.node_cap
        tex.bvh_tail = int(ends.max()) if ends.size else 0
        region0 = tex.bvh_tail
        self.grid = grid = GridState(
            layout=lay, count=counts, cap=cap, offset=offset, maxh=maxh,
            obvh=np.full(n_nodes, -1, np.int64), obvh_start=np.zeros(n_nodes, np.int64),
            obvh_cap=np.zeros(n_nodes, np.int64), level_count=level_count, index_tail=used)
        obj = casters[order]
        obj, _, grid.bvh_grown = self.place_object_bvhs(np.arange(n_nodes), first, counts, obj,
                                                     reserve=cfg.grid.index_reserve)
        grid.bvh_range = (region0, tex.bvh_tail)  # [bvh] records written (for regrid reports)
        tex.bvh.used = tex.bvh_tail * BVH_TEXELS
        if obj.size:
            objects.slot[obj] = slot
        reserve = max(1024, int(used * cfg.grid.index_reserve))
        tex.grid = new_texture("grid", n_nodes * GRID_TEXELS, cfg.tex_width)
        tex.grid_index = new_texture("grid_index", (used + reserve) * INDEX_TEXELS, cfg.tex_width)
        tex.grid_index.used = used
        self.write_nodes(np.arange(n_nodes))
        lin = tex.grid_index.linear()
        lin[slot, 0] = obj
        lin[slot, 1] = self.index_code(obj)
