"""A sun's light-space grid: every shadow ray of a hard sun is parallel, so it stays in one
column of a grid laid across the sun's direction, and one lookup finds every caster it can meet.

The casters (world-space triangles in bake space, and the analytic sphere instances) are filed
by their box in the plane across the sun (axes ``ux``, ``uy``) into the cells it covers; each
cell lists its casters by their highest point towards the sun (``key``, the depth along the
direction towards the sun), highest first. A ray from ``o`` towards the sun can meet only casters
whose key is above ``o``'s own depth, so it walks its cell's list in one flat loop until the first
hit or the first key at or below its depth (``shaders/common/scene_sungrid.glsl``; numpy mirror
:func:`trace_sun_grid`).

Exactness: the boxes are widened by ``margin`` (float32 error of the lookups and of the
watertight test, relative to the scene's coordinates) and the keys rounded up by it, so a ray
whose triangle test would report a hit always finds that triangle in its cell; the triangle test
itself is the two-level BVH's (``hs_tri_hit``), on the triangle in bake space instead of model
space, and spheres are tested in model space through the instance record, as the BVH does.

Textures (linear texel index, as every scene texture): ``sg_cell`` u4 x2 (first entry, count)
per cell, in 8 x 8 tiles (row-major tiles, row-major cells within); ``sg_entry`` u4 x3 (caster code, float bits of key, its box
within the cell: 8 bits each of x0, x1, y0, y1 in 1/255 of the cell, rounded outward): a
triangle ``t`` (its vertices at ``sg_tri`` texels 3t..3t+2, f4 x4, xyz) or ``SPHERE_FLAG | i``
(instance ``i``, its record at the two-level BVH's ``[leaf]`` texel 5i).

A grid is built per sun direction (:func:`build_sun_grid`) from the world casters
(:func:`world_casters`, built once per bake); a light whose grid would be too large or too
crowded (:data:`MAX_ENTRIES`, :data:`MAX_CELL`) returns None and keeps the BVH.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .textures import SPHERE_FLAG, TextureData, alloc_texture, f32_bits, f32_up

#: cells per caster aimed at (the grid's cell size follows from the casters' extent)
CELLS_PER_CASTER = 1.0
MIN_CELLS, MAX_SIDE = 64, 4096
MAX_ENTRIES = 24_000_000  # entries over this coarsen the grid (4x fewer cells, up to twice)
MAX_CELL = 16384  # a cell listing more casters than this: the light keeps the BVH (loop budget)
#: relative widening of boxes and keys (x the scene's largest coordinate): a few float32
#: roundings of the lookup (dot products of the origin) and of the watertight test
REL_MARGIN = 2.0 ** -16
TILE_LOG2 = 3
TILE = 1 << TILE_LOG2  # cells are stored in TILE x TILE tiles
SUB = 255  # an entry's box within its cell: 8 bits per side
SLIVER_CELLS = 8  # triangles whose box covers this many cells keep only the cells they reach


@dataclass
class WorldCasters:
    """Shadow casters in bake space (float32 as the GPU holds them): triangles ``tris``
    (T, 3, 3); analytic spheres as instance indices ``sphere_inst`` with world centres and radii
    (conservative: the largest axis scale) for filing; ``scale`` the largest absolute bake-space
    coordinate of any instance's box (casters or not: the receivers)."""

    tris: np.ndarray
    sphere_inst: np.ndarray
    sphere_center: np.ndarray
    sphere_radius: np.ndarray
    scale: float

    @property
    def count(self) -> int:
        return len(self.tris) + len(self.sphere_inst)


def world_casters(scene, origin) -> WorldCasters:
    """Every shadow-casting instance's triangles moved to bake space (float64, then float32), and
    its analytic spheres, instances of one model together."""
    inst = scene.instances
    origin = np.asarray(origin, np.float64)
    n = len(inst.names)
    casting = np.asarray(inst.casts_shadow, bool) if n else np.zeros(0, bool)
    tris = []
    sph = np.zeros(0, np.int64)
    scale = 0.0
    if n:
        mids = inst.model_ids.astype(np.int64)
        sphere = np.asarray(inst.sphere, bool)
        # the largest coordinate of any instance's world box corners (receivers included)
        lo = np.array([scene.models[m].bounds_min for m in range(len(scene.models))], np.float64).reshape(-1, 3)
        hi = np.array([scene.models[m].bounds_max for m in range(len(scene.models))], np.float64).reshape(-1, 3)
        c, e = (lo + hi)[mids] * 0.5, (hi - lo)[mids] * 0.5
        m3 = inst.matrices[:, :3, :3]
        wc = np.einsum("nij,nj->ni", m3, c) + inst.matrices[:, :3, 3] - origin
        we = np.einsum("nij,nj->ni", np.abs(m3), e)
        scale = float(np.max(np.abs(wc) + we)) if n else 0.0
        sph = np.nonzero(casting & sphere)[0]
        mesh = casting & ~sphere
        for m in np.unique(mids[mesh]).tolist():
            model = scene.models[m]
            if not model.triangle_count:
                continue
            idx = np.nonzero(mesh & (mids == m))[0]
            v = model.vertices.astype(np.float64)
            mats = inst.matrices[idx]
            wv = np.einsum("nij,vj->nvi", mats[:, :3, :3], v) + (mats[:, :3, 3] - origin)[:, None, :]
            tris.append(wv[:, model.triangles.astype(np.int64)].reshape(-1, 3, 3).astype(np.float32))
    t = np.concatenate(tris) if tris else np.zeros((0, 3, 3), np.float32)
    sc = np.zeros((0, 3))
    sr = np.zeros(0)
    if len(sph):
        mids = inst.model_ids[sph].astype(np.int64)
        mc = np.array([scene.models[m].sphere_center for m in mids.tolist()], np.float64).reshape(-1, 3)
        mr = np.array([scene.models[m].sphere_radius for m in mids.tolist()], np.float64)
        mats = inst.matrices[sph]
        sc = np.einsum("nij,nj->ni", mats[:, :3, :3], mc) + mats[:, :3, 3] - origin
        sr = mr * np.linalg.norm(mats[:, :3, :3], axis=1).max(axis=1)
    return WorldCasters(t, sph.astype(np.int64), sc, sr, scale)


def sun_basis(direction) -> np.ndarray:
    """(3, 3) rows ux, uy, dz: dz the direction towards the sun as the shader gets it (float32,
    normalised in float64), ux and uy across it."""
    dz = np.asarray(np.asarray(direction, np.float32), np.float64)
    dz = dz / np.linalg.norm(dz)
    a = np.array([1.0, 0.0, 0.0]) if abs(dz[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    ux = np.cross(dz, a)
    ux /= np.linalg.norm(ux)
    uy = np.cross(dz, ux)
    return np.stack([ux, uy, dz])


@dataclass
class SunGrid:
    """One sun's grid: textures, the uniforms and defines its shader code reads."""

    textures: dict
    uniforms: dict
    defines: dict
    cells: tuple
    entries: int
    max_cell: int
    build_ms: float = 0.0

    @property
    def samplers(self) -> dict:
        return {"sg_cell": "hs_sg_cell_tex", "sg_entry": "hs_sg_entry_tex", "sg_tri": "hs_sg_tri_tex"}

    @property
    def nbytes(self) -> int:
        return sum(t.nbytes for t in self.textures.values())


def _texture(name: str, data: np.ndarray, fmt: str, width: int) -> TextureData:
    n, comp = data.shape
    td = alloc_texture(name, max(n, 1), comp, fmt, width)
    td.linear()[:n] = data
    td.used = n
    return td


def caster_boxes(wc: WorldCasters, basis: np.ndarray):
    """Light-space boxes (lo, hi) (N, 3) of triangles then spheres: x, y across the sun, z the
    depth towards it (float64, exact for the float32 vertices up to float64 rounding), and the
    triangles' edge planes across the sun (:func:`edge_planes`)."""
    t = wc.tris
    p0, p1, p2 = (t[:, k].astype(np.float64) @ basis.T for k in range(3))
    lo = np.minimum(np.minimum(p0, p1), p2)
    hi = np.maximum(np.maximum(p0, p1), p2)
    planes = edge_planes(p0[:, :2], p1[:, :2], p2[:, :2])
    if len(wc.sphere_inst):
        c = wc.sphere_center @ basis.T
        r = wc.sphere_radius[:, None]
        lo = np.concatenate([lo, c - r])
        hi = np.concatenate([hi, c + r])
    return lo, hi, planes


def edge_planes(a, b, c):
    """(normals (T, 3, 2), offsets (T, 3)) of the projected triangles' edges, pointing out: a
    point q lies outside edge k where normals[:, k] . q > offsets[:, k]. A triangle seen edge-on
    (no area across the sun) gets zero normals: it is never outside."""
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    sgn = np.sign(area)[:, None]
    normals = np.empty((len(a), 3, 2))
    offsets = np.empty((len(a), 3))
    for k, (p, q) in enumerate(((a, b), (b, c), (c, a))):
        e = q - p
        n = np.stack([e[:, 1], -e[:, 0]], axis=1) * sgn
        normals[:, k] = n
        offsets[:, k] = (n * p).sum(axis=1)
    return normals, offsets


def build_sun_grid(wc: WorldCasters, direction, tex_width: int = 4096,
                   cells_per_caster: float | None = None) -> SunGrid | None:
    """The grid of the sun shining from ``direction`` (towards the sun), or None where it would
    not fit (:data:`MAX_ENTRIES` after coarsening twice, or a cell over :data:`MAX_CELL`)."""
    import time

    t0 = time.perf_counter()
    basis = sun_basis(direction)
    n = wc.count
    margin = REL_MARGIN * max(wc.scale, 1e-6)
    if n == 0:
        lo = hi = np.zeros((0, 3))
        g0, ext = np.zeros(2), np.ones(2)
    else:
        lo, hi, (normals, offsets) = caster_boxes(wc, basis)
        lo = lo - margin
        hi = hi + margin
        g0 = lo[:, :2].min(axis=0)
        ext = np.maximum(hi[:, :2].max(axis=0) - g0, margin)
    if cells_per_caster is None:
        cells_per_caster = CELLS_PER_CASTER
    target = max(MIN_CELLS, cells_per_caster * n)
    cs = float(np.sqrt(ext[0] * ext[1] / target))
    cs = max(cs, float(ext.max()) / MAX_SIDE)
    for _ in range(3):
        nx = int(min(MAX_SIDE, max(1, np.ceil(ext[0] / cs))))
        ny = int(min(MAX_SIDE, max(1, np.ceil(ext[1] / cs))))
        inv = 1.0 / cs
        i0 = np.clip(np.floor((lo[:, :2] - g0) * inv).astype(np.int64), 0, [nx - 1, ny - 1])
        i1 = np.clip(np.floor((hi[:, :2] - g0) * inv).astype(np.int64), 0, [nx - 1, ny - 1])
        cx = i1[:, 0] - i0[:, 0] + 1
        cy = i1[:, 1] - i0[:, 1] + 1
        per = cx * cy
        total = int(per.sum())
        if total <= MAX_ENTRIES:
            break
        cs *= 2.0
    else:
        return None
    # casters highest first: a stable sort by cell keeps that order within every cell
    key = hi[:, 2]
    order = np.argsort(-key, kind="stable")
    per_o = per[order]
    own = np.repeat(order.astype(np.int32), per_o)
    loc = np.arange(total, dtype=np.int32) - np.repeat((np.cumsum(per_o) - per_o).astype(np.int32), per_o)
    cxo = np.repeat(cx[order].astype(np.int32), per_o)
    row = loc // cxo
    cix = np.repeat(i0[order, 0].astype(np.int32), per_o) + (loc - row * cxo)
    ciy = np.repeat(i0[order, 1].astype(np.int32), per_o) + row
    del loc, row, cxo
    # a triangle's box covers cells the triangle does not (a long sliver across the sun): keep
    # only the cells (widened by the margin) that no edge of it leaves outside
    n_tri = len(wc.tris)
    big = (per >= SLIVER_CELLS)
    big[n_tri:] = False
    test = np.nonzero(np.repeat(big[order], per_o))[0]
    if len(test):
        t = own[test]
        half = 0.5 * cs + margin
        px = (cix[test] + 0.5) * cs + g0[0]
        py = (ciy[test] + 0.5) * cs + g0[1]
        out = np.zeros(len(test), bool)
        for k in range(3):
            nxk, nyk = np.ascontiguousarray(normals[:, k, 0]), np.ascontiguousarray(normals[:, k, 1])
            lim = offsets[:, k] + (np.abs(nxk) + np.abs(nyk)) * half   # (per triangle, then gathered)
            out |= nxk[t] * px + nyk[t] * py > lim[t]
        drop = test[out]
        if len(drop):
            keep = np.ones(total, bool)
            keep[drop] = False
            own, cix, ciy = own[keep], cix[keep], ciy[keep]
            total = len(own)
    # cells in 8 x 8 tiles, tile after tile (row-major), row-major within a tile: the cells of
    # neighbouring pixels, and so their lists, lie close together (texel cache)
    ntx, nty = -(-nx // TILE), -(-ny // TILE)
    cell = ((ciy >> TILE_LOG2) * np.int32(ntx) + (cix >> TILE_LOG2)) * np.int32(TILE * TILE) \
        + (ciy & (TILE - 1)) * np.int32(TILE) + (cix & (TILE - 1))
    # each entry's box within its cell, in 1/255 of the cell, rounded outward: a ray outside it
    # skips the caster's fetches
    sub = np.zeros(total, np.uint32)
    for shift, (ci, axis) in enumerate(((cix, 0), (ciy, 1))):
        c0 = g0[axis] + ci * cs
        a = np.clip(np.floor((lo[own, axis] - c0) * (inv * SUB)), 0, SUB).astype(np.uint32)
        b = np.clip(np.ceil((hi[own, axis] - c0) * (inv * SUB)), 0, SUB).astype(np.uint32)
        sub |= (a << np.uint32(16 * shift)) | (b << np.uint32(16 * shift + 8))
    del cix, ciy
    srt = np.argsort(cell, kind="stable")
    cell = cell[srt]
    own = own[srt]
    sub = sub[srt]
    counts = np.bincount(cell, minlength=ntx * nty * TILE * TILE)
    max_cell = int(counts.max()) if total else 0
    if max_cell > MAX_CELL:
        return None
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint32)
    cells = np.stack([start, counts.astype(np.uint32)], axis=1)
    # triangles renumbered in the order the lists first name them (neighbouring cells' casters
    # close together in the texture, too)
    is_tri = own < n_tri
    t_ent = own[is_tri]
    first = np.full(n_tri, total, np.int64)
    pos = np.nonzero(is_tri)[0]
    first[t_ent[::-1]] = pos[::-1]
    tri_order = np.argsort(first, kind="stable")
    new_id = np.empty(n_tri, np.int64)
    new_id[tri_order] = np.arange(n_tri)
    code = own.astype(np.uint32)
    code[is_tri] = new_id[t_ent].astype(np.uint32)
    if len(wc.sphere_inst):
        sp = own >= n_tri
        code[sp] = SPHERE_FLAG | wc.sphere_inst[own[sp] - n_tri].astype(np.uint32)
    entries = np.stack([code, f32_bits(f32_up(key[own])), sub], axis=1) if total else \
        np.zeros((0, 3), np.uint32)
    tri = np.zeros((max(n_tri, 1) * 3, 4), np.float32)
    tri[: n_tri * 3, :3] = wc.tris[tri_order].reshape(-1, 3)
    textures = {"sg_cell": _texture("sg_cell", cells, "u4", tex_width),
                "sg_entry": _texture("sg_entry", entries, "u4", tex_width),
                "sg_tri": _texture("sg_tri", tri, "f4", tex_width)}
    b32 = basis.astype(np.float32)
    uniforms = {"hs_sg_ux": b32[0], "hs_sg_uy": b32[1], "hs_sg_dz": b32[2],
                "hs_sg_base": g0.astype(np.float32), "hs_sg_inv_cell": np.float32(inv),
                "hs_sg_dims": np.array([nx, ny], np.int32), "hs_sg_tiles_x": np.int32(ntx)}
    defines = {"HS_SUN_GRID": 1}
    if n_tri:
        defines["HS_SG_TRIS"] = 1
    if len(wc.sphere_inst):
        defines["HS_SG_SPHERES"] = 1
    return SunGrid(textures, uniforms, defines, (nx, ny), total, max_cell,
                   (time.perf_counter() - t0) * 1e3)
