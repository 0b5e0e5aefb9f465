"""Incremental updates of a :class:`~.grid.HierarchicalGrid`, and the object BVHs of its crowded
nodes (built by the bake and by every update that touches such a node).

Moving instances rewrites their [object] texels, the [grid] texels of the nodes they leave and
enter, and the [grid_index] entries of those nodes only. A node keeps its slot range while its
new count fits its capacity; otherwise its list moves to the spare tail of the index list (the
old range becomes unreferenced garbage). When the tail runs out, or too many casters have left
the grid rectangle (they sit in the always-tested outside node), the grid is rebuilt (``regrid``).
Model BVHs are untouched by moves; a crowded node (object BVH, see ``place_object_bvhs``) that an
update touches (objects left, entered or moved inside it) rebuilds its object BVH, in place when
it fits the node's [bvh] allocation, else at the [bvh] tail. An edited mesh rebuilds that model's
BVH only: in place when it fits the model's old allocation, else appended (the texture grows when
needed). Alpha-cut shadows: [object_mat] follows the moved instances' materials (a model that gets
an alpha-cut instance gets its UVs into [uv]); [uv] follows the edited model's [tri] records.
"""

from __future__ import annotations

import numpy as np

from .. import grid as _grid
from ..bvh import build_bvhs, build_trees, morton_order_groups
from ..report import UpdateReport
from ..textures import (
    BVH_TEXELS,
    MODEL_TEXELS,
    OBJECT_TEXELS,
    TRI_TEXELS,
    f32_bits,
    f32_down,
    f32_up,
    grow_texture,
    rows_of_texels,
    texel_rows,
)
from .grid_state import UV_TEXELS


def _ragged(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges [s, s + c) for each (s, c)."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    rep = np.repeat(np.asarray(starts, np.int64) - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    return rep + np.arange(total, dtype=np.int64)


class GridUpdates:
    """Moves, model rebuilds and object-BVH placement of :class:`~.grid.HierarchicalGrid` (its
    state: ``tex``, ``models``, ``instances``, ``grid``; its writers: ``write_*``)."""

    def report_regrid(self, rep: UpdateReport) -> None:
        """The grid was built again: every grid texture is new."""
        rep.regrid = True
        rep.resized |= {"grid", "grid_index"}
        if self.grid.bvh_grown:
            rep.resized.add("bvh")
        else:
            lo, hi = self.grid.bvh_range
            rep.ranges += texel_rows("bvh", lo * BVH_TEXELS, hi * BVH_TEXELS, self.config.tex_width)
        rep.uniforms_changed = True
        rep.defines_changed = True

    def update_instances(self, scene, indices) -> UpdateReport:
        rep = UpdateReport()
        idx = np.unique(np.asarray(indices, np.int64).reshape(-1))
        if idx.size == 0:
            return rep
        objects = self.instances
        if len(scene.instances) != len(objects):
            raise ValueError("instances were added or removed: bake the scene again")
        w = self.config.tex_width
        old_level_defs = (self.has_meshes, self.has_spheres)
        old_maxh = self.scene_max_height

        # object texels ------------------------------------------------------------------------
        rep.ranges += self.ensure_model_uvs(scene, idx)
        self.write_objects(scene, idx)
        rep.ranges += rows_of_texels("object", (idx[:, None] * OBJECT_TEXELS + np.arange(OBJECT_TEXELS)).ravel(), w)
        if self.tex.object_mat is not None:
            rep.ranges += rows_of_texels("object_mat", idx, w)
        rep.objects = int(idx.size)

        # grid: nodes left and entered ---------------------------------------------------------
        lay = self.grid.layout
        casts = scene.instances.casts_shadow[idx]
        old = objects.node[idx]
        new = np.full(idx.size, -1, np.int64)
        if casts.any():
            new[casts] = _grid.place(lay, objects.center[idx[casts]], objects.radius[idx[casts]])
        moving = (old >= 0) | (new >= 0)
        if moving.any():
            ok = self.move_casters(idx[moving], old[moving], new[moving], rep)
            n_casters = int((objects.node >= 0).sum())
            outside = int(self.grid.count[lay.outside_node])
            if not ok or outside > max(16, self.config.grid.outside_rebake_fraction * n_casters):
                self.build_grid(scene)
                self.report_regrid(rep)
        if (self.has_meshes, self.has_spheres) != old_level_defs:
            rep.defines_changed = True
        if self.scene_max_height != old_maxh:
            rep.uniforms_changed = True
        return self.finish_update(rep)

    def move_casters(self, obj, old, new, rep) -> bool:
        """Move casters ``obj`` from nodes ``old`` to ``new`` (-1: none). False: index list full."""
        grid, objects, tex = self.grid, self.instances, self.tex
        lay = grid.layout
        aff = np.unique(np.concatenate([old[old >= 0], new[new >= 0]]))
        # current members of the affected nodes, minus the movers
        pos = _ragged(grid.offset[aff], grid.count[aff])
        node_of_pos = np.repeat(aff, grid.count[aff])
        lin = tex.grid_index.linear()
        members = lin[pos, 0].astype(np.int64)
        keep = ~np.isin(members, obj)
        ent_obj = np.concatenate([members[keep], obj[new >= 0]])
        ent_node = np.concatenate([node_of_pos[keep], new[new >= 0]])
        order = np.argsort(ent_node, kind="stable")
        ent_obj, ent_node = ent_obj[order], ent_node[order]
        k = np.searchsorted(aff, ent_node)
        cnt = np.bincount(k, minlength=aff.size).astype(np.int64)
        # relocate nodes that overflow their capacity to the tail
        over = cnt > grid.cap[aff]
        if over.any():
            need = _grid.node_capacity(cnt[over], self.config.grid.index_slack)
            starts = grid.index_tail + np.concatenate([[0], np.cumsum(need)[:-1]])
            end = grid.index_tail + int(need.sum())
            if end > tex.grid_index.capacity:
                return False
            grid.offset[aff[over]] = starts
            grid.cap[aff[over]] = need
            grid.index_tail = end
            tex.grid_index.used = end
        # per-level object counts
        lv_old = lay.node_level(old[old >= 0])
        lv_new = lay.node_level(new[new >= 0])
        lc = np.bincount(lv_new, minlength=lay.levels + 1) - np.bincount(lv_old, minlength=lay.levels + 1)
        grid.level_count += lc[: lay.levels]
        # write entries (crowded nodes: in their rebuilt object BVH's leaf order)
        first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        rank = np.arange(ent_obj.size) - first[k]
        slot = grid.offset[ent_node] + rank
        ent_obj, (bvh_start, bvh_count), grown = self.place_object_bvhs(aff, first, cnt, ent_obj)
        w = self.config.tex_width
        if grown:
            rep.resized.add("bvh")
        elif bvh_start.size:
            rep.ranges += rows_of_texels("bvh", _ragged(bvh_start * BVH_TEXELS, bvh_count * BVH_TEXELS), w)
        lin[slot, 0] = ent_obj
        lin[slot, 1] = self.index_code(ent_obj)
        objects.node[obj] = -1
        objects.slot[obj] = -1
        objects.node[ent_obj] = ent_node
        objects.slot[ent_obj] = slot
        # node records
        grid.count[aff] = cnt
        maxh = np.full(aff.size, -np.inf)
        if ent_obj.size:
            nz = np.nonzero(cnt)[0]
            maxh[nz] = np.maximum.reduceat(objects.top[ent_obj], first[nz])
        grid.maxh[aff] = maxh
        self.write_nodes(aff)
        rep.nodes_changed += int(aff.size)
        rep.ranges += rows_of_texels("grid", aff, w)
        rep.ranges += rows_of_texels("grid_index", slot, w)
        if (lc != 0).any():
            rep.uniforms_changed = True
        return True

    def append_model(self, rep: UpdateReport) -> None:
        self.models.append()
        if grow_texture(self.tex.model, len(self.models) * MODEL_TEXELS):
            rep.resized.add("model")

    def rebuild_model(self, scene, m: int, rep: UpdateReport) -> None:
        w = self.config.tex_width
        slots, tex = self.models, self.tex
        build = build_bvhs([scene.models[m]], self.config.grid.leaf_size)
        nc, tc = int(build.node_count[0]), int(build.tri_count[0])
        node_base, tri_base, at_tail = slots.place(m, nc, tc, tex.bvh_tail, tex.tri_tail)
        if at_tail:
            tex.bvh_tail += nc
            tex.tri_tail += tc
            for name, n_tex in (("bvh", tex.bvh_tail * BVH_TEXELS), ("tri", tex.tri_tail * TRI_TEXELS)):
                if grow_texture(tex[name], n_tex):
                    rep.resized.add(name)
                tex[name].used = n_tex
        slots.node_start[m], slots.node_count[m] = node_base, nc
        slots.tri_start[m], slots.tri_count[m] = tri_base, tc
        slots.depth[m] = int(build.depth[0]) if len(build.depth) else 0
        if nc:
            self.write_bvh(build, node_base, tri_base, 0)
        self.write_models(np.array([m]), scene)
        if tex.uv is not None:  # alpha-cut shadows: [uv] mirrors [tri]
            n_uv = tex.tri_tail * UV_TEXELS
            if grow_texture(tex.uv, n_uv):
                rep.resized.add("uv")
            tex.uv.used = max(tex.uv.used, n_uv)
            slots.uv[m] = bool(scene.alpha_models()[m])
            self.write_model_uvs(scene, m, build.tri_src[:tc], tri_base)
            rep.ranges += texel_rows("uv", tri_base * UV_TEXELS, (tri_base + tc) * UV_TEXELS, w)
        rep.ranges += texel_rows("bvh", node_base * BVH_TEXELS, (node_base + nc) * BVH_TEXELS, w)
        rep.ranges += texel_rows("tri", tri_base * TRI_TEXELS, (tri_base + tc) * TRI_TEXELS, w)
        rep.ranges += texel_rows("model", m * MODEL_TEXELS, (m + 1) * MODEL_TEXELS, w)

    def obvh_nodes_for(self, n) -> np.ndarray:
        """Object-BVH tree nodes for ``n`` objects (balanced tree over ceil(n / leaf) leaves)."""
        leaves = -(-np.asarray(n, np.int64) // int(self.config.grid.object_leaf_size))
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
        grid, tex = self.grid, self.tex
        nodes = np.asarray(nodes, np.int64)
        crowd = np.asarray(cnt) > int(self.config.grid.object_bvh_threshold)
        grid.obvh[nodes[~crowd]] = -1
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
            lo, hi, istart, cc, int(self.config.grid.object_leaf_size))
        # allocation: in place when the node's previous allocation is large enough
        fits = ncount <= grid.obvh_cap[cn]
        grown = False
        if (~fits).any():
            cap = self.obvh_nodes_for(np.maximum(grid.cap[cn[~fits]], cc[~fits]))
            grid.obvh_start[cn[~fits]] = tex.bvh_tail + np.concatenate([[0], np.cumsum(cap)[:-1]])
            grid.obvh_cap[cn[~fits]] = cap
            tex.bvh_tail += int(cap.sum())
            if tex.bvh_tail * BVH_TEXELS > tex.bvh.capacity:
                spare = int(reserve * cap.sum()) + 1024
                grown = grow_texture(tex.bvh, (tex.bvh_tail + spare) * BVH_TEXELS, slack=0.0)
            tex.bvh.used = tex.bvh_tail * BVH_TEXELS
        base = grid.obvh_start[cn]
        towner = np.repeat(np.arange(cn.size), ncount)
        shift = base[towner] - nstart[towner]  # local tree node -> absolute [bvh] record
        block = np.empty((len(esc), 8), np.uint32)
        block[:, 0:3] = f32_bits(nmin)
        block[:, 3] = esc + shift
        block[:, 4:7] = f32_bits(nmax)
        slot = grid.offset[cn][towner] + (lstart - istart[towner])
        block[:, 7] = np.where(lcount > 0, (slot << 3) | lcount, 0)
        tex.bvh.records(BVH_TEXELS)[np.arange(len(esc)) + shift] = block
        grid.obvh[cn] = base
        return ent_obj, (base, ncount), grown
