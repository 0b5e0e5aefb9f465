"""The full bake: Scene -> BakedScene (textures + defines + uniforms + stats).

Texel layouts: ``shaders/common/scene_data.glsl`` ("SCENE TEXTURE LAYOUT"), section names cited
below as [grid], [grid_index], [object], [model], [bvh], [tri].

Crowded grid nodes (more than ``BakeConfig.object_bvh_threshold`` objects) also get an *object BVH*
in [bvh] (after the model BVHs): a stackless tree over the bake-space boxes of their objects'
stored spheres, leaves of ``object_leaf_size`` consecutive [grid_index] entries (the node's list is
kept in the tree's Morton leaf order). ``place_object_bvhs`` builds them, vectorised over nodes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from . import grid as _grid
from .bvh import build_bvhs, build_trees, morton_order_groups
from .textures import (BVH_TEXELS, EMPTY_HEIGHT, GRID_TEXELS, INDEX_TEXELS, MAX_ROWS_LOG2, MODEL_TEXELS,
                       OBJECT_TEXELS, SPHERE_FLAG, TRI_TEXELS, TextureData, alloc_texture, f32_bits, f32_down, f32_up,
                       grow_texture)

REL_EPS = 2.0 ** -20
TEXTURE_NAMES = ("grid", "grid_index", "object", "model", "bvh", "tri")


@dataclass
class BakeConfig:
    tex_width: int = 4096  # power of two <= 16384; every texture wraps its rows at this width
    base_node_size: Optional[float] = None  # level-0 node size (m); None: fit to the scene
    max_level0_nodes: Optional[int] = None  # None: 4 * casters (at least 64, at most 4M)
    leaf_size: int = 4  # triangles per BVH leaf (1..7)
    index_slack: float = 0.25  # spare slots per grid node, as a fraction of its count (+1)
    index_reserve: float = 0.25  # spare tail of the grid index list, fraction of its length
    outside_rebake_fraction: float = 0.01  # regrid when more casters than this left the grid
    origin: Optional[tuple] = None  # bake-space origin in world space; None: choose_origin()
    object_bvh_threshold: int = 32  # nodes with more objects than this get an object BVH
    object_leaf_size: int = 4  # grid-index entries per object-BVH leaf (1..7)

    def __post_init__(self):
        w = int(self.tex_width)
        if w < 4 or w > 16384 or w & (w - 1):
            raise ValueError("tex_width must be a power of two between 4 and 16384")
        if not 1 <= int(self.leaf_size) <= 7:
            raise ValueError("leaf_size must be 1..7")
        if not 1 <= int(self.object_leaf_size) <= 7:
            raise ValueError("object_leaf_size must be 1..7")
        if int(self.object_bvh_threshold) < 1:
            raise ValueError("object_bvh_threshold must be >= 1")


@dataclass
class UpdateReport:
    """What an incremental update changed, for partial re-uploads.

    ``ranges``: ``(texture_name, layer, y0, y1)`` row ranges (y1 exclusive) whose texels changed;
    ``resized``: textures whose shape changed (re-create and upload whole; their rows are not
    listed); ``uniforms_changed`` / ``defines_changed``: re-read ``BakedScene.uniforms`` /
    ``.defines`` (defines mean recompiling the program); ``regrid``: the grid was rebuilt.
    """

    ranges: list = field(default_factory=list)
    resized: set = field(default_factory=set)
    uniforms_changed: bool = False
    defines_changed: bool = False
    regrid: bool = False
    objects: int = 0
    nodes_changed: int = 0
    ms: float = 0.0

    def texels_changed(self, baked: "BakedScene") -> int:
        n = 0
        for name, _layer, y0, y1 in self.ranges:
            n += (y1 - y0) * baked.textures[name].width
        return n

    def merge(self, other: "UpdateReport") -> "UpdateReport":
        from .textures import merge_ranges

        self.ranges = merge_ranges(self.ranges + other.ranges)
        self.resized |= other.resized
        self.uniforms_changed |= other.uniforms_changed
        self.defines_changed |= other.defines_changed
        self.regrid |= other.regrid
        self.objects += other.objects
        self.nodes_changed += other.nodes_changed
        return self


def instance_spheres(scene, idx=None):
    """World bounding spheres (float64) of instances ``idx`` (all when None): centres, radii.
    Same maths as ``Scene.instance_spheres`` but for a subset."""
    inst = scene.instances
    if idx is None:
        idx = np.arange(len(inst))
    if len(idx) == 0 or not scene.models:
        return np.zeros((len(idx), 3)), np.zeros(len(idx))
    centers_m = np.array([m.sphere_center for m in scene.models], np.float64).reshape(-1, 3)
    radii_m = np.array([m.sphere_radius for m in scene.models], np.float64)
    mid = inst.model_ids[idx]
    M = inst.matrices[idx]
    c = np.einsum("nij,nj->ni", M[:, :3, :3], centers_m[mid]) + M[:, :3, 3]
    scale = np.sqrt((M[:, :3, :3] ** 2).sum(axis=1)).max(axis=1)
    return c, radii_m[mid] * scale


def choose_origin(scene) -> np.ndarray:
    """The bake-space origin: world zero, unless the casters sit farther from it than their own
    extent — then a nearby round point (a multiple of a power of two near the extent), so that
    float32 coordinates keep their precision 100 km out as well as at home."""
    casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else []
    if len(casters) == 0:
        return np.zeros(3)
    c, r = instance_spheres(scene, casters)
    lo, hi = (c - r[:, None]).min(axis=0), (c + r[:, None]).max(axis=0)
    center, extent = (lo + hi) / 2, float((hi - lo).max())
    if not np.isfinite(center).all() or np.abs(center).max() <= max(extent, 1.0):
        return np.zeros(3)
    q = 2.0 ** np.ceil(np.log2(max(extent, 1.0)))
    return np.round(center / q) * q


def stored_radius(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """World radius as stored/tested: enlarged so rounding never culls (float32, rounded up)."""
    return f32_up(r * (1.0 + REL_EPS) + REL_EPS * np.abs(c).max(axis=1) + 1e-30)


class BakedScene:
    """All GPU-ready scene data. Build with :func:`bake_scene`."""

    def __init__(self, config: BakeConfig):
        self.config = config
        # bake space = world - origin (float64 on the CPU): every texture and uniform is in it
        self.origin = np.zeros(3)
        self.textures: dict[str, TextureData] = {}
        self.layout: _grid.GridLayout = None
        self.stats: dict = {}

    # ------------------------------------------------------------------ public read-outs --
    @property
    def defines(self) -> dict:
        """``#define``s for scene_data.glsl. Flags are present only when true (``#ifdef``)."""
        w = self.config.tex_width
        d = {
            "HS_GRID_LEVELS": int(self.layout.levels),
            "HS_TEX_WIDTH": int(w),
            "HS_TEX_WIDTH_LOG2": int(w).bit_length() - 1,
            "HS_TEX_ROWS_LOG2": MAX_ROWS_LOG2,
            "HS_BVH_LEAF_SIZE": int(self.config.leaf_size),
        }
        if self.has_meshes:
            d["HS_HAS_MESHES"] = 1
        if self.has_spheres:
            d["HS_HAS_SPHERES"] = 1
        if (self.node_obvh >= 0).any():
            d["HS_HAS_NODE_BVH"] = 1
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
            "hs_level_count": self.level_count.astype(np.int32),
            "hs_outside_node": int(lay.outside_node),
            "hs_scene_max_height": float(self.scene_max_height),
        }

    @property
    def samplers(self) -> dict:
        """GLSL sampler uniform name of each texture."""
        return {name: f"hs_{name}_tex" for name in TEXTURE_NAMES}

    @property
    def has_meshes(self) -> bool:
        c = self.inst_node >= 0
        if not c.any():
            return False
        tri = self.model_tri_count[self.inst_model[c]] > 0
        return bool((tri & ~self.inst_sphere[c]).any())

    @property
    def has_spheres(self) -> bool:
        return bool((self.inst_sphere & (self.inst_node >= 0)).any())

    @property
    def scene_max_height(self) -> float:
        nonempty = self.node_count > 0
        if not nonempty.any():
            return float(EMPTY_HEIGHT)
        return float(self.node_maxh[nonempty].max())

    @property
    def texture_bytes(self) -> dict:
        return {k: t.nbytes for k, t in self.textures.items()}

    # ------------------------------------------------------------------ updates ------------
    def update_instances(self, scene, indices) -> UpdateReport:
        """Instances ``indices`` moved (``scene.instances`` already holds their new matrices)."""
        from .update import update_instances

        return update_instances(self, scene, indices)

    def update_model(self, scene, model_id: int) -> UpdateReport:
        """Mesh ``model_id`` was edited (or appended to ``scene.models``): rebuild that model's
        BVH and triangles only, then re-place its instances."""
        from .update import update_model

        return update_model(self, scene, model_id)

    # ------------------------------------------------------------------ writers ------------
    def write_objects(self, scene, idx: np.ndarray) -> None:
        """[object] texels of instances ``idx`` (+ spheres kept for the grid), in bake space."""
        inst = scene.instances
        c, r = instance_spheres(scene, idx)
        c = c - self.origin
        rs = stored_radius(c, r)
        self.inst_center[idx] = c
        self.inst_radius[idx] = r
        self.inst_top[idx] = c[:, 2] + rs
        rec = self.textures["object"].records(OBJECT_TEXELS)
        block = np.empty((len(idx), 16), np.float32)
        inv = inst.inverse[idx, :3, :].copy()  # world -> model, then bake space -> model:
        inv[:, :, 3] += inv[:, :, :3] @ self.origin  # M^-1 T(origin), in float64
        block[:, 0:12] = inv.reshape(len(idx), 12)
        block[:, 12:15] = c
        block[:, 15] = rs
        rec[idx] = block
        self.inst_model[idx] = inst.model_ids[idx]
        self.inst_sphere[idx] = inst.sphere[idx]

    def index_code(self, obj: np.ndarray) -> np.ndarray:
        return self.inst_model[obj].astype(np.uint32) | np.where(self.inst_sphere[obj], SPHERE_FLAG, np.uint32(0))

    def write_nodes(self, nodes: np.ndarray) -> None:
        """[grid] texels of global node ids ``nodes`` from the node arrays."""
        lin = self.textures["grid"].linear()
        lin[nodes, 0] = self.node_offset[nodes]
        lin[nodes, 1] = self.node_count[nodes]
        mh = np.where(self.node_count[nodes] > 0, self.node_maxh[nodes], 0.0)
        h = np.where(self.node_count[nodes] > 0, f32_up(mh + REL_EPS * np.abs(mh)), EMPTY_HEIGHT)
        lin[nodes, 2] = f32_bits(h)
        lin[nodes, 3] = np.where(self.node_obvh[nodes] >= 0, self.node_obvh[nodes] + 1, 0)

    def obvh_nodes_for(self, n) -> np.ndarray:
        """Object-BVH tree nodes for ``n`` objects (balanced tree over ceil(n / leaf) leaves)."""
        leaves = -(-np.asarray(n, np.int64) // int(self.config.object_leaf_size))
        return np.where(leaves > 0, 2 * leaves - 1, 0)

    def place_object_bvhs(self, nodes, first, cnt, ent_obj, reserve: float = 0.25):
        """Object BVHs of grid ``nodes``: node ``nodes[k]`` holds ``ent_obj[first[k]:first[k] +
        cnt[k]]`` in slot order (slots ``node_offset + rank``; offsets already final). Crowded nodes
        (count > threshold) get their entries reordered into Morton order (returned as a new
        ``ent_obj``) and their tree built and written to [bvh], in place when it fits the node's
        allocation, else at the [bvh] tail; the others get none (flat list). Vectorised over all
        nodes. Returns ``(ent_obj, (starts, counts), grown)``: the [bvh] record ranges written and
        whether the texture was resized. The caller writes the [grid] texels (``write_nodes``).
        ``reserve``: when the texture grows, spare records as a fraction of the new trees."""
        nodes = np.asarray(nodes, np.int64)
        crowd = np.asarray(cnt) > int(self.config.object_bvh_threshold)
        self.node_obvh[nodes[~crowd]] = -1
        none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if not crowd.any():
            return ent_obj, none, False
        cn = nodes[crowd]
        cf = np.asarray(first, np.int64)[crowd]
        cc = np.asarray(cnt, np.int64)[crowd]
        istart = np.concatenate([[0], np.cumsum(cc)[:-1]]).astype(np.int64)
        owner = np.repeat(np.arange(cn.size), cc)
        items = cf[owner] + np.arange(int(cc.sum())) - istart[owner]  # positions in ent_obj
        obj = ent_obj[items]
        obj = obj[morton_order_groups(self.inst_center[obj], istart, cc)]
        ent_obj = ent_obj.copy()
        ent_obj[items] = obj
        # item boxes: the stored (float32) sphere of each object, rounded outward
        rec = self.textures["object"].records(OBJECT_TEXELS)[obj]
        c = rec[:, 12:15].astype(np.float64)
        r = rec[:, 15:16].astype(np.float64)
        lo, hi = f32_down(c - r), f32_up(c + r)
        nmin, nmax, esc, lstart, lcount, nstart, ncount, _ = build_trees(
            lo, hi, istart, cc, int(self.config.object_leaf_size))
        # allocation: in place when the node's previous allocation is large enough
        fits = ncount <= self.node_obvh_cap[cn]
        grown = False
        if (~fits).any():
            cap = self.obvh_nodes_for(np.maximum(self.node_cap[cn[~fits]], cc[~fits]))
            self.node_obvh_start[cn[~fits]] = self.bvh_tail + np.concatenate([[0], np.cumsum(cap)[:-1]])
            self.node_obvh_cap[cn[~fits]] = cap
            self.bvh_tail += int(cap.sum())
            if self.bvh_tail * BVH_TEXELS > self.textures["bvh"].capacity:
                spare = int(reserve * cap.sum()) + 1024
                grown = grow_texture(self.textures["bvh"], (self.bvh_tail + spare) * BVH_TEXELS, slack=0.0)
            self.textures["bvh"].used = self.bvh_tail * BVH_TEXELS
        base = self.node_obvh_start[cn]
        towner = np.repeat(np.arange(cn.size), ncount)
        shift = base[towner] - nstart[towner]  # local tree node -> absolute [bvh] record
        block = np.empty((len(esc), 8), np.uint32)
        block[:, 0:3] = f32_bits(nmin)
        block[:, 3] = esc + shift
        block[:, 4:7] = f32_bits(nmax)
        slot = self.node_offset[cn][towner] + (lstart - istart[towner])
        block[:, 7] = np.where(lcount > 0, (slot << 3) | lcount, 0)
        self.textures["bvh"].records(BVH_TEXELS)[np.arange(len(esc)) + shift] = block
        self.node_obvh[cn] = base
        return ent_obj, (base, ncount), grown

    def write_models(self, ids: np.ndarray, scene) -> None:
        """[model] texels of model ids ``ids``."""
        rec = self.textures["model"].records(MODEL_TEXELS)
        for m in np.asarray(ids).tolist():
            model = scene.models[m]
            sph = np.array([*model.sphere_center, model.sphere_radius], np.float64)
            s = np.concatenate([sph[:3].astype(np.float32), f32_up(sph[3:])])
            rec[m, 0:4] = f32_bits(s)
            rec[m, 4:8] = [self.model_node_start[m], self.model_node_count[m],
                           self.model_tri_start[m], self.model_tri_count[m]]

    def write_bvh(self, build, node_base: int, tri_base: int, local_model: int) -> None:
        """[bvh] and [tri] records of one model of ``build`` at absolute ``node_base``/``tri_base``."""
        ns, nc = int(build.node_start[local_model]), int(build.node_count[local_model])
        ts, tc = int(build.tri_start[local_model]), int(build.tri_count[local_model])
        self._write_bvh_block(build, ns, nc, ts, tc, node_base, tri_base)

    def _write_bvh_block(self, build, ns, nc, ts, tc, node_base, tri_base) -> None:
        sl = slice(ns, ns + nc)
        rec = self.textures["bvh"].records(BVH_TEXELS)
        block = np.empty((nc, 8), np.uint32)
        block[:, 0:3] = f32_bits(build.node_min[sl])
        block[:, 3] = build.escape[sl] - ns + node_base
        block[:, 4:7] = f32_bits(build.node_max[sl])
        lc = build.leaf_count[sl]
        block[:, 7] = np.where(lc > 0, ((build.leaf_start[sl] - ts + tri_base) << 3) | lc, 0)
        rec[node_base:node_base + nc] = block
        trec = self.textures["tri"].records(TRI_TEXELS)
        trec[tri_base:tri_base + tc] = build.tris[ts:ts + tc].reshape(tc, 9)

    # ------------------------------------------------------------------ grid ---------------
    def build_grid(self, scene) -> None:
        """(Re)build the grid and its index list from the instance spheres."""
        cfg = self.config
        casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else np.zeros(0, np.int64)
        self.layout = lay = _grid.plan_grid(self.inst_center[casters], self.inst_radius[casters],
                                            cfg.base_node_size, cfg.max_level0_nodes)
        node = _grid.place(lay, self.inst_center[casters], self.inst_radius[casters])
        n_nodes = lay.n_nodes
        counts = np.bincount(node, minlength=n_nodes).astype(np.int64)
        cap = _grid.node_capacity(counts, cfg.index_slack)
        offset = np.concatenate([[0], np.cumsum(cap)[:-1]]).astype(np.int64)
        used = int(cap.sum())
        order = np.argsort(node, kind="stable")
        sn = node[order]
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(len(sn)) - first[sn]
        slot = offset[sn] + rank
        self.inst_node[:] = -1
        self.inst_slot[:] = -1
        self.inst_node[casters[order]] = sn
        self.inst_slot[casters[order]] = slot
        self.node_count, self.node_cap, self.node_offset = counts, cap, offset
        maxh = np.full(n_nodes, -np.inf)
        if len(sn):
            starts = np.nonzero(np.concatenate([[True], sn[1:] != sn[:-1]]))[0]
            maxh[sn[starts]] = np.maximum.reduceat(self.inst_top[casters[order]], starts)
        self.node_maxh = maxh
        self.level_count = np.bincount(lay.node_level(node), minlength=lay.levels + 1)[: lay.levels].astype(np.int64)
        self.index_tail = used
        # object BVHs of crowded nodes: one contiguous [bvh] region after the model BVHs (every
        # [bvh] record past the last model allocation belonged to the previous grid: reclaimed)
        ends = self.model_node_start + self.model_node_cap
        self.bvh_tail = int(ends.max()) if ends.size else 0
        region0 = self.bvh_tail
        self.node_obvh = np.full(n_nodes, -1, np.int64)
        self.node_obvh_start = np.zeros(n_nodes, np.int64)
        self.node_obvh_cap = np.zeros(n_nodes, np.int64)
        obj = casters[order]
        obj, _, self.grid_bvh_grown = self.place_object_bvhs(np.arange(n_nodes), first, counts, obj,
                                                             reserve=cfg.index_reserve)
        self.grid_bvh_range = (region0, self.bvh_tail)  # [bvh] records written (for regrid reports)
        self.textures["bvh"].used = self.bvh_tail * BVH_TEXELS
        if obj.size:
            self.inst_slot[obj] = slot
        reserve = max(1024, int(used * cfg.index_reserve))
        self.textures["grid"] = alloc_texture("grid", n_nodes * GRID_TEXELS, 4, "u4", cfg.tex_width)
        self.textures["grid_index"] = alloc_texture("grid_index", (used + reserve) * INDEX_TEXELS, 2, "u4", cfg.tex_width)
        self.textures["grid_index"].used = used
        self.write_nodes(np.arange(n_nodes))
        lin = self.textures["grid_index"].linear()
        lin[slot, 0] = obj
        lin[slot, 1] = self.index_code(obj)


def bake_scene(scene, config: BakeConfig | None = None) -> BakedScene:
    """Bake ``scene`` into GPU textures (see scene_data.glsl for every texel)."""
    cfg = config or BakeConfig()
    t0 = time.perf_counter()
    b = BakedScene(cfg)
    inst = scene.instances
    n = len(inst)
    models = list(scene.models)
    m_count = len(models)

    # models: BVH + triangles, once per model ---------------------------------------------
    tb = time.perf_counter()
    build = build_bvhs(models, cfg.leaf_size)
    b.model_node_start = build.node_start.copy()
    b.model_node_count = build.node_count.copy()
    b.model_tri_start = build.tri_start.copy()
    b.model_tri_count = build.tri_count.copy()
    b.model_node_cap = build.node_count.copy()
    b.model_tri_cap = build.tri_count.copy()
    b.bvh_tail = int(build.node_count.sum())
    b.tri_tail = int(build.tri_count.sum())
    b.model_depth = build.depth.copy()
    b.textures["model"] = alloc_texture("model", m_count * MODEL_TEXELS, 4, "u4", cfg.tex_width)
    b.textures["bvh"] = alloc_texture("bvh", b.bvh_tail * BVH_TEXELS, 4, "u4", cfg.tex_width)
    b.textures["tri"] = alloc_texture("tri", b.tri_tail * TRI_TEXELS, 3, "f4", cfg.tex_width)
    if b.bvh_tail:
        b._write_bvh_block(build, 0, b.bvh_tail, 0, b.tri_tail, 0, 0)
    b.write_models(np.arange(m_count), scene)
    t_bvh = time.perf_counter() - tb

    # objects ------------------------------------------------------------------------------
    to = time.perf_counter()
    b.inst_center = np.zeros((n, 3))
    b.inst_radius = np.zeros(n)
    b.inst_top = np.zeros(n)
    b.inst_model = np.zeros(n, np.int64)
    b.inst_sphere = np.zeros(n, bool)
    b.inst_node = np.full(n, -1, np.int64)
    b.inst_slot = np.full(n, -1, np.int64)
    b.textures["object"] = alloc_texture("object", n * OBJECT_TEXELS, 4, "f4", cfg.tex_width)
    b.origin = choose_origin(scene) if cfg.origin is None else np.asarray(cfg.origin, np.float64).reshape(3)
    if n:
        b.write_objects(scene, np.arange(n))
    t_obj = time.perf_counter() - to

    # grid ---------------------------------------------------------------------------------
    tg = time.perf_counter()
    b.build_grid(scene)
    t_grid = time.perf_counter() - tg
    b.textures = {k: b.textures[k] for k in TEXTURE_NAMES}
    b.stats = {
        "bake_ms": (time.perf_counter() - t0) * 1e3,
        "bvh_ms": t_bvh * 1e3,
        "objects_ms": t_obj * 1e3,
        "grid_ms": t_grid * 1e3,
    }
    refresh_stats(b)
    return b


def refresh_stats(b: BakedScene) -> dict:
    lay = b.layout
    counts = b.node_count
    s = b.stats
    s.update({
        "instances": int(len(b.inst_node)),
        "casters": int((b.inst_node >= 0).sum()),
        "models": int(len(b.model_node_count)),
        "triangles": int(b.model_tri_count.sum()),
        "bvh_nodes": int(b.model_node_count.sum()),
        "bvh_max_depth": int(b.model_depth.max()) if len(b.model_depth) else 0,
        "grid_levels": int(lay.levels),
        "grid_base_node_size": float(lay.base_size),
        "origin": [float(x) for x in b.origin],
        "grid_origin": [float(x) for x in lay.origin],
        "grid_dims": lay.dims.tolist(),
        "grid_nodes": int(lay.n_nodes),
        "grid_nodes_nonempty": int((counts > 0).sum()),
        "objects_per_level": b.level_count.tolist(),
        "outside_objects": int(counts[lay.outside_node]),
        "max_objects_per_node": int(counts.max()) if len(counts) else 0,
        "object_bvh_nodes": int((b.node_obvh >= 0).sum()),
        "object_bvh_objects": int(counts[b.node_obvh >= 0].sum()),
        "bytes": b.texture_bytes,
        "total_bytes": int(sum(b.texture_bytes.values())),
    })
    return s
