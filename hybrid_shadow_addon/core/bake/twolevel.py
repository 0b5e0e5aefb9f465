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
``TLAS_PAD`` relative, quantised on one grid over the scene. Moves refit the top level: the
moved leaves and their ancestors only, re-packing just those texels (rebuild when the boxes leave
the grid, membership changes or the SAH area doubles); a model edit rebuilds that model's tree (in
place when it fits) and refits. The bake builds the top-level tree on a second thread while the
model trees build (it needs only the model boxes).
"""
from __future__ import annotations

import threading
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
    # by component (3, N) C order: the per-node scale then runs along the contiguous axis
    inv = np.asarray(inv_s, np.float64)
    out = []
    for v, up in ((nmin, False), (nmax, True)):
        t = np.subtract(np.asarray(v).T, np.asarray(base).T, dtype=np.float64, order="C")
        t *= inv
        if up:
            np.ceil(t, out=t)
        np.clip(t, 0, QMAX, out=t)
        out.append(t.astype(np.uint32).T)  # truncation: the floor of the clipped lower bound
    return out[0], out[1]


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


def build_blas(models, leaf_size: int = 4, uv_models=None, alloc=None) -> BlasBuild:
    """Model trees of ``models``; ``uv_models`` (bool per model): pack those models' UVs into
    ``uv4`` at the same texels as their triangles (the any-hit alpha test reads them).
    ``alloc(texels, want_uv)``: where to write ``tri4`` / ``uv4`` (zeroed (texels, 4) float32
    views, e.g. into the textures; the second None unless ``want_uv``); default new arrays."""
    M = len(models)
    L = int(min(max(leaf_size, 1), 4))
    tc = np.array([m.triangle_count for m in models], np.int64)
    total = int(tc.sum())
    tris = np.empty((total, 3, 3), np.float32)
    want_uv = uv_models is not None and bool(np.any(uv_models))
    uvs = np.zeros((total, 3, 2), np.float32) if want_uv else None
    t0 = np.concatenate([[0], np.cumsum(tc)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    third = np.float32(1.0 / 3.0)
    t9 = tris.reshape(total, 9)
    tmin = np.empty((3, total), np.float32)  # triangle boxes by component (while the model's
    tmax = np.empty((3, total), np.float32)  # triangles are in cache)
    for mi, (m, s0) in enumerate(zip(models, t0.tolist())):
        T = m.triangle_count
        if not T:
            continue
        tr = m.vertices.take(m.triangles.ravel(), axis=0).reshape(T, 3, 3)
        cen = (tr[:, 0] + tr[:, 1] + tr[:, 2]) * third
        cmin = np.array([cen[:, k].min() for k in range(3)], np.float32)  # (a column is faster
        cmax = np.array([cen[:, k].max() for k in range(3)], np.float32)  # than min(axis=0))
        span = np.maximum(cmax - cmin, np.float32(1e-30))
        q = np.clip((cen - cmin) * (np.float32(1023.0) / span), 0, 1023).astype(np.uint32)
        order = np.argsort(_morton3(q), kind="stable")
        np.take(tr, order, axis=0, out=tris[s0:s0 + T])
        tm = t9[s0:s0 + T]
        for k in range(3):
            np.minimum(np.minimum(tm[:, k], tm[:, 3 + k]), tm[:, 6 + k], out=tmin[k, s0:s0 + T])
            np.maximum(np.maximum(tm[:, k], tm[:, 3 + k]), tm[:, 6 + k], out=tmax[k, s0:s0 + T])
        if want_uv and uv_models[mi] and m.uvs is not None:
            uvs[s0:s0 + T] = m.uvs[order]
    # clusters of L consecutive triangles per model
    ncl = -(-tc // L)
    c0 = np.concatenate([[0], np.cumsum(ncl)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    mod = np.repeat(np.arange(M), ncl)
    j = np.arange(int(ncl.sum())) - c0[mod]
    cl_tri0 = t0[mod] + j * L
    cl_cnt = np.minimum(L, tc[mod] - j * L)
    # cluster boxes: min(min(t0, t1), ..) like a reduceat over the cluster (its last triangle
    # repeats in a short cluster: min is idempotent)
    if len(cl_tri0):
        cmn = np.take(tmin, cl_tri0, axis=1)
        cmx = np.take(tmax, cl_tri0, axis=1)
        for jj in range(1, L):
            nxt = cl_tri0 + np.minimum(jj, cl_cnt - 1)
            np.minimum(cmn, np.take(tmin, nxt, axis=1), out=cmn)
            np.maximum(cmx, np.take(tmax, nxt, axis=1), out=cmx)
        cmn, cmx = np.ascontiguousarray(cmn.T), np.ascontiguousarray(cmx.T)
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
    n_tex = int(ltex.sum())
    if alloc is None:
        tri4 = np.zeros((n_tex, 4), np.float32)
        uv4 = np.zeros((n_tex, 4), np.float32) if want_uv else None
    else:
        tri4, uv4 = alloc(n_tex, want_uv)
    ltri0 = cl_tri0[lcl]
    for cnt in np.unique(lcnt).tolist():  # leaves of ``cnt`` triangles: blocks of ceil(9 cnt / 4) texels
        sel = np.nonzero(lcnt == cnt)[0]
        tt = -(-cnt * TRI4_FLOATS // 4)
        t_first = ltri0[sel]
        _put_blocks(tri4, lfirst[sel], t9, t_first, cnt, TRI4_FLOATS, tt)
        if want_uv:
            _put_blocks(uv4, lfirst[sel], uvs.reshape(total, 6), t_first, cnt, 6, tt)
    # packed nodes
    qlo, qhi = quantise(b.node_min, b.node_max, np.repeat(base.T, b.node_count, axis=1).T,
                        np.repeat(inv_s, b.node_count))
    w = np.where(leaf, 0, b.escape).astype(np.uint32)
    lpay = ((lfirst - tri_start[lmod]) << 3) | lcnt
    w[leaf] = LEAF_FLAG | lpay.astype(np.uint32)
    return BlasBuild(b, b.node_start, b.node_count, tri_start, tri_texels_m, tc, b.depth, base, inv_s,
                     pack_nodes(qlo, qhi, w), tri4, uv4)


def _run(a, step) -> bool:
    """``a`` (1-D int) is ``a[0] + step * arange(len(a))``."""
    n = len(a)
    return n == 1 or (int(a[-1] - a[0]) == (n - 1) * step and bool((np.diff(a) == step).all()))


def _put_blocks(tex4, first, rows, row0, cnt, per, tt) -> None:
    """Leaf blocks: rows ``row0[i] .. row0[i] + cnt`` of ``rows`` (R, per) float32, back to back,
    at texels ``first[i] ..`` of ``tex4`` (texels, 4), a block spanning ``tt`` texels (the tail
    stays zero). Slices when both sides run back to back, else a scatter of whole texels (as
    uint64 pairs: bit-exact)."""
    n = len(first)
    if not n:
        return
    if _run(first, tt) and _run(row0, cnt):
        dst = tex4[first[0]:first[0] + n * tt].reshape(n, tt * 4)
        dst[:, :cnt * per] = rows[row0[0]:row0[0] + n * cnt].reshape(n, cnt * per)
        return
    blk = np.zeros((n, tt * 4), np.float32)
    blk[:, :cnt * per] = np.take(rows, row0[:, None] + np.arange(cnt), axis=0).reshape(n, cnt * per)
    dst = ((first[:, None] + np.arange(tt)) * 2)[:, :, None] + np.arange(2)
    tex4.view(np.uint64).reshape(-1)[dst.reshape(-1)] = blk.view(np.uint64).reshape(-1)


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
    tlas_parent: np.ndarray = None  # local parent index (-1 for the root)
    tlas_node_of: np.ndarray = None  # (N,) tlas leaf of each member instance, -1 none
    tlas_lo: np.ndarray = None  # (count, 3) float64 node boxes as last refit (exact unions)
    tlas_hi: np.ndarray = None
    tlas_areas: np.ndarray = None  # (count,) their SAH areas
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
    uv_models = scene.alpha_models() if b.materials is not None and b.materials.cuts_shadows else None
    inst_end = n * INST_TEXELS
    st.tri_count = np.array([m.triangle_count for m in models], np.int64)
    st.mbox = np.zeros((M, 2, 3))
    for m in range(M):
        st.mbox[m] = _model_box(models[m], False)
    st.member = np.zeros(n, bool)
    st.sphere_of = np.zeros(n, bool)
    st.box_lo = np.zeros((n, 3))
    st.box_hi = np.zeros((n, 3))

    # the instance boxes and the top-level tree need only the model boxes: a second thread
    # builds them while this one builds the model trees (numpy releases the GIL in its loops;
    # the two touch disjoint state)
    top = {}

    def plan_top():
        try:
            t1 = time.perf_counter()
            if n:
                write_instance_boxes(b, st, scene, np.arange(n))
            top["count"] = _plan_tlas(st)
            top["ms"] = (time.perf_counter() - t1) * 1e3
        except BaseException as e:  # re-raised by the bake
            top["error"] = e

    def alloc(n_tex, want_uv):  # the triangles go straight into [leaf] (and the UVs into "uv")
        tail = inst_end + n_tex
        st.tex["leaf"] = _new("leaf", tail + LEAF_READ, W)
        uv4 = None
        if want_uv:
            st.tex["uv"] = _new("uv", st.tex["leaf"].capacity, W)
            uv4 = st.tex["uv"].linear()[inst_end:tail]
        return st.tex["leaf"].linear()[inst_end:tail].view(np.float32), uv4

    worker = threading.Thread(target=plan_top, name="hybrid-shadows-tlas", daemon=True)
    t0 = time.perf_counter()
    worker.start()
    try:
        bl = build_blas(models, leaf_size(cfg), uv_models, alloc)
        st.blas_ms = (time.perf_counter() - t0) * 1e3
    finally:
        worker.join()
    if "error" in top:
        raise top["error"]
    t0 = time.perf_counter()
    st.node_start = bl.node_start.copy()
    st.node_count = bl.node_count.copy()
    st.node_cap = bl.node_count.copy()
    st.tri_start = bl.tri_start + inst_end
    st.tri_cap = bl.tri_texels.copy()
    st.depth = bl.depth.copy()
    st.base, st.inv_s = bl.base.copy(), bl.inv_s.copy()
    st.node_tail = int(bl.node_count.sum())
    st.leaf_tail = inst_end + int(bl.tri_texels.sum())
    st.tex["leaf"].used = st.leaf_tail
    if bl.uv4 is not None:
        st.uv_models = np.asarray(uv_models, bool).copy()
        st.tex["uv"].used = st.leaf_tail
    # [node]: model trees, then the top level (with spare room)
    ncast = int(scene.instances.casts_shadow.sum()) if n else 0
    spare = max(1024, int(0.25 * (st.node_tail + 2 * ncast)))
    st.tex["node"] = _new("node", st.node_tail + 2 * ncast + spare, W)
    st.tex["node"].used = st.node_tail
    if st.node_tail:
        nodes = st.tex["node"].linear()[: st.node_tail]
        nodes[:] = bl.nodes
        _relocate(nodes, st.node_start, bl.node_start, bl.node_count, st.tri_start, bl.tri_start)
    if n:
        write_instance_records(b, st, scene, np.arange(n))
    _place_tlas(st, top["count"])
    st.tlas_ms = top["ms"] + (time.perf_counter() - t0) * 1e3  # (its tree overlaps the model trees)
    return st


def _relocate(nodes, node_base, local_start, local_count, tri_base, local_tri):
    """Local escapes / leaf payloads of each model's nodes -> absolute indices (in place)."""
    # (uint32 arithmetic wraps like the int64 sums cast to uint32; payload + (tri_base << 3)
    # keeps the count bits)
    def per_node(v):
        return np.repeat((np.asarray(v, np.int64) % 2 ** 32).astype(np.uint32), local_count)
    w = nodes[:, 3]
    leaf = (w & LEAF_FLAG) != 0
    w_inner = w + per_node(np.asarray(node_base, np.int64) - local_start)
    pay = (w & np.uint32(0x7FFFFFFF)) + per_node(np.asarray(tri_base, np.int64) << 3)
    nodes[:, 3] = np.where(leaf, LEAF_FLAG | pay, w_inner)


def _model_box(model, sphere: bool) -> np.ndarray:
    if sphere:
        c = model.sphere_center.astype(np.float64)
        r = float(f32_up(model.sphere_radius))
        return np.stack([c - r, c + r])
    return np.stack([model.bounds_min.astype(np.float64), model.bounds_max.astype(np.float64)])


def write_instances(b, st, scene, idx) -> None:
    """[leaf] instance records and world boxes of instances ``idx``."""
    write_instance_records(b, st, scene, idx)
    write_instance_boxes(b, st, scene, idx)


def _sphere_frames(scene, mid, sph) -> np.ndarray:
    """(count of ``sph``, 4) float32 model spheres (centre, radius rounded up) of the analytic
    sphere instances among model ids ``mid``."""
    ms = np.unique(mid[sph])
    sp = np.array([np.concatenate([scene.models[m].sphere_center, f32_up([scene.models[m].sphere_radius])])
                   for m in ms.tolist()], np.float32).reshape(-1, 4)
    return sp[np.searchsorted(ms, mid[sph])]


def write_instance_records(b, st, scene, idx) -> None:
    """[leaf] instance records of instances ``idx`` (needs the model trees' places)."""
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
    if sph.any():
        frame[sph] = _sphere_frames(scene, mid, sph)
    block[:, 16:20] = f32_bits(frame)
    rec[idx] = block


def write_instance_boxes(b, st, scene, idx) -> None:
    """World boxes (bake space, padded) and top-level membership of instances ``idx`` (needs
    only the model boxes ``st.mbox`` and triangle counts ``st.tri_count``)."""
    inst = scene.instances
    idx = np.asarray(idx, np.int64)
    mid = inst.model_ids[idx].astype(np.int64)
    sph = inst.sphere[idx]
    box = np.empty((len(idx), 2, 3))
    box[:] = st.mbox[mid] if len(st.mbox) else 0.0
    if sph.any():
        sp = _sphere_frames(scene, mid, sph)
        c, r = sp[:, 0:3].astype(np.float64), sp[:, 3:4].astype(np.float64)
        box[sph, 0], box[sph, 1] = c - r, c + r
    # world boxes of the model box corners (bake space), padded: corner k maps to
    # ((R[i,0] p0 + R[i,2] p2) + R[i,1] p1 + t_i) - origin_i (the order np.einsum sums in); every
    # rounding step is monotone in each term, so the min / max over the 8 corners is that sum of
    # the per-term min / max (bit for bit, without the (n, 8, 3) corner array)
    Mx = inst.matrices[idx]
    R = Mx[:, :3, :3]
    ta = R * box[:, None, 0, :]
    tb = R * box[:, None, 1, :]
    mn = np.minimum(ta, tb)
    mx = np.maximum(ta, tb)
    t = Mx[:, :3, 3]
    lo = ((((0.0 + mn[:, :, 0]) + mn[:, :, 2]) + mn[:, :, 1]) + t) - b.origin
    hi = ((((0.0 + mx[:, :, 0]) + mx[:, :, 2]) + mx[:, :, 1]) + t) - b.origin
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
    return _place_tlas(st, _plan_tlas(st))


def _place_tlas(st, cnt) -> bool:
    """[node] records for the planned top level of ``cnt`` nodes, and its texels. True when
    [node] was resized."""
    start, grown = _alloc_nodes(st, cnt)
    st.tlas_start, st.tlas_count = start, cnt
    _write_tlas(st)
    return grown


def _plan_tlas(st) -> int:
    """The top-level tree over the member instances: shape, frame, boxes and areas (no [node]
    texels yet). Returns its node count."""
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
        lo, hi = sb.node_min[0], sb.node_max[0]  # the root: the exact union of the member boxes
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
        inner = np.nonzero(~leaf)[0]
        st.tlas_parent = np.full(cnt, -1, np.int64)
        st.tlas_parent[left[inner]] = inner
        st.tlas_parent[right[inner]] = inner
        st.tlas_lo, st.tlas_hi = sb.node_min, sb.node_max  # the exact unions a refit gives
    else:
        cnt = 0
        st.tlas_base, st.tlas_inv_s = np.zeros(3), 1.0
        st.tlas_leaf_inst = np.zeros(0, np.int64)
        st.tlas_escape = st.tlas_left = st.tlas_right = st.tlas_depth = np.zeros(0, np.int64)
        st.tlas_parent = np.zeros(0, np.int64)
        st.tlas_lo, st.tlas_hi = np.zeros((0, 3)), np.zeros((0, 3))
    st.tlas_node_of = np.full(len(st.member), -1, np.int64)
    lf = np.nonzero(st.tlas_leaf_inst >= 0)[0]
    st.tlas_node_of[st.tlas_leaf_inst[lf]] = lf
    st.tlas_areas = _areas(st.tlas_lo, st.tlas_hi)
    st.tlas_area = float(st.tlas_areas.sum())
    return cnt


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


def _refit(st, idx) -> np.ndarray:
    """Refit the top level after instances ``idx`` got new boxes: their leaves and every
    ancestor, deepest first (the other nodes keep their boxes). Returns the refitted nodes
    (local, ascending)."""
    nodes = st.tlas_node_of[idx]
    nodes = np.unique(nodes[nodes >= 0])
    if not nodes.size:
        return nodes
    li = st.tlas_leaf_inst[nodes]
    st.tlas_lo[nodes] = st.box_lo[li]
    st.tlas_hi[nodes] = st.box_hi[li]
    anc = []
    f = st.tlas_parent[nodes]
    f = f[f >= 0]
    while f.size:
        f = np.unique(f)
        anc.append(f)
        f = st.tlas_parent[f]
        f = f[f >= 0]
    if anc:
        a = np.unique(np.concatenate(anc))
        dep = st.tlas_depth[a]
        o = np.argsort(-dep, kind="stable")
        a, dep = a[o], dep[o]
        for k in np.split(a, np.nonzero(np.diff(dep))[0] + 1):
            lc, rc = st.tlas_left[k], st.tlas_right[k]
            st.tlas_lo[k] = np.minimum(st.tlas_lo[lc], st.tlas_lo[rc])
            st.tlas_hi[k] = np.maximum(st.tlas_hi[lc], st.tlas_hi[rc])
        nodes = np.union1d(nodes, a)
    st.tlas_areas[nodes] = _areas(st.tlas_lo[nodes], st.tlas_hi[nodes])
    return nodes


def _tlas_texels(st, nodes) -> np.ndarray:
    """Packed [node] texels of top-level nodes ``nodes`` (local indices, or a slice)."""
    lo, hi = st.tlas_lo[nodes], st.tlas_hi[nodes]
    inv = np.full(len(lo), st.tlas_inv_s)
    qlo, qhi = quantise(lo, hi, st.tlas_base[None, :], inv)
    li = st.tlas_leaf_inst[nodes]
    w = np.where(li >= 0, LEAF_FLAG | np.maximum(li, 0).astype(np.uint32),
                 (st.tlas_escape[nodes] + st.tlas_start).astype(np.uint32))
    return pack_nodes(qlo, qhi, w.astype(np.uint32))


def _write_tlas(st, nodes=None) -> np.ndarray:
    """Write the texels of top-level nodes ``nodes`` (local, ascending; None: all); returns the
    [node] indices whose texels changed."""
    tex = st.tex["node"].linear()
    if nodes is None:
        nodes = slice(0, st.tlas_count)
        pos = np.arange(st.tlas_start, st.tlas_start + st.tlas_count)
    else:
        pos = st.tlas_start + nodes
    new = _tlas_texels(st, nodes)
    old = tex[pos]
    tex[pos] = new
    return pos[(old != new).any(axis=1)]


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
        refit = _refit(st, idx)
        if float(st.tlas_areas.sum()) > 2.0 * st.tlas_area:
            rebuild = True
        else:
            changed = _write_tlas(st, refit)
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
