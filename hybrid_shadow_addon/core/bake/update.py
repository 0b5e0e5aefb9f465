"""Incremental updates of a :class:`~.baked.BakedScene`.

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

import time

import numpy as np

from . import grid as _grid
from .bvh import build_bvhs
from .state import UV_TEXELS, UpdateReport
from .textures import (BVH_TEXELS, MODEL_TEXELS, OBJECT_TEXELS, TRI_TEXELS, grow_texture, merge_ranges,
                       rows_of_texels, texel_rows)


def _ragged(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges [s, s + c) for each (s, c)."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    rep = np.repeat(np.asarray(starts, np.int64) - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    return rep + np.arange(total, dtype=np.int64)


def _full_grid_report(b, rep: UpdateReport) -> None:
    rep.regrid = True
    rep.resized |= {"grid", "grid_index"}
    if b.grid.bvh_grown:
        rep.resized.add("bvh")
    else:
        lo, hi = b.grid.bvh_range
        rep.ranges += texel_rows("bvh", lo * BVH_TEXELS, hi * BVH_TEXELS, b.config.tex_width)
    rep.uniforms_changed = True
    rep.defines_changed = True


def update_instances(b, scene, indices) -> UpdateReport:
    """Instances ``indices`` of the baked scene ``b`` moved; see :meth:`BakedScene.update_instances`."""
    t0 = time.perf_counter()
    rep = UpdateReport()
    idx = np.unique(np.asarray(indices, np.int64).reshape(-1))
    if idx.size == 0:
        return rep
    st = b.instances
    if len(scene.instances) != len(st):
        raise ValueError("instances were added or removed: bake the scene again")
    w = b.config.tex_width
    old_level_defs = (b.has_meshes, b.has_spheres)
    old_maxh = b.scene_max_height

    # object texels ------------------------------------------------------------------------
    rep.ranges += b.ensure_model_uvs(scene, idx)
    b.write_objects(scene, idx)
    rep.ranges += rows_of_texels("object", (idx[:, None] * OBJECT_TEXELS + np.arange(OBJECT_TEXELS)).ravel(), w)
    if b.tex.object_mat is not None:
        rep.ranges += rows_of_texels("object_mat", idx, w)
    rep.objects = int(idx.size)

    # grid: nodes left and entered ---------------------------------------------------------
    lay = b.grid.layout
    casts = scene.instances.casts_shadow[idx]
    old = st.node[idx]
    new = np.full(idx.size, -1, np.int64)
    if casts.any():
        new[casts] = _grid.place(lay, st.center[idx[casts]], st.radius[idx[casts]])
    moving = (old >= 0) | (new >= 0)
    if moving.any():
        ok = _move(b, idx[moving], old[moving], new[moving], rep)
        n_casters = int((st.node >= 0).sum())
        outside = int(b.grid.count[lay.outside_node])
        if not ok or outside > max(16, b.config.outside_rebake_fraction * n_casters):
            b.build_grid(scene)
            _full_grid_report(b, rep)
    if (b.has_meshes, b.has_spheres) != old_level_defs:
        rep.defines_changed = True
    if b.scene_max_height != old_maxh:
        rep.uniforms_changed = True
    rep.ranges = merge_ranges([r for r in rep.ranges if r[0] not in rep.resized])
    b.refresh_stats()
    rep.ms = (time.perf_counter() - t0) * 1e3
    b.stats["last_update_ms"] = rep.ms
    return rep


def _move(b, obj, old, new, rep) -> bool:
    """Move casters ``obj`` from nodes ``old`` to ``new`` (-1: none). False: index list full."""
    g, st, tex = b.grid, b.instances, b.tex
    lay = g.layout
    aff = np.unique(np.concatenate([old[old >= 0], new[new >= 0]]))
    # current members of the affected nodes, minus the movers
    pos = _ragged(g.offset[aff], g.count[aff])
    node_of_pos = np.repeat(aff, g.count[aff])
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
    over = cnt > g.cap[aff]
    if over.any():
        need = _grid.node_capacity(cnt[over], b.config.index_slack)
        starts = g.index_tail + np.concatenate([[0], np.cumsum(need)[:-1]])
        end = g.index_tail + int(need.sum())
        if end > tex.grid_index.capacity:
            return False
        g.offset[aff[over]] = starts
        g.cap[aff[over]] = need
        g.index_tail = end
        tex.grid_index.used = end
    # per-level object counts
    lv_old = lay.node_level(old[old >= 0])
    lv_new = lay.node_level(new[new >= 0])
    lc = np.bincount(lv_new, minlength=lay.levels + 1) - np.bincount(lv_old, minlength=lay.levels + 1)
    g.level_count += lc[: lay.levels]
    # write entries (crowded nodes: in their rebuilt object BVH's leaf order)
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    rank = np.arange(ent_obj.size) - first[k]
    slot = g.offset[ent_node] + rank
    ent_obj, (bvh_start, bvh_count), grown = b.place_object_bvhs(aff, first, cnt, ent_obj)
    w = b.config.tex_width
    if grown:
        rep.resized.add("bvh")
    elif bvh_start.size:
        rep.ranges += rows_of_texels("bvh", _ragged(bvh_start * BVH_TEXELS, bvh_count * BVH_TEXELS), w)
    lin[slot, 0] = ent_obj
    lin[slot, 1] = b.index_code(ent_obj)
    st.node[obj] = -1
    st.slot[obj] = -1
    st.node[ent_obj] = ent_node
    st.slot[ent_obj] = slot
    # node records
    g.count[aff] = cnt
    maxh = np.full(aff.size, -np.inf)
    if ent_obj.size:
        nz = np.nonzero(cnt)[0]
        maxh[nz] = np.maximum.reduceat(st.top[ent_obj], first[nz])
    g.maxh[aff] = maxh
    b.write_nodes(aff)
    rep.nodes_changed += int(aff.size)
    rep.ranges += rows_of_texels("grid", aff, w)
    rep.ranges += rows_of_texels("grid_index", slot, w)
    if (lc != 0).any():
        rep.uniforms_changed = True
    return True


def update_model(b, scene, model_id: int) -> UpdateReport:
    """Model ``model_id`` of the baked scene ``b`` changed; see :meth:`BakedScene.update_model`."""
    t0 = time.perf_counter()
    rep = UpdateReport()
    m = int(model_id)
    w = b.config.tex_width
    ms, tex = b.models, b.tex
    n_old = len(ms)
    if m > n_old or m >= len(scene.models):
        raise ValueError(f"model id {m} is neither an existing model nor the next new one")
    if m == n_old:  # a new model
        ms.append()
        if grow_texture(tex.model, (m + 1) * MODEL_TEXELS):
            rep.resized.add("model")
    old_defs = b.defines
    build = build_bvhs([scene.models[m]], b.config.leaf_size)
    nc, tc = int(build.node_count[0]), int(build.tri_count[0])
    if nc <= ms.node_cap[m] and tc <= ms.tri_cap[m]:
        node_base, tri_base = int(ms.node_start[m]), int(ms.tri_start[m])
    else:
        node_base, tri_base = tex.bvh_tail, tex.tri_tail
        tex.bvh_tail += nc
        tex.tri_tail += tc
        ms.node_cap[m], ms.tri_cap[m] = nc, tc
        for name, n_tex in (("bvh", tex.bvh_tail * BVH_TEXELS), ("tri", tex.tri_tail * TRI_TEXELS)):
            if grow_texture(tex[name], n_tex):
                rep.resized.add(name)
            tex[name].used = n_tex
    ms.node_start[m], ms.node_count[m] = node_base, nc
    ms.tri_start[m], ms.tri_count[m] = tri_base, tc
    ms.depth[m] = int(build.depth[0]) if len(build.depth) else 0
    if nc:
        b.write_bvh(build, node_base, tri_base, 0)
    b.write_models(np.array([m]), scene)
    if tex.uv is not None:  # alpha-cut shadows: [uv] mirrors [tri]
        n_uv = tex.tri_tail * UV_TEXELS
        if grow_texture(tex.uv, n_uv):
            rep.resized.add("uv")
        tex.uv.used = max(tex.uv.used, n_uv)
        ms.uv[m] = bool(scene.alpha_models()[m])
        b.write_model_uvs(scene, m, build.tri_src[:tc], tri_base)
        rep.ranges += texel_rows("uv", tri_base * UV_TEXELS, (tri_base + tc) * UV_TEXELS, w)
    rep.ranges += texel_rows("bvh", node_base * BVH_TEXELS, (node_base + nc) * BVH_TEXELS, w)
    rep.ranges += texel_rows("tri", tri_base * TRI_TEXELS, (tri_base + tc) * TRI_TEXELS, w)
    rep.ranges += texel_rows("model", m * MODEL_TEXELS, (m + 1) * MODEL_TEXELS, w)
    users = np.nonzero(scene.instances.model_ids == m)[0] if len(scene.instances) else np.zeros(0, np.int64)
    if users.size:
        rep.merge(update_instances(b, scene, users))
    if b.defines != old_defs:
        rep.defines_changed = True
    rep.ranges = merge_ranges([r for r in rep.ranges if r[0] not in rep.resized])
    b.refresh_stats()
    rep.ms = (time.perf_counter() - t0) * 1e3
    return rep
