"""Two-level BVH (``structure="bvh"``): SAH model trees (BLAS) under an SAH tree over the
casters' world boxes (TLAS), one 16-bit quantised node per texel; textures [node] and [leaf] of
``shaders/common/scene_data.glsl``.

Model trees: triangles Morton-sorted per model, cut into clusters of ``leaf_size`` consecutive
triangles; the clusters are the leaves of a tree whose nodes of more than ``RUN_SAH_MIN``
clusters split by SAH between equal runs of the Morton order (``sah.build_sah``); the top level
splits nodes of more than ``SPATIAL_MIN`` instances by spatially binned SAH first. Node boxes are
quantised on a per-model grid (origin ``base``, power-of-two step ``1 / inv_s``), floor / ceil
of the exact float64 union, so the decoded box always holds its triangles. The top level holds
one caster per leaf, boxes = the world box of the model box (or sphere box) corners, padded by
``TLAS_PAD`` relative, quantised on one grid over the scene. Moves refit the top level (rebuild
when the boxes leave the grid, membership changes or the SAH area doubles); a model edit rebuilds
that model's tree (in place when it fits) and refits.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .bvh import _morton3
from .sah import build_sah
from .state import UpdateReport
from .textures import (SPHERE_FLAG, TextureData, alloc_texture, f32_bits, f32_down, f32_up, grow_texture,
                       merge_ranges, rows_of_texels, texel_rows)

QMAX = 65535
QSPAN = 65000.0  # quanta a box spans at most (room for floor / ceil and the base rounding)
LEAF_FLAG = np.uint32(1 << 31)
SPATIAL_MIN = 4096  # top-level nodes larger than this split by spatially binned SAH
RUN_SAH_MIN = 32  # nodes larger than this split by SAH over runs of their Morton order
FRAME_MARGIN = 1.0 / 16.0  # top-level quantisation frame: scene box + this fraction per side
TLAS_PAD = 2.0 ** -18  # relative padding of the top-level boxes (float32 inverse matrices)
INST_TEXELS = 5  # [leaf] instance record: bits(inverse rows 0..2), (tree root, tree end,
#                 model | SPHERE_FLAG, 0), bits(quant base xyz, inv_s) or bits(model sphere)
NODE_TEXELS = 1  # [node] u4: quantised box (3 x 2 x 16 bits), escape or LEAF_FLAG | payload
TRI4_FLOATS = 9  # [leaf] triangles: a leaf's triangles back to back, 9 float bits each
LEAF_READ = 9  # texels the shader reads from any [leaf] record start (the tail is padded)

FORMATS = {"node": (4, "u4"), "leaf": (4, "u4"), "uv": (4, "f4")}
NAMES = tuple(FORMATS)  # "uv" (UVs at the [leaf] texels of alpha-cut models) only when present


def leaf_size(config) -> int:
    """Triangles per model leaf (``BakeConfig.bvh_leaf_size``, 1..4)."""
    return int(min(max(int(config.bvh_leaf_size), 1), 4))


def tri_texels(count) -> np.ndarray:
    return -(-(np.asarray(count, np.int64) * TRI4_FLOATS) // 4)


def quant_frame(lo, hi):
    """(base float32, inv_s power of two) of a grid over [lo, hi] (rows: one frame each)."""
    lo = np.asarray(lo, np.float64).reshape(-1, 3)
    hi = np.asarray(hi, np.float64).reshape(-1, 3)
    base = f32_down(lo).astype(np.float64)
    ext = np.maximum((hi - base).max(axis=1), 1e-30)
    e = np.ceil(np.log2(ext / QSPAN))
    e = np.clip(e, -120, 120)
    return base, 2.0 ** (-e)


def quantise(nmin, nmax, base, inv_s):
    """(N, 3) uint32 pairs (qlo, qhi): floor / ceil of the box on the frame, clipped."""
    qlo = np.clip(np.floor((nmin - base) * inv_s[:, None]), 0, QMAX).astype(np.uint32)
    qhi = np.clip(np.ceil((nmax - base) * inv_s[:, None]), 0, QMAX).astype(np.uint32)
    return qlo, qhi


def pack_nodes(qlo, qhi, w) -> np.ndarray:
    out = np.empty((len(qlo), 4), np.uint32)
    out[:, 0] = qlo[:, 0] | (qlo[:, 1] << np.uint32(16))
    out[:, 1] = qlo[:, 2] | (qhi[:, 0] << np.uint32(16))
    out[:, 2] = qhi[:, 1] | (qhi[:, 2] << np.uint32(16))
    out[:, 3] = w
    return out


@dataclass
class BlasBuild:
    """Model trees of a list of models, local indices (nodes, [tri4] texels)."""

    build: object  # SAHBuild over clusters
    node_start: np.ndarray
    node_count: np.ndarray
    tri_start: np.ndarray  # first [tri4] texel per model
    tri_texels: np.ndarray
    tri_count: np.ndarray
    depth: np.ndarray
    base: np.ndarray  # (M, 3)
    inv_s: np.ndarray  # (M,)
    nodes: np.ndarray  # (Nn, 4) uint32 packed, leaf payloads local to tri_start = 0, escapes local
    tri4: np.ndarray  # (texels, 4) float32
    uv4: np.ndarray = None  # (texels, 4) float32 UVs at the triangles' texels (6 per triangle), or None


def build_blas(models, leaf_size: int = 4, uv_models=None) -> BlasBuild:
    """Model trees of ``models``; ``uv_models`` (bool per model): pack those models' UVs into
    ``uv4`` at the same texels as their triangles (the any-hit alpha test reads them)."""
    M = len(models)
    L = int(min(max(leaf_size, 1), 4))
    tc = np.array([m.triangle_count for m in models], np.int64)
    total = int(tc.sum())
    tris = np.empty((total, 3, 3), np.float32)
    want_uv = uv_models is not None and bool(np.any(uv_models))
    uvs = np.zeros((total, 3, 2), np.float32) if want_uv else None
    t0 = np.concatenate([[0], np.cumsum(tc)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    third = np.float32(1.0 / 3.0)
    for mi, (m, s0) in enumerate(zip(models, t0.tolist())):
        T = m.triangle_count
        if not T:
            continue
        tr = m.vertices.take(m.triangles.ravel(), axis=0).reshape(T, 3, 3)
        cen = (tr[:, 0] + tr[:, 1] + tr[:, 2]) * third
        cmin, cmax = cen.min(axis=0), cen.max(axis=0)
        span = np.maximum(cmax - cmin, np.float32(1e-30))
        q = np.clip((cen - cmin) * (np.float32(1023.0) / span), 0, 1023).astype(np.uint32)
        order = np.argsort(_morton3(q), kind="stable")
        tris[s0:s0 + T] = tr[order]
        if want_uv and uv_models[mi] and m.uvs is not None:
            uvs[s0:s0 + T] = m.uvs[order]
    # clusters of L consecutive triangles per model
    ncl = -(-tc // L)
    c0 = np.concatenate([[0], np.cumsum(ncl)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    mod = np.repeat(np.arange(M), ncl)
    j = np.arange(int(ncl.sum())) - c0[mod]
    cl_tri0 = t0[mod] + j * L
    cl_cnt = np.minimum(L, tc[mod] - j * L)
    tmin = np.minimum(np.minimum(tris[:, 0], tris[:, 1]), tris[:, 2])
    tmax = np.maximum(np.maximum(tris[:, 0], tris[:, 1]), tris[:, 2])
    if len(cl_tri0):
        cmn = np.minimum.reduceat(tmin, cl_tri0, axis=0)
        cmx = np.maximum.reduceat(tmax, cl_tri0, axis=0)
    else:
        cmn = cmx = np.zeros((0, 3))
    b = build_sah(cmn, cmx, c0, ncl, leaf_size=1, bins=8, sah_min=RUN_SAH_MIN)
    # model frames
    lo = np.zeros((M, 3))
    hi = np.zeros((M, 3))
    has = ncl > 0
    if has.any():
        lo[has] = np.minimum.reduceat(cmn, c0[has], axis=0)
        hi[has] = np.maximum.reduceat(cmx, c0[has], axis=0)
    base, inv_s = quant_frame(lo, hi)
    # triangles in leaf order; a leaf = one cluster, ceil(9 c / 4) texels
    nmod = np.repeat(np.arange(M), b.node_count)
    leaf = b.leaf_count > 0
    lcl = b.perm[b.leaf_start[leaf]]  # cluster of each leaf, leaves in pre-order
    lcnt = cl_cnt[lcl]
    ltex = tri_texels(lcnt)
    lmod = nmod[leaf]
    tri_texels_m = np.bincount(lmod, weights=ltex, minlength=M).astype(np.int64)
    tri_start = np.concatenate([[0], np.cumsum(tri_texels_m)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    lfirst = (np.cumsum(ltex) - ltex).astype(np.int64)  # global texel
    flat = np.zeros(int(ltex.sum()) * 4, np.float32)
    own = np.repeat(np.arange(len(lcl)), lcnt)
    k = np.arange(int(lcnt.sum())) - np.repeat((np.cumsum(lcnt) - lcnt).astype(np.int64), lcnt)
    src = cl_tri0[lcl][own] + k
    dst = (lfirst[own] * 4)[:, None] + k[:, None] * 9 + np.arange(9)
    flat[dst.ravel()] = tris[src].reshape(-1)
    uv4 = None
    if want_uv:
        uflat = np.zeros_like(flat)
        udst = (lfirst[own] * 4)[:, None] + k[:, None] * 6 + np.arange(6)
        uflat[udst.ravel()] = uvs[src].reshape(-1)
        uv4 = uflat.reshape(-1, 4)
    # packed nodes
    qlo, qhi = quantise(b.node_min, b.node_max, base[nmod], inv_s[nmod])
    w = np.where(leaf, 0, b.escape).astype(np.uint32)
    lpay = ((lfirst - tri_start[lmod]) << 3) | lcnt
    w[leaf] = LEAF_FLAG | lpay.astype(np.uint32)
    return BlasBuild(b, b.node_start, b.node_count, tri_start, tri_texels_m, tc, b.depth, base, inv_s,
                     pack_nodes(qlo, qhi, w), flat.reshape(-1, 4), uv4)


@dataclass
class TwoLevelState:
    """Where everything of the two-level structure sits, plus what a refit needs."""

    tex: dict = field(default_factory=dict)  # name -> TextureData
    node_tail: int = 0  # [node] records allocated
    leaf_tail: int = 0  # [leaf] texels allocated (instance records, then triangle blocks)
    # per model
    node_start: np.ndarray = None
    node_count: np.ndarray = None
    node_cap: np.ndarray = None
    tri_start: np.ndarray = None  # first [leaf] texel of the model's triangle blocks
    tri_cap: np.ndarray = None
    tri_count: np.ndarray = None
    depth: np.ndarray = None
    base: np.ndarray = None  # (M, 3) quantisation frame of the model tree
    inv_s: np.ndarray = None  # (M,)
    mbox: np.ndarray = None  # (M, 2, 3) model box float64
    # per instance
    member: np.ndarray = None  # (N,) bool in the top level
    sphere_of: np.ndarray = None  # (N,) bool analytic sphere
    box_lo: np.ndarray = None  # (N, 3) padded world box, bake space
    box_hi: np.ndarray = None
    # top level
    tlas_start: int = 0
    tlas_count: int = 0
    tlas_cap: int = 0
    tlas_leaf_inst: np.ndarray = None  # instance of each tlas node (-1 inner)
    tlas_left: np.ndarray = None  # local child indices (-1 for leaves)
    tlas_right: np.ndarray = None
    tlas_depth: np.ndarray = None
    tlas_levels: list = None  # refit order (derived from tlas_depth)
    tlas_escape: np.ndarray = None  # local
    tlas_base: np.ndarray = None
    tlas_inv_s: float = 1.0
    tlas_area: float = 0.0
    blas_ms: float = 0.0  # bake timings
    tlas_ms: float = 0.0
    uv_models: np.ndarray = None  # (M,) bool: models whose UVs are in "uv" (alpha-cut shadows)

    def textures(self) -> dict:
        return {n: self.tex[n] for n in NAMES if n in self.tex}


def _new(name, n, width) -> TextureData:
    comps, fmt = FORMATS[name]
    return alloc_texture(name, n, comps, fmt, width)


def _grow(st, name, need, rep=None) -> None:
    tex = st.tex[name]
    if grow_texture(tex, need) and rep is not None:
        rep.resized.add(name)
    tex.used = max(tex.used, need)
    if name == "leaf" and "uv" in st.tex:  # the UVs mirror the [leaf] texels
        _grow(st, "uv", need, rep)


# ------------------------------------------------------------------------------------- bake --
def bake_twolevel(b, scene) -> TwoLevelState:
    """Fill the two-level textures of BakedScene ``b`` (origin and config already set)."""
    cfg = b.config
    W = cfg.tex_width
    st = TwoLevelState()
    models = list(scene.models)
    M = len(models)
    n = len(scene.instances)
    t0 = time.perf_counter()
    uv_models = scene.alpha_models() if b.materials is not None and b.materials.cuts_shadows else None
    bl = build_blas(models, leaf_size(cfg), uv_models)
    st.blas_ms = (time.perf_counter() - t0) * 1e3
    inst_end = n * INST_TEXELS
    st.node_start = bl.node_start.copy()
    st.node_count = bl.node_count.copy()
    st.node_cap = bl.node_count.copy()
    st.tri_start = bl.tri_start + inst_end
    st.tri_cap = bl.tri_texels.copy()
    st.tri_count = bl.tri_count.copy()
    st.depth = bl.depth.copy()
    st.base, st.inv_s = bl.base.copy(), bl.inv_s.copy()
    st.node_tail = int(bl.node_count.sum())
    st.leaf_tail = inst_end + int(bl.tri_texels.sum())
    st.tex["leaf"] = _new("leaf", st.leaf_tail + LEAF_READ, W)
    st.tex["leaf"].used = st.leaf_tail
    st.tex["leaf"].linear()[inst_end:st.leaf_tail] = bl.tri4.view(np.uint32)
    if bl.uv4 is not None:
        st.uv_models = np.asarray(uv_models, bool).copy()
        st.tex["uv"] = _new("uv", st.tex["leaf"].capacity, W)
        st.tex["uv"].used = st.leaf_tail
        st.tex["uv"].linear()[inst_end:st.leaf_tail] = bl.uv4
    st.mbox = np.zeros((M, 2, 3))
    for m in range(M):
        st.mbox[m] = _model_box(models[m], False)
    # [node]: model trees, then the top level (with spare room)
    st.member = np.zeros(n, bool)
    st.sphere_of = np.zeros(n, bool)
    st.box_lo = np.zeros((n, 3))
    st.box_hi = np.zeros((n, 3))
    ncast = int(scene.instances.casts_shadow.sum()) if n else 0
    spare = max(1024, int(0.25 * (st.node_tail + 2 * ncast)))
    st.tex["node"] = _new("node", st.node_tail + 2 * ncast + spare, W)
    st.tex["node"].used = st.node_tail
    if st.node_tail:
        nodes = bl.nodes.copy()
        _relocate(nodes, st.node_start, bl.node_start, bl.node_count, st.tri_start, bl.tri_start)
        st.tex["node"].linear()[: st.node_tail] = nodes
    t0 = time.perf_counter()
    if n:
        write_instances(b, st, scene, np.arange(n))
    build_tlas(b, st)
    st.tlas_ms = (time.perf_counter() - t0) * 1e3
    return st


def _relocate(nodes, node_base, local_start, local_count, tri_base, local_tri):
    """Local escapes / leaf payloads of each model's nodes -> absolute indices (in place)."""
    own = np.repeat(np.arange(len(local_count)), local_count)
    w = nodes[:, 3]
    leaf = (w & LEAF_FLAG) != 0
    shift_n = (np.asarray(node_base, np.int64) - local_start)[own]
    w_inner = w.astype(np.int64) + shift_n
    pay = (w & np.uint32(0x7FFFFFFF)).astype(np.int64)
    pay = (((pay >> 3) + np.asarray(tri_base, np.int64)[own]) << 3) | (pay & 7)
    nodes[:, 3] = np.where(leaf, LEAF_FLAG | pay.astype(np.uint32), w_inner.astype(np.uint32))


def _model_box(model, sphere: bool) -> np.ndarray:
    if sphere:
        c = model.sphere_center.astype(np.float64)
        r = float(f32_up(model.sphere_radius))
        return np.stack([c - r, c + r])
    return np.stack([model.bounds_min.astype(np.float64), model.bounds_max.astype(np.float64)])


def write_instances(b, st, scene, idx) -> None:
    """[leaf] instance records and world boxes of instances ``idx``."""
    inst = scene.instances
    idx = np.asarray(idx, np.int64)
    mid = inst.model_ids[idx].astype(np.int64)
    sph = inst.sphere[idx]
    inv = inst.inverse[idx, :3, :].copy()
    inv[:, :, 3] += inv[:, :, :3] @ b.origin
    rec = st.tex["leaf"].linear()[: len(inst) * INST_TEXELS].reshape(-1, INST_TEXELS * 4)
    block = np.zeros((len(idx), INST_TEXELS * 4), np.uint32)
    block[:, 0:12] = f32_bits(inv.reshape(len(idx), 12).astype(np.float32))
    root = st.node_start[mid]
    block[:, 12] = np.where(sph, 0, root)
    block[:, 13] = np.where(sph, 0, root + st.node_count[mid])
    block[:, 14] = mid.astype(np.uint32) | np.where(sph, SPHERE_FLAG, np.uint32(0))
    if st.uv_models is not None:  # 1 + material of an alpha-cut caster (its model has UVs), else 0
        slot = b.materials.instance_slots(inst.material_ids[idx])
        block[:, 15] = np.where(st.uv_models[mid] & ~sph, slot, 0)
    frame = np.zeros((len(idx), 4), np.float32)
    frame[:, 0:3] = st.base[mid]
    frame[:, 3] = st.inv_s[mid]
    box = np.empty((len(idx), 2, 3))
    box[:] = st.mbox[mid] if len(st.mbox) else 0.0
    if sph.any():
        ms = np.unique(mid[sph])
        sp = np.array([np.concatenate([scene.models[m].sphere_center, f32_up([scene.models[m].sphere_radius])])
                       for m in ms.tolist()], np.float32).reshape(-1, 4)
        k = np.searchsorted(ms, mid[sph])
        frame[sph] = sp[k]
        c, r = sp[k, 0:3].astype(np.float64), sp[k, 3:4].astype(np.float64)
        box[sph, 0], box[sph, 1] = c - r, c + r
    block[:, 16:20] = f32_bits(frame)
    rec[idx] = block
    # world boxes of the model box corners (bake space), padded
    corners = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(8, 3)
    pts = np.where(corners[None, :, :] == 0, box[:, None, 0, :], box[:, None, 1, :])  # (n, 8, 3)
    Mx = inst.matrices[idx]
    wp = np.einsum("nij,nkj->nki", Mx[:, :3, :3], pts) + Mx[:, None, :3, 3] - b.origin
    lo, hi = wp.min(axis=1), wp.max(axis=1)
    pad = TLAS_PAD * (np.maximum(np.abs(lo), np.abs(hi)).max(axis=1) + (hi - lo).max(axis=1)) + 1e-30
    st.box_lo[idx] = lo - pad[:, None]
    st.box_hi[idx] = hi + pad[:, None]
    tri = st.tri_count[mid] > 0 if len(st.tri_count) else np.zeros(len(idx), bool)
    ok = np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1)
    st.member[idx] = inst.casts_shadow[idx] & (sph | tri) & ok
    st.sphere_of[idx] = sph


def _alloc_nodes(st, n) -> tuple[int, bool]:
    """[node] records for the top level: in place when it fits, else at the tail."""
    grown = False
    if n <= st.tlas_cap and st.tlas_cap:
        return st.tlas_start, False
    start = st.node_tail
    st.node_tail += n
    st.tlas_cap = n
    tex = st.tex["node"]
    if st.node_tail > tex.capacity:
        grown = grow_texture(tex, st.node_tail + 1024)
    tex.used = max(tex.used, st.node_tail)
    return start, grown


def build_tlas(b, st) -> bool:
    """(Re)build the top level over the member instances. True when [node] was resized."""
    mem = np.nonzero(st.member)[0]
    n = mem.size
    if n:
        lo_m, hi_m = st.box_lo[mem], st.box_hi[mem]
        c = (lo_m + hi_m) * 0.5
        cmin, cmax = c.min(axis=0), c.max(axis=0)
        q = np.clip((c - cmin) * (1023.0 / np.maximum((cmax - cmin).max(), 1e-30)), 0, 1023).astype(np.uint32)
        mem = mem[np.argsort(_morton3(q), kind="stable")]
        sb = build_sah(st.box_lo[mem], st.box_hi[mem], [0], [n], leaf_size=1, bins=16, sah_min=RUN_SAH_MIN,
                       spatial_min=SPATIAL_MIN)
        cnt = int(sb.node_count[0])
        lo, hi = st.box_lo[mem].min(axis=0), st.box_hi[mem].max(axis=0)
        margin = FRAME_MARGIN * (hi - lo).max()  # room for moves before the frame must change
        base, inv_s = quant_frame(lo - margin, hi + margin)
        st.tlas_base, st.tlas_inv_s = base[0], float(inv_s[0])
        leaf = sb.leaf_count > 0
        st.tlas_leaf_inst = np.where(leaf, mem[sb.perm[np.maximum(sb.leaf_start, 0)]], -1)
        st.tlas_escape = sb.escape
        left = np.where(leaf, -1, np.arange(cnt) + 1)
        right = np.where(leaf, -1, sb.escape[np.minimum(np.arange(cnt) + 1, cnt - 1)])
        st.tlas_left, st.tlas_right = left, right
        st.tlas_depth = _depths(left, right)
        st.tlas_levels = None
    else:
        cnt = 0
        st.tlas_base, st.tlas_inv_s = np.zeros(3), 1.0
        st.tlas_leaf_inst = np.zeros(0, np.int64)
        st.tlas_escape = st.tlas_left = st.tlas_right = st.tlas_depth = np.zeros(0, np.int64)
        st.tlas_levels = None
    start, grown = _alloc_nodes(st, cnt)
    st.tlas_start, st.tlas_count = start, cnt
    nmin, nmax = _tlas_boxes(st)
    st.tlas_area = float(_areas(nmin, nmax).sum())
    _write_tlas(st, nmin, nmax)
    return grown


def _depths(left, right) -> np.ndarray:
    n = len(left)
    depth = np.zeros(n, np.int64)
    frontier = np.array([0]) if n else np.zeros(0, np.int64)
    d = 0
    while frontier.size:
        depth[frontier] = d
        inner = frontier[left[frontier] >= 0]
        frontier = np.concatenate([left[inner], right[inner]])
        d += 1
    return depth


def _areas(lo, hi):
    e = np.maximum(hi - lo, 0.0)
    return e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]


def _tlas_boxes(st):
    """Node boxes of the top level from the current instance boxes (refit, bottom up; boxes as
    (min, -max) rows so one np.minimum does both)."""
    cnt = st.tlas_count
    if not cnt:
        return np.zeros((0, 3)), np.zeros((0, 3))
    box6 = np.empty((cnt, 6))
    leaf = st.tlas_leaf_inst >= 0
    li = st.tlas_leaf_inst[leaf]
    box6[leaf, :3] = st.box_lo[li]
    box6[leaf, 3:] = -st.box_hi[li]
    if st.tlas_levels is None:  # inner nodes grouped by depth, deepest first
        inner = np.nonzero(~leaf)[0]
        order = inner[np.argsort(-st.tlas_depth[inner], kind="stable")]
        cuts = np.nonzero(np.diff(st.tlas_depth[order]))[0] + 1
        st.tlas_levels = [(k, st.tlas_left[k], st.tlas_right[k]) for k in np.split(order, cuts)]
    for k, l, r in st.tlas_levels:
        box6[k] = np.minimum(box6[l], box6[r])
    return box6[:, :3], -box6[:, 3:]


def _tlas_texels(st, nmin, nmax) -> np.ndarray:
    cnt = st.tlas_count
    inv = np.full(cnt, st.tlas_inv_s)
    qlo, qhi = quantise(nmin, nmax, st.tlas_base[None, :], inv)
    leaf = st.tlas_leaf_inst >= 0
    w = np.where(leaf, LEAF_FLAG | np.maximum(st.tlas_leaf_inst, 0).astype(np.uint32),
                 (st.tlas_escape + st.tlas_start).astype(np.uint32))
    return pack_nodes(qlo, qhi, w.astype(np.uint32))


def _write_tlas(st, nmin, nmax) -> np.ndarray:
    tex = st.tex["node"].linear()
    new = _tlas_texels(st, nmin, nmax)
    old = tex[st.tlas_start:st.tlas_start + st.tlas_count].copy()
    tex[st.tlas_start:st.tlas_start + st.tlas_count] = new
    return np.nonzero((old != new).any(axis=1))[0] + st.tlas_start


def tlas_uniforms(st) -> dict:
    base = np.asarray(st.tlas_base, np.float32)
    inv = np.float32(st.tlas_inv_s)
    return {
        "hs_tlas_base": base,
        "hs_tlas_inv_scale": float(inv),
        "hs_tlas_babs": float(np.abs(base.astype(np.float64) * float(inv)).sum()),
        "hs_tlas_root": int(st.tlas_start),
        "hs_tlas_end": int(st.tlas_start + st.tlas_count),
    }


# ----------------------------------------------------------------------------------- updates --
def _inside_frame(st, idx) -> bool:
    if not st.tlas_count:
        return False
    lo = (st.box_lo[idx] - st.tlas_base) * st.tlas_inv_s
    hi = (st.box_hi[idx] - st.tlas_base) * st.tlas_inv_s
    return bool((lo >= 0).all() and (hi <= QMAX).all())


def _ensure_uvs(b, scene, models, rep: UpdateReport) -> None:
    """Store the UVs of ``models`` that now need them (an instance of theirs got an alpha-cut
    material since the bake): the "uv" texture is created when the bake had none."""
    st = b.bvh
    if b.materials is None:
        return  # no material records baked: a scene with new materials needs a new bake
    need = scene.alpha_models()
    todo = [m for m in models if m < len(need) and need[m] and (st.uv_models is None or not st.uv_models[m])]
    if not todo:
        return
    W = b.config.tex_width
    if st.uv_models is None:
        st.uv_models = np.zeros(len(st.node_count), bool)
        st.tex["uv"] = _new("uv", st.tex["leaf"].capacity, W)
        st.tex["uv"].used = st.leaf_tail
        rep.resized.add("uv")
    for m in todo:
        st.uv_models[m] = True
        # the same build as the baked tree (deterministic): its triangles sit in the same order
        bl = build_blas([scene.models[m]], leaf_size(b.config), np.array([True]))
        tb, tt = int(st.tri_start[m]), int(bl.tri_texels[0])
        if bl.uv4 is not None and tt:
            st.tex["uv"].linear()[tb:tb + tt] = bl.uv4
            rep.ranges += texel_rows("uv", tb, tb + tt, W)


def update_instances(b, scene, indices, rep: UpdateReport | None = None) -> UpdateReport:
    st = b.bvh
    rep = rep or UpdateReport()
    idx = np.unique(np.asarray(indices, np.int64).reshape(-1))
    if idx.size == 0:
        return rep
    if len(scene.instances) != len(st.member):
        raise ValueError("instances were added or removed: bake the scene again")
    W = b.config.tex_width
    old_member = st.member[idx].copy()
    old_uniforms = tlas_uniforms(st)
    old_defines = b.defines
    _ensure_uvs(b, scene, np.unique(scene.instances.model_ids[idx]).tolist(), rep)
    write_instances(b, st, scene, idx)
    rep.ranges += rows_of_texels("leaf", (idx[:, None] * INST_TEXELS + np.arange(INST_TEXELS)).ravel(), W)
    rep.objects += int(idx.size)
    mem = st.member[idx]
    rebuild = bool((mem != old_member).any()) or not _inside_frame(st, idx[mem])
    if not rebuild:
        nmin, nmax = _tlas_boxes(st)
        if float(_areas(nmin, nmax).sum()) > 2.0 * st.tlas_area:
            rebuild = True
        else:
            changed = _write_tlas(st, nmin, nmax)
            rep.ranges += rows_of_texels("node", changed, W)
            rep.nodes_changed += int(changed.size)
    if rebuild:
        grown = build_tlas(b, st)
        rep.regrid = True
        if grown:
            rep.resized.add("node")
        else:
            rep.ranges += texel_rows("node", st.tlas_start, st.tlas_start + st.tlas_count, W)
        rep.nodes_changed += st.tlas_count
    new_uniforms = tlas_uniforms(st)
    if any(not np.array_equal(new_uniforms[k], old_uniforms[k]) for k in new_uniforms):
        rep.uniforms_changed = True
    if b.defines != old_defines:
        rep.defines_changed = True
    rep.ranges = merge_ranges([r for r in rep.ranges if r[0] not in rep.resized])
    return rep


def update_model(b, scene, m: int, rep: UpdateReport) -> UpdateReport:
    st = b.bvh
    W = b.config.tex_width
    M = len(st.node_count)
    if m > M or m >= len(scene.models):
        raise ValueError(f"model id {m} is neither an existing model nor the next new one")
    if m == M:
        for name in ("node_start", "node_count", "node_cap", "tri_start", "tri_cap", "tri_count", "depth", "inv_s"):
            setattr(st, name, np.concatenate([getattr(st, name), [0]]).astype(getattr(st, name).dtype))
        st.base = np.concatenate([st.base, np.zeros((1, 3))])
        st.mbox = np.concatenate([st.mbox, np.zeros((1, 2, 3))])
    uvm = None
    if st.uv_models is not None:
        if m == len(st.uv_models):
            st.uv_models = np.concatenate([st.uv_models, [False]])
        need = scene.alpha_models()
        st.uv_models[m] = bool(need[m]) and b.materials is not None
        uvm = st.uv_models[m:m + 1]
    bl = build_blas([scene.models[m]], leaf_size(b.config), uvm)
    nc, tt = int(bl.node_count[0]), int(bl.tri_texels[0])
    if nc <= st.node_cap[m] and tt <= st.tri_cap[m]:
        nb, tb = int(st.node_start[m]), int(st.tri_start[m])
    else:
        nb, tb = st.node_tail, st.leaf_tail
        st.node_tail += nc
        st.leaf_tail += tt
        st.node_cap[m], st.tri_cap[m] = nc, tt
        _grow(st, "node", st.node_tail, rep)
        _grow(st, "leaf", st.leaf_tail + LEAF_READ, rep)
    st.node_start[m], st.node_count[m] = nb, nc
    st.tri_start[m], st.tri_count[m] = tb, int(bl.tri_count[0])
    st.depth[m] = int(bl.depth[0])
    st.base[m], st.inv_s[m] = bl.base[0], bl.inv_s[0]
    st.mbox[m] = _model_box(scene.models[m], False)
    if nc:
        nodes = bl.nodes.copy()
        _relocate(nodes, np.array([nb]), bl.node_start, bl.node_count, np.array([tb]), bl.tri_start)
        st.tex["node"].linear()[nb:nb + nc] = nodes
        st.tex["leaf"].linear()[tb:tb + tt] = bl.tri4.view(np.uint32)
        if bl.uv4 is not None:
            st.tex["uv"].linear()[tb:tb + tt] = bl.uv4
    rep.ranges += texel_rows("node", nb, nb + nc, W)
    rep.ranges += texel_rows("leaf", tb, tb + tt, W)
    if bl.uv4 is not None:
        rep.ranges += texel_rows("uv", tb, tb + tt, W)
    _ensure_uvs(b, scene, [m], rep)
    users = np.nonzero(scene.instances.model_ids == m)[0] if len(scene.instances) else np.zeros(0, np.int64)
    if users.size:
        update_instances(b, scene, users, rep)
    rep.ranges = merge_ranges([r for r in rep.ranges if r[0] not in rep.resized])
    return rep
