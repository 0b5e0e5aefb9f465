"""The model trees of the two-level BVH (its bottom level): SAH trees over Morton-ordered
clusters of triangles, boxes quantised to 16 bits on a per-model grid, packed for [node] and
[leaf] of ``shaders/common/scene_bvh.glsl`` (see :mod:`.twolevel` for the whole structure).

Triangles are Morton-sorted per model and cut into clusters of ``leaf_size`` consecutive
triangles; the clusters are the leaves of a tree whose nodes of more than ``BLAS_SPATIAL_MIN``
clusters split by spatially binned SAH (``sah.build_sah``: 8 bins along the longest axis of the
clusters' centroids), smaller ones at the middle of their Morton order. Node boxes are
quantised on a per-model grid (origin ``base``, power-of-two step ``1 / inv_s``), floor / ceil of
the exact float64 union, so the decoded box always holds its triangles.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...progress import checkpoint
from ..bvh import _morton3
from ..sah import build_sah
from ..textures import f32_down, f32_up

QMAX = 65535
QSPAN = 65000.0  # quanta a box spans at most (room for floor / ceil and the base rounding)
LEAF_FLAG = np.uint32(1 << 31)
BLAS_SPATIAL_MIN = 8  # model-tree nodes larger than this (clusters) split by spatially binned SAH
RUN_SAH_MIN = 32  # nodes larger than this split by SAH over runs of their Morton order
FRAME_MARGIN = 1.0 / 16.0  # top-level quantisation frame: scene box + this fraction per side
TLAS_PAD = 2.0 ** -18  # relative padding of the top-level boxes (float32 inverse matrices)
INST_TEXELS = 5  # [leaf] instance record: bits(inverse rows 0..2), (tree root, tree end,
#                 model | SPHERE_FLAG, 0), bits(quant base xyz, inv_s) or bits(model sphere)
NODE_TEXELS = 1  # [node] u4: quantised box (3 x 2 x 16 bits), escape or LEAF_FLAG | payload
TRI4_FLOATS = 9  # [leaf] triangles: a leaf's triangles back to back, 9 float bits each
LEAF_READ = 9  # texels the shader reads from any [leaf] record start (the tail is padded)

FORMATS = {"node": (4, "u4"), "leaf": (4, "u4"), "uv": (4, "f4"), "wide": (4, "u4")}
#: "uv" (UVs at the [leaf] texels of alpha-cut models) and "wide" (:mod:`.wide`) only when present
NAMES = tuple(FORMATS)


def leaf_size(config) -> int:
    """Triangles per model leaf (``BVHConfig.leaf_size``, 1..4)."""
    return int(min(max(int(config.bvh.leaf_size), 1), 4))


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


def _grid_cells(t9) -> np.ndarray:
    """(T, 3) uint32 cells of the triangles' centroids (``t9``: (T, 9) vertex coordinates) on a
    1024^3 grid over their box; by component (1-D passes: ops on (T, 3) arrays are slow)."""
    T = len(t9)
    third = np.float32(1.0 / 3.0)
    cen = np.empty((3, T), np.float32)
    for k in range(3):
        np.add(t9[:, k], t9[:, 3 + k], out=cen[k])
        cen[k] += t9[:, 6 + k]
        cen[k] *= third
    cmin = cen.min(axis=1)
    span = np.maximum(cen.max(axis=1) - cmin, np.float32(1e-30))
    sc = np.float32(1023.0) / span
    q = np.empty((3, T), np.uint32)
    for k in range(3):
        x = cen[k] - cmin[k]
        x *= sc[k]
        q[k] = np.clip(x, 0, 1023, out=x)  # (the cast truncates, as astype)
    return q.T


#: the Morton codes of (0, 0, i): the bits of i (< 1024) spread to every third bit
_SPREAD = _morton3(np.stack([np.zeros(1024, np.uint32), np.zeros(1024, np.uint32), np.arange(1024)], 1))


def morton_order(q) -> np.ndarray:
    """The stable order of the 30-bit Morton codes of ``q`` ((N, 3) integers in [0, 1023], the
    bits spread by a table): ``np.argsort(codes, kind="stable")`` as two 16-bit passes (numpy's
    stable sort of 16-bit integers is a radix sort; of wider ones a merge sort)."""
    code = np.take(_SPREAD, q[:, 0]) << np.uint32(2)
    code |= np.take(_SPREAD, q[:, 1]) << np.uint32(1)
    code |= np.take(_SPREAD, q[:, 2])
    lo = (code & np.uint32(0xFFFF)).astype(np.uint16)
    hi = (code >> np.uint32(16)).astype(np.uint16)
    order = np.argsort(lo, kind="stable")
    return order[np.argsort(hi[order], kind="stable")]


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


def build_blas(models, leaf_size: int = 4, uv_models=None, alloc=None, spatial_min: int | None = None) -> BlasBuild:
    """Model trees of ``models``; ``uv_models`` (bool per model): pack those models' UVs into
    ``uv4`` at the same texels as their triangles (the any-hit alpha test reads them).
    ``alloc(texels, want_uv)``: where to write ``tri4`` / ``uv4`` (zeroed (texels, 4) float32
    views, e.g. into the textures; the second None unless ``want_uv``); default new arrays.
    ``spatial_min``: nodes of more clusters split by spatially binned SAH (None:
    :data:`BLAS_SPATIAL_MIN`; 0: SAH between runs of the Morton order only, the builder before)."""
    M = len(models)
    L = int(min(max(leaf_size, 1), 4))
    tc = np.array([m.triangle_count for m in models], np.int64)
    total = int(tc.sum())
    tris = np.empty((total, 3, 3), np.float32)
    want_uv = uv_models is not None and bool(np.any(uv_models))
    uvs = np.zeros((total, 3, 2), np.float32) if want_uv else None
    t0 = np.concatenate([[0], np.cumsum(tc)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    t9 = tris.reshape(total, 9)  # the triangles in model order
    morton = np.empty(total, np.int64)  # the triangle at each place of its model's Morton order
    tmin = np.empty((3, total), np.float32)  # triangle boxes by component (while the model's
    tmax = np.empty((3, total), np.float32)  # triangles are in cache)
    for mi, (m, s0) in enumerate(zip(models, t0.tolist())):
        checkpoint()
        T = m.triangle_count
        if not T:
            continue
        tm = t9[s0:s0 + T]
        np.take(m.vertices, m.triangles.ravel(), axis=0, out=tm.reshape(3 * T, 3))
        checkpoint()
        order = morton_order(_grid_cells(tm))
        np.add(order, s0, out=morton[s0:s0 + T])
        checkpoint()
        for k in range(3):
            np.minimum(np.minimum(tm[:, k], tm[:, 3 + k]), tm[:, 6 + k], out=tmin[k, s0:s0 + T])
            np.maximum(np.maximum(tm[:, k], tm[:, 3 + k]), tm[:, 6 + k], out=tmax[k, s0:s0 + T])
        if want_uv and uv_models[mi] and m.uvs is not None:
            uvs[s0:s0 + T] = m.uvs
    # clusters of L consecutive triangles (in Morton order) per model
    ncl = -(-tc // L)
    c0 = np.concatenate([[0], np.cumsum(ncl)[:-1]]).astype(np.int64) if M else np.zeros(0, np.int64)
    mod = np.repeat(np.arange(M), ncl)
    j = np.arange(int(ncl.sum())) - c0[mod]
    cl_tri0 = t0[mod] + j * L
    cl_cnt = np.minimum(L, tc[mod] - j * L)
    # cluster boxes: min(min(t0, t1), ..) like a reduceat over the cluster (its last triangle
    # repeats in a short cluster: min is idempotent)
    if len(cl_tri0):
        tri = np.take(morton, cl_tri0)
        cmn = np.take(tmin, tri, axis=1)
        cmx = np.take(tmax, tri, axis=1)
        for jj in range(1, L):
            checkpoint()
            tri = np.take(morton, cl_tri0 + np.minimum(jj, cl_cnt - 1))
            np.minimum(cmn, np.take(tmin, tri, axis=1), out=cmn)
            np.maximum(cmx, np.take(tmax, tri, axis=1), out=cmx)
    else:
        cmn = cmx = np.zeros((3, 0), np.float32)
    checkpoint()
    sm = BLAS_SPATIAL_MIN if spatial_min is None else int(spatial_min)
    tree = build_sah(cmn.T, cmx.T, c0, ncl, leaf_size=1, bins=8, sah_min=RUN_SAH_MIN, spatial_min=sm)
    checkpoint()
    # model frames
    lo = np.zeros((M, 3))
    hi = np.zeros((M, 3))
    has = ncl > 0
    if has.any():
        lo[has] = np.minimum.reduceat(cmn, c0[has], axis=1).T
        hi[has] = np.maximum.reduceat(cmx, c0[has], axis=1).T
    base, inv_s = quant_frame(lo, hi)
    # triangles in leaf order; a leaf = one cluster, ceil(9 c / 4) texels
    nmod = np.repeat(np.arange(M), tree.node_count)
    leaf = tree.leaf_count > 0
    lcl = tree.perm[tree.leaf_start[leaf]]  # cluster of each leaf, leaves in pre-order
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
        checkpoint()
        sel = np.nonzero(lcnt == cnt)[0]
        tt = -(-cnt * TRI4_FLOATS // 4)
        tri = np.take(morton, (ltri0[sel, None] + np.arange(cnt)).reshape(-1))  # the leaves' triangles
        _put_blocks(tri4, lfirst[sel], t9, tri, cnt, TRI4_FLOATS, tt)
        if want_uv:
            _put_blocks(uv4, lfirst[sel], uvs.reshape(total, 6), tri, cnt, 6, tt)
    checkpoint()
    # packed nodes
    qlo, qhi = quantise(tree.node_min, tree.node_max, np.repeat(base.T, tree.node_count, axis=1).T,
                        np.repeat(inv_s, tree.node_count))
    checkpoint()
    w = np.where(leaf, 0, tree.escape).astype(np.uint32)
    lpay = ((lfirst - tri_start[lmod]) << 3) | lcnt
    w[leaf] = LEAF_FLAG | lpay.astype(np.uint32)
    nodes = pack_nodes(qlo, qhi, w)
    checkpoint()
    return BlasBuild(tree, tree.node_start, tree.node_count, tri_start, tri_texels_m, tc, tree.depth, base, inv_s,
                     nodes, tri4, uv4)


def _run(a, step) -> bool:
    """``a`` (1-D int) is ``a[0] + step * arange(len(a))``."""
    n = len(a)
    return n == 1 or (int(a[-1] - a[0]) == (n - 1) * step and bool((np.diff(a) == step).all()))


def _put_blocks(tex4, first, rows, ri, cnt, per, tt) -> None:
    """Leaf blocks: rows ``ri[cnt i:cnt (i + 1)]`` of ``rows`` (R, per) float32, back to back, at
    texels ``first[i] ..`` of ``tex4`` (texels, 4, zeroed), a block spanning ``tt`` texels (the
    tail stays zero). Slices where the blocks land back to back, else a scatter of whole texels
    (as uint64 pairs: bit-exact)."""
    n = len(first)
    if not n:
        return
    if _run(ri, 1):
        src = rows[ri[0]:ri[0] + n * cnt].reshape(n, cnt * per)
    else:
        src = np.take(rows, ri, axis=0).reshape(n, cnt * per)
    # the blocks land in runs of back-to-back texels (a tree's leaves of one size, broken where
    # a leaf of another size sits): a slice per run, unless the runs are short
    cut = np.flatnonzero(np.diff(first) != tt) + 1
    if len(cut) <= n // 16:
        for a, b in zip([0, *cut.tolist()], [*cut.tolist(), n]):
            tex4[first[a]:first[a] + (b - a) * tt].reshape(b - a, tt * 4)[:, :cnt * per] = src[a:b]
        return
    blk = np.zeros((n, tt * 4), np.float32)
    blk[:, :cnt * per] = src
    dst = ((first[:, None] + np.arange(tt)) * 2)[:, :, None] + np.arange(2)
    tex4.view(np.uint64).reshape(-1)[dst.reshape(-1)] = blk.view(np.uint64).reshape(-1)


def relocate_nodes(nodes, node_base, local_start, local_count, tri_base, local_tri):
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


def model_box(model, sphere: bool) -> np.ndarray:
    """(2, 3) float64 model-space box of a mesh (or of its bounding sphere)."""
    if sphere:
        c = model.sphere_center.astype(np.float64)
        r = float(f32_up(model.sphere_radius))
        return np.stack([c - r, c + r])
    return np.stack([model.bounds_min.astype(np.float64), model.bounds_max.astype(np.float64)])

