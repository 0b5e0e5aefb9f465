"""The full bake: Scene -> BakedScene (textures + defines + uniforms + stats).

Texel layouts: ``shaders/common/scene_data.glsl`` ("SCENE TEXTURE LAYOUT"), section names cited
below as [grid], [grid_index], [object], [model], [bvh], [tri]. The state a bake keeps is declared
in ``state.py``; incremental updates are in ``update.py``.

Crowded grid nodes (more than ``BakeConfig.object_bvh_threshold`` objects) also get an *object BVH*
in [bvh] (after the model BVHs): a stackless tree over the bake-space boxes of their objects'
stored spheres, leaves of ``object_leaf_size`` consecutive [grid_index] entries (the node's list is
kept in the tree's Morton leaf order). ``place_object_bvhs`` builds them, vectorised over nodes.

Alpha-cut shadows (some caster's material cuts its shadow, ``Scene.alpha_models``): two more
textures, [uv] (the UVs of the alpha models' triangles, mirroring [tri]: ``UV_TEXELS`` per
triangle record) and [object_mat] (per instance 1 + its material when the walk must run the
any-hit alpha test on it, else 0), and ``HS_HAS_ALPHA``. Opaque scenes have neither.
"""
from __future__ import annotations

import time

import numpy as np

from . import grid as _grid
from . import twolevel as _twolevel
from . import update as _update
from .bvh import build_bvhs, build_trees, morton_order_groups
from .state import (UV_TEXELS, BakeConfig, GridState, InstanceState, ModelState, TextureSet, UpdateReport,
                    new_texture)
from .materials import MaterialBake, bake_materials, model_uvs
from .textures import (BVH_TEXELS, EMPTY_HEIGHT, GRID_TEXELS, INDEX_TEXELS, MAX_ROWS_LOG2, MODEL_TEXELS,
                       OBJECT_TEXELS, REL_EPS, SPHERE_FLAG, TRI_TEXELS, TextureData, f32_bits, f32_down, f32_up,
                       grow_texture, texel_rows)


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


def stored_radius(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """World radius as stored/tested: enlarged so rounding never culls (float32, rounded up)."""
    return f32_up(r * (1.0 + REL_EPS) + REL_EPS * np.abs(c).max(axis=1) + 1e-30)


class BakedScene:
    """All GPU-ready scene data. Build with :func:`bake_scene`."""

    def __init__(self, config: BakeConfig):
        self.config: BakeConfig = config
        #: bake space = world - origin (float64 on the CPU): every texture and uniform is in it
        self.origin: np.ndarray = np.zeros(3)
        self.tex: TextureSet = TextureSet.empty(config.tex_width)
        self.models: ModelState = ModelState.empty()
        self.instances: InstanceState = InstanceState.empty()
        self.grid: GridState = GridState.empty()
        #: the two-level BVH (``structure == "bvh"``), else None
        self.bvh: _twolevel.TwoLevelState | None = None
        #: textured / alpha-cut materials (atlas + records), None when the scene has none
        self.materials: MaterialBake | None = None
        self.stats: dict = {}

    @property
    def structure(self) -> str:
        return self.config.structure

    # ------------------------------------------------------------------ public read-outs --
    @property
    def textures(self) -> dict[str, TextureData]:
        """Every texture by name, in upload order."""
        out = self.bvh.textures() if self.bvh is not None else self.tex.as_dict()
        if self.materials is not None:
            out = dict(out, mat=self.materials.mat, atlas=self.materials.atlas)
        return out

    @property
    def has_alpha(self) -> bool:
        """Some caster's material cuts its shadow: the traversal runs the any-hit alpha test
        (``HS_HAS_ALPHA``; the UVs are baked, and some mesh caster has triangles to test)."""
        if self.bvh is not None:
            return self.bvh.uv_models is not None and self.has_meshes
        return self.tex.uv is not None and self.has_meshes

    @property
    def layout(self) -> _grid.GridLayout:
        return self.grid.layout

    @property
    def defines(self) -> dict:
        """``#define``s for scene_data.glsl. Flags are present only when true (``#ifdef``)."""
        w = self.config.tex_width
        if self.bvh is not None:
            d = {"HS_STRUCTURE_BVH": 1, "HS_TEX_WIDTH": int(w), "HS_TEX_WIDTH_LOG2": int(w).bit_length() - 1,
                 "HS_TEX_ROWS_LOG2": MAX_ROWS_LOG2, "HS_BVH_LEAF_SIZE": _twolevel.leaf_size(self.config)}
            if self.has_meshes:
                d["HS_HAS_MESHES"] = 1
            if self.has_spheres:
                d["HS_HAS_SPHERES"] = 1
            if self.has_alpha:
                d["HS_HAS_ALPHA"] = 1
            return d
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
        if (self.grid.obvh >= 0).any():
            d["HS_HAS_NODE_BVH"] = 1
        if self.has_alpha:
            d["HS_HAS_ALPHA"] = 1
        return d

    @property
    def uniforms(self) -> dict:
        """Uniform values by GLSL name (numpy arrays / Python scalars)."""
        if self.bvh is not None:
            return _twolevel.tlas_uniforms(self.bvh)
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
    def samplers(self) -> dict:
        """GLSL sampler uniform name of each texture."""
        return {name: f"hs_{name}_tex" for name in self.textures}

    @property
    def has_meshes(self) -> bool:
        if self.bvh is not None:
            return bool((self.bvh.member & ~self.bvh.sphere_of).any()) if len(self.bvh.member) else False
        inst = self.instances
        c = inst.node >= 0
        if not c.any():
            return False
        tri = self.models.tri_count[inst.model[c]] > 0
        return bool((tri & ~inst.sphere[c]).any())

    @property
    def has_spheres(self) -> bool:
        if self.bvh is not None:
            return bool((self.bvh.member & self.bvh.sphere_of).any()) if len(self.bvh.member) else False
        return bool((self.instances.sphere & (self.instances.node >= 0)).any())

    @property
    def scene_max_height(self) -> float:
        nonempty = self.grid.count > 0
        if not nonempty.any():
            return float(EMPTY_HEIGHT)
        return float(self.grid.maxh[nonempty].max())

    @property
    def texture_bytes(self) -> dict:
        return {k: t.nbytes for k, t in self.textures.items()}

    # read-only views of the state arrays by their flat names
    @property
    def node_count(self) -> np.ndarray:
        return self.grid.count

    @property
    def node_obvh(self) -> np.ndarray:
        return self.grid.obvh

    @property
    def index_tail(self) -> int:
        return self.grid.index_tail

    @property
    def grid_bvh_range(self) -> tuple[int, int]:
        return self.grid.bvh_range

    @property
    def bvh_tail(self) -> int:
        return self.tex.bvh_tail

    @property
    def inst_node(self) -> np.ndarray:
        return self.instances.node

    @property
    def inst_center(self) -> np.ndarray:
        return self.instances.center

    @property
    def inst_radius(self) -> np.ndarray:
        return self.instances.radius

    @property
    def model_node_start(self) -> np.ndarray:
        return self.models.node_start

    @property
    def model_node_count(self) -> np.ndarray:
        return self.models.node_count

    @property
    def model_node_cap(self) -> np.ndarray:
        return self.models.node_cap

    def refresh_stats(self) -> dict:
        """Recompute the derived entries of :attr:`stats` (the timings stay)."""
        if self.bvh is not None:
            return self._refresh_bvh_stats()
        lay = self.layout
        counts = self.grid.count
        obvh = self.grid.obvh
        models = self.models
        tex_bytes = self.texture_bytes
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
            "origin": [float(x) for x in self.origin],
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
            "bytes": tex_bytes,
            "total_bytes": int(sum(tex_bytes.values())),
        })
        return s

    def _refresh_bvh_stats(self) -> dict:
        t = self.bvh
        tex_bytes = self.texture_bytes
        self.stats.update({
            "structure": "bvh",
            "instances": int(len(t.member)),
            "casters": int(t.member.sum()),
            "models": int(len(t.node_count)),
            "triangles": int(t.tri_count.sum()),
            "bvh_nodes": int(t.node_count.sum()),
            "bvh_max_depth": int(t.depth.max()) if len(t.depth) else 0,
            "tlas_nodes": int(t.tlas_count),
            "tlas_max_depth": int(t.tlas_depth.max()) if len(t.tlas_depth) else 0,
            "origin": [float(x) for x in self.origin],
            "bytes": tex_bytes,
            "total_bytes": int(sum(tex_bytes.values())),
        })
        return self.stats

    # ------------------------------------------------------------------ updates ------------
    def update_instances(self, scene, indices) -> UpdateReport:
        """Instances ``indices`` moved (``scene.instances`` already holds their new matrices)."""
        if self.bvh is not None:
            t0 = time.perf_counter()
            rep = _twolevel.update_instances(self, scene, indices)
            self.refresh_stats()
            rep.ms = (time.perf_counter() - t0) * 1e3
            self.stats["last_update_ms"] = rep.ms
            return rep
        return _update.update_instances(self, scene, indices)

    def update_model(self, scene, model_id: int) -> UpdateReport:
        """Mesh ``model_id`` was edited (or appended to ``scene.models``): rebuild that model's
        BVH and triangles only, then re-place its instances."""
        if self.bvh is not None:
            t0 = time.perf_counter()
            old = self.defines
            rep = _twolevel.update_model(self, scene, int(model_id), UpdateReport())
            if self.defines != old:
                rep.defines_changed = True
            self.refresh_stats()
            rep.ms = (time.perf_counter() - t0) * 1e3
            return rep
        return _update.update_model(self, scene, model_id)

    # ------------------------------------------------------------------ writers ------------
    def write_objects(self, scene, idx: np.ndarray) -> None:
        """[object] texels of instances ``idx`` (+ spheres kept for the grid), in bake space."""
        inst = scene.instances
        st = self.instances
        c, r = scene.instance_spheres(idx)
        c = c - self.origin
        rs = stored_radius(c, r)
        st.center[idx] = c
        st.radius[idx] = r
        st.top[idx] = c[:, 2] + rs
        rec = self.tex.object.records(OBJECT_TEXELS)
        block = np.empty((len(idx), 16), np.float32)
        inv = inst.inverse[idx, :3, :].copy()  # world -> model, then bake space -> model:
        inv[:, :, 3] += inv[:, :, :3] @ self.origin  # M^-1 T(origin), in float64
        block[:, 0:12] = inv.reshape(len(idx), 12)
        block[:, 12:15] = c
        block[:, 15] = rs
        rec[idx] = block
        st.model[idx] = inst.model_ids[idx]
        st.sphere[idx] = inst.sphere[idx]
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
            src = build_bvhs([scene.models[m]], self.config.leaf_size).tri_src
            t0 = int(self.models.tri_start[m])
            self.write_model_uvs(scene, m, src, t0)
            ranges += texel_rows("uv", t0 * UV_TEXELS, (t0 + tc) * UV_TEXELS, w)
        return ranges

    def index_code(self, obj: np.ndarray) -> np.ndarray:
        st = self.instances
        return st.model[obj].astype(np.uint32) | np.where(st.sphere[obj], SPHERE_FLAG, np.uint32(0))

    def write_nodes(self, nodes: np.ndarray) -> None:
        """[grid] texels of global node ids ``nodes`` from the node arrays."""
        g = self.grid
        lin = self.tex.grid.linear()
        lin[nodes, 0] = g.offset[nodes]
        lin[nodes, 1] = g.count[nodes]
        mh = np.where(g.count[nodes] > 0, g.maxh[nodes], 0.0)
        h = np.where(g.count[nodes] > 0, f32_up(mh + REL_EPS * np.abs(mh)), EMPTY_HEIGHT)
        lin[nodes, 2] = f32_bits(h)
        lin[nodes, 3] = np.where(g.obvh[nodes] >= 0, g.obvh[nodes] + 1, 0)

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
        g, tex = self.grid, self.tex
        nodes = np.asarray(nodes, np.int64)
        crowd = np.asarray(cnt) > int(self.config.object_bvh_threshold)
        g.obvh[nodes[~crowd]] = -1
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
        obj = obj[morton_order_groups(self.instances.center[obj], istart, cc)]
        ent_obj = ent_obj.copy()
        ent_obj[items] = obj
        # item boxes: the stored (float32) sphere of each object, rounded outward
        rec = tex.object.records(OBJECT_TEXELS)[obj]
        c = rec[:, 12:15].astype(np.float64)
        r = rec[:, 15:16].astype(np.float64)
        lo, hi = f32_down(c - r), f32_up(c + r)
        nmin, nmax, esc, lstart, lcount, nstart, ncount, _ = build_trees(
            lo, hi, istart, cc, int(self.config.object_leaf_size))
        # allocation: in place when the node's previous allocation is large enough
        fits = ncount <= g.obvh_cap[cn]
        grown = False
        if (~fits).any():
            cap = self.obvh_nodes_for(np.maximum(g.cap[cn[~fits]], cc[~fits]))
            g.obvh_start[cn[~fits]] = tex.bvh_tail + np.concatenate([[0], np.cumsum(cap)[:-1]])
            g.obvh_cap[cn[~fits]] = cap
            tex.bvh_tail += int(cap.sum())
            if tex.bvh_tail * BVH_TEXELS > tex.bvh.capacity:
                spare = int(reserve * cap.sum()) + 1024
                grown = grow_texture(tex.bvh, (tex.bvh_tail + spare) * BVH_TEXELS, slack=0.0)
            tex.bvh.used = tex.bvh_tail * BVH_TEXELS
        base = g.obvh_start[cn]
        towner = np.repeat(np.arange(cn.size), ncount)
        shift = base[towner] - nstart[towner]  # local tree node -> absolute [bvh] record
        block = np.empty((len(esc), 8), np.uint32)
        block[:, 0:3] = f32_bits(nmin)
        block[:, 3] = esc + shift
        block[:, 4:7] = f32_bits(nmax)
        slot = g.offset[cn][towner] + (lstart - istart[towner])
        block[:, 7] = np.where(lcount > 0, (slot << 3) | lcount, 0)
        tex.bvh.records(BVH_TEXELS)[np.arange(len(esc)) + shift] = block
        g.obvh[cn] = base
        return ent_obj, (base, ncount), grown

    def write_models(self, ids: np.ndarray, scene) -> None:
        """[model] texels of model ids ``ids``."""
        ms = self.models
        rec = self.tex.model.records(MODEL_TEXELS)
        for m in np.asarray(ids).tolist():
            model = scene.models[m]
            sph = np.array([*model.sphere_center, model.sphere_radius], np.float64)
            s = np.concatenate([sph[:3].astype(np.float32), f32_up(sph[3:])])
            rec[m, 0:4] = f32_bits(s)
            rec[m, 4:8] = [ms.node_start[m], ms.node_count[m], ms.tri_start[m], ms.tri_count[m]]

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
        cfg, st, tex = self.config, self.instances, self.tex
        casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else np.zeros(0, np.int64)
        lay = _grid.plan_grid(st.center[casters], st.radius[casters], cfg.base_node_size, cfg.max_level0_nodes)
        node = _grid.place(lay, st.center[casters], st.radius[casters])
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
        st.node[:] = -1
        st.slot[:] = -1
        st.node[casters[order]] = sn
        st.slot[casters[order]] = slot
        maxh = np.full(n_nodes, -np.inf)
        if len(sn):
            starts = np.nonzero(np.concatenate([[True], sn[1:] != sn[:-1]]))[0]
            maxh[sn[starts]] = np.maximum.reduceat(st.top[casters[order]], starts)
        level_count = np.bincount(lay.node_level(node), minlength=lay.levels + 1)[: lay.levels].astype(np.int64)
        # object BVHs of crowded nodes: one contiguous [bvh] region after the model BVHs (every
        # [bvh] record past the last model allocation belonged to the previous grid: reclaimed)
        ends = self.models.node_start + self.models.node_cap
        tex.bvh_tail = int(ends.max()) if ends.size else 0
        region0 = tex.bvh_tail
        self.grid = g = GridState(
            layout=lay, count=counts, cap=cap, offset=offset, maxh=maxh,
            obvh=np.full(n_nodes, -1, np.int64), obvh_start=np.zeros(n_nodes, np.int64),
            obvh_cap=np.zeros(n_nodes, np.int64), level_count=level_count, index_tail=used)
        obj = casters[order]
        obj, _, g.bvh_grown = self.place_object_bvhs(np.arange(n_nodes), first, counts, obj,
                                                     reserve=cfg.index_reserve)
        g.bvh_range = (region0, tex.bvh_tail)  # [bvh] records written (for regrid reports)
        tex.bvh.used = tex.bvh_tail * BVH_TEXELS
        if obj.size:
            st.slot[obj] = slot
        reserve = max(1024, int(used * cfg.index_reserve))
        tex.grid = new_texture("grid", n_nodes * GRID_TEXELS, cfg.tex_width)
        tex.grid_index = new_texture("grid_index", (used + reserve) * INDEX_TEXELS, cfg.tex_width)
        tex.grid_index.used = used
        self.write_nodes(np.arange(n_nodes))
        lin = tex.grid_index.linear()
        lin[slot, 0] = obj
        lin[slot, 1] = self.index_code(obj)


def bake_scene(scene, config: BakeConfig | None = None) -> BakedScene:
    """Bake ``scene`` into GPU textures (see scene_data.glsl for every texel)."""
    cfg = config or BakeConfig()
    t0 = time.perf_counter()
    b = BakedScene(cfg)
    b.materials = bake_materials(scene, cfg.tex_width)
    if cfg.structure == "bvh":
        b.origin = choose_origin(scene) if cfg.origin is None else np.asarray(cfg.origin, np.float64).reshape(3)
        b.bvh = _twolevel.bake_twolevel(b, scene)
        b.stats = {"bake_ms": (time.perf_counter() - t0) * 1e3, "blas_ms": b.bvh.blas_ms, "tlas_ms": b.bvh.tlas_ms}
        b.refresh_stats()
        return b
    tex = b.tex
    n = len(scene.instances)
    models = list(scene.models)
    m_count = len(models)

    # models: BVH + triangles, once per model ---------------------------------------------
    tb = time.perf_counter()
    build = build_bvhs(models, cfg.leaf_size)
    b.models = ModelState.from_build(build)
    tex.bvh_tail = int(build.node_count.sum())
    tex.tri_tail = int(build.tri_count.sum())
    tex.model = new_texture("model", m_count * MODEL_TEXELS, cfg.tex_width)
    tex.bvh = new_texture("bvh", tex.bvh_tail * BVH_TEXELS, cfg.tex_width)
    tex.tri = new_texture("tri", tex.tri_tail * TRI_TEXELS, cfg.tex_width)
    if tex.bvh_tail:
        b._write_bvh_block(build, 0, tex.bvh_tail, 0, tex.tri_tail, 0, 0)
    b.write_models(np.arange(m_count), scene)
    if b.materials is not None and b.materials.cuts_shadows:
        uvm = scene.alpha_models()
        if uvm.any():  # alpha-cut shadows: [uv] mirrors [tri], [object_mat] below
            b.models.uv = uvm.copy()
            tex.uv = new_texture("uv", tex.tri_tail * UV_TEXELS, cfg.tex_width)
            ms = b.models
            for m in np.nonzero(uvm)[0].tolist():
                ts, tc = int(build.tri_start[m]), int(build.tri_count[m])
                b.write_model_uvs(scene, m, build.tri_src[ts:ts + tc], int(ms.tri_start[m]))
    t_bvh = time.perf_counter() - tb

    # objects ------------------------------------------------------------------------------
    to = time.perf_counter()
    b.instances = InstanceState.empty(n)
    tex.object = new_texture("object", n * OBJECT_TEXELS, cfg.tex_width)
    if tex.uv is not None:
        tex.object_mat = new_texture("object_mat", n, cfg.tex_width)
    b.origin = choose_origin(scene) if cfg.origin is None else np.asarray(cfg.origin, np.float64).reshape(3)
    if n:
        b.write_objects(scene, np.arange(n))
    t_obj = time.perf_counter() - to

    # grid ---------------------------------------------------------------------------------
    tg = time.perf_counter()
    b.build_grid(scene)
    t_grid = time.perf_counter() - tg
    b.stats = {
        "bake_ms": (time.perf_counter() - t0) * 1e3,
        "bvh_ms": t_bvh * 1e3,
        "objects_ms": t_obj * 1e3,
        "grid_ms": t_grid * 1e3,
    }
    b.refresh_stats()
    return b
