"""Light-space grids of hard lights: every shadow ray of a hard light lies on one line through
the light (a sun's rays are parallel; a point, spot or hard area light's rays all end at its
centre), so each ray stays in one cell of a grid over the light's directions, and one lookup
finds every caster it can meet.

- A **sun**: a grid laid across its direction (axes ``ux``, ``uy``); a ray's cell is its origin's
  place across the sun. Casters are filed by their box across the sun, each cell lists them
  highest towards the sun first; key = the caster's highest depth towards the sun, and a ray from
  depth ``s`` can meet only casters whose key lies above ``s``.
- A **local** light at ``L``: a cube of six faces of R x R cells over the directions from ``L``
  (a ray from ``o`` has direction ``o - L``: major axis = face, the other two over it = the cell).
  A caster is filed on each face by the box of its projection (the triangle clipped to the face's
  side of the light first, so that it projects to a bounded polygon); key = minus the caster's
  least depth along the face's axis, so that the lists again run highest key first and a ray from
  ``o`` (depth ``z_o`` along the axis) can meet only casters whose key lies above ``-z_o``.

A ray walks its cell's list in one flat loop (``shaders/common/scene_lightgrid.glsl``; numpy
mirror ``core/oracle/tracer/lightgrid.py`` :func:`trace_light_grid`) until the first hit or the first key at
or below its own. Each entry also holds its caster's box within the cell (1/255 of the cell,
rounded outward): a ray outside it skips the caster's fetches.

Exactness: boxes and keys are widened by margins that cover the float32 error of the shader's
lookup and of the triangle test (for a local light also the error of the direction of a hit near
the light, which grows as 1 / distance: casters touching the light are filed everywhere), so a
ray whose triangle test would report a hit always finds that caster in its cell; the triangle
test is the two-level BVH's, on the triangle in bake space, and spheres are tested in model space
through the instance record, as the BVH does.

Textures (linear texel index, as every scene texture): ``lg_cell`` u4 x2 (first entry, count)
per cell, in 8 x 8 tiles (row-major tiles, row-major cells within; a cube's faces one above the
other); ``lg_entry`` u4 x3 (caster code, float bits of its key, its box in the cell: 8 bits each
of x0, x1, y0, y1); caster code = triangle ``t`` (vertices at the shared ``lg_tri`` texels 3t..3t+2,
f4 x3, of :func:`tri_texture`) or ``SPHERE_FLAG | i`` (instance ``i``, its record at the
two-level BVH's ``[leaf]`` texel 5i).

A grid is built per light (:func:`build_sun_grid`, :func:`build_local_grid`) from the world
casters (:func:`world_casters`, once per bake); one that would be too large or too crowded
(:data:`MAX_ENTRIES`, :data:`MAX_CELL`) is None and the light keeps the BVH. A light whose
blocker collection leaves casters out (shadow linking) files only its blockers (``keep``,
:func:`caster_keep`), over the same shared triangles.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, fields

import numpy as np

from ..progress import checkpoint
from .textures import SPHERE_FLAG, TextureData, alloc_texture, f32_bits, f32_up

#: cells per caster aimed at (the cell size follows from the casters' extent, or the cube's faces)
CELLS_PER_CASTER = 1.0
MIN_CELLS, MAX_SIDE = 64, 4096
MAX_ENTRIES = 16_000_000  # entries over this coarsen the grid (4x fewer cells, up to twice)
MAX_CELL = 16384  # a cell listing more casters than this: the light keeps the BVH (loop budget)
#: relative widening of boxes and keys (x the scene's largest coordinate): a few float32
#: roundings of the lookup (dot products of the origin) and of the watertight test
REL_MARGIN = 2.0 ** -16
#: a local light: the float32 error of a ray's direction from the light, relative to the
#: coordinates' size, times a safety factor (the margin of a caster at distance r is this x
#: size / r, in face units)
DIR_ERROR = 16.0 * 2.0 ** -22
FACE_MARGIN = 2.0 ** -14  # a local light: the lookup's own error, in face units
TILE_LOG2 = 3
TILE = 1 << TILE_LOG2  # cells are stored in TILE x TILE tiles
SUB = 255  # an entry's box within its cell: 8 bits per side
SLIVER_CELLS = 8  # triangles whose box covers this many cells keep only the cells they reach
#: the cube's faces: (axis, sign, the two axes across it); the shader picks the same
FACES = ((0, 1, 1, 2), (0, -1, 1, 2), (1, 1, 2, 0), (1, -1, 2, 0), (2, 1, 0, 1), (2, -1, 0, 1))


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
    tri_inst: np.ndarray = None  # (T,) the instance of each triangle

    @property
    def count(self) -> int:
        return len(self.tris) + len(self.sphere_inst)


def world_casters(scene, origin) -> WorldCasters:
    """Every shadow-casting instance's triangles moved to bake space (float64, then float32), and
    its analytic spheres, instances of one model together."""
    inst = scene.instances
    origin = np.asarray(origin, np.float64)
    n = len(inst.names)
    tris = []
    owners = []
    sph = np.zeros(0, np.int64)
    scale = 0.0
    if n:
        casting = np.asarray(inst.casts_shadow, bool)
        mids = inst.model_ids.astype(np.int64)
        sphere = np.asarray(inst.sphere, bool)
        # the largest coordinate of any instance's world box (receivers included)
        lo = np.array([m.bounds_min for m in scene.models], np.float64).reshape(-1, 3)
        hi = np.array([m.bounds_max for m in scene.models], np.float64).reshape(-1, 3)
        c, e = (lo + hi)[mids] * 0.5, (hi - lo)[mids] * 0.5
        m3 = inst.matrices[:, :3, :3]
        wc = np.einsum("nij,nj->ni", m3, c) + inst.matrices[:, :3, 3] - origin
        we = np.einsum("nij,nj->ni", np.abs(m3), e)
        scale = float(np.max(np.abs(wc) + we))
        sph = np.nonzero(casting & sphere)[0]
        mesh = casting & ~sphere
        for m in np.unique(mids[mesh]).tolist():
            model = scene.models[m]
            if not model.triangle_count:
                continue
            checkpoint()
            idx = np.nonzero(mesh & (mids == m))[0]
            v = model.vertices.astype(np.float64)
            mats = inst.matrices[idx]
            wv = np.einsum("nij,vj->nvi", mats[:, :3, :3], v) + (mats[:, :3, 3] - origin)[:, None, :]
            tris.append(wv[:, model.triangles.astype(np.int64)].reshape(-1, 3, 3).astype(np.float32))
            owners.append(np.repeat(idx, model.triangle_count))
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
    return WorldCasters(t, sph.astype(np.int64), sc, sr, scale,
                        np.concatenate(owners) if owners else np.zeros(0, np.int64))


def caster_keep(wc: WorldCasters, instances: np.ndarray) -> np.ndarray:
    """(count,) bool over the casters (triangles, then spheres): those of the instances that
    ``instances`` (N,) bool marks (a light's blockers)."""
    instances = np.asarray(instances, bool)
    return np.concatenate([instances[wc.tri_inst], instances[wc.sphere_inst]])


def _kept(it: _Items, keep) -> _Items:
    """The items whose caster ``keep`` marks (all where it is None)."""
    if keep is None:
        return it
    sel = np.asarray(keep, bool)[it.caster]
    return _Items(*(None if getattr(it, f.name) is None else getattr(it, f.name)[sel] for f in fields(_Items)))


def tri_texture(wc: WorldCasters, tex_width: int = 4096) -> TextureData:
    """``lg_tri``: the casters' triangles, 3 texels (xyz) each, shared by every light's grid."""
    n = len(wc.tris)
    return _texture("lg_tri", wc.tris.reshape(-1, 3) if n else np.zeros((1, 3), np.float32), "f4", tex_width)


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
class LightGrid:
    """One light's grid: textures, the uniforms and defines its shader code reads."""

    textures: dict
    uniforms: dict
    defines: dict
    cells: tuple
    entries: int
    max_cell: int
    build_ms: float = 0.0

    @property
    def samplers(self) -> dict:
        return {"lg_cell": "hs_lg_cell_tex", "lg_entry": "hs_lg_entry_tex"}

    @property
    def nbytes(self) -> int:
        return sum(t.nbytes for t in self.textures.values())


def _texture(name: str, data: np.ndarray, fmt: str, width: int) -> TextureData:
    n, comp = data.shape
    td = alloc_texture(name, max(n, 1), comp, fmt, width)
    td.linear()[:n] = data
    td.used = n
    return td


def edge_planes(a, b, c):
    """(normals (T, 3, 2), offsets (T, 3)) of 2D triangles' edges, pointing out: a point q lies
    outside edge k where normals[:, k] . q > offsets[:, k]. A triangle seen edge-on (no area)
    gets zero normals: it is never outside."""
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    sgn = np.sign(area)[:, None]
    normals = np.empty((len(a), 3, 2))
    offsets = np.empty((len(a), 3))
    for k, (p, q) in enumerate(((a, b), (b, c), (c, a))):
        e = q - p
        checkpoint()
        n = np.stack([e[:, 1], -e[:, 0]], axis=1) * sgn
        normals[:, k] = n
        offsets[:, k] = (n * p).sum(axis=1)
    return normals, offsets


# ------------------------------------------------------------------------------------------
# filing: items (a caster, or a caster on one cube face) into cells
# ------------------------------------------------------------------------------------------
@dataclass
class _Items:
    caster: np.ndarray   # (N,) caster index: triangles, then spheres (n_tri + k)
    lo: np.ndarray       # (N, 2) box in grid units, widened by the item's margin
    hi: np.ndarray
    key: np.ndarray      # (N,) float64: rays whose own key lies at or above it skip the item
    margin: np.ndarray   # (N,) the widening, for the edge test
    normals: np.ndarray  # (N, 3, 2) edge planes (zero: no edge test)
    offsets: np.ndarray  # (N, 3)
    face: np.ndarray | None = None  # (N,) a cube's face the item lies on (rows 2 face .. 2 face + 2)


def _file(it: _Items, g0, ext, n_casters: int, n_tri: int, sphere_codes, cells_per_caster):
    """Cells, entries of the items; ``None`` where they do not fit. Grid units: a sun's
    light-space plane; a cube (items with a ``face``): faces 2 units square one above the other
    (x = u + 1, y = v + 1 + 2 face)."""
    cube = it.face is not None
    if cells_per_caster is None:
        cells_per_caster = CELLS_PER_CASTER
    target = max(MIN_CELLS, cells_per_caster * max(n_casters, 1))
    if cube:  # R x R per face, R a multiple of the tile
        r = int(np.clip(np.sqrt(target / 6.0), TILE, MAX_SIDE // 6))
        cs = 2.0 / (-(-r // TILE) * TILE)
    else:
        cs = float(np.sqrt(ext[0] * ext[1] / target))
        cs = max(cs, float(ext.max()) / MAX_SIDE)
    for _ in range(3):
        inv = 1.0 / cs
        nx = int(min(MAX_SIDE, max(1, np.ceil(ext[0] * inv - 1e-9))))
        ny = int(max(1, np.ceil(ext[1] * inv - 1e-9)))
        i0 = np.floor((it.lo - g0) * inv).astype(np.int64)
        i1 = np.floor((it.hi - g0) * inv).astype(np.int64)
        i0[:, 0] = np.clip(i0[:, 0], 0, nx - 1)
        i1[:, 0] = np.clip(i1[:, 0], 0, nx - 1)
        if cube:  # (an item stays on its face: R rows each)
            f0 = it.face * int(round(2.0 * inv))
            f1 = f0 + int(round(2.0 * inv)) - 1
            i0[:, 1] = np.clip(i0[:, 1], f0, f1)
            i1[:, 1] = np.clip(i1[:, 1], f0, f1)
        else:
            i0[:, 1] = np.clip(i0[:, 1], 0, ny - 1)
            i1[:, 1] = np.clip(i1[:, 1], 0, ny - 1)
        cx = i1[:, 0] - i0[:, 0] + 1
        cy = i1[:, 1] - i0[:, 1] + 1
        per = cx * cy
        total = int(per.sum())
        if total <= MAX_ENTRIES:
            break
        cs *= 2.0
    else:
        return None
    checkpoint()
    # items highest key first: a stable sort by cell keeps that order within every cell
    order = np.argsort(-it.key, kind="stable")
    per_o = per[order]
    own = np.repeat(order.astype(np.int32), per_o)
    checkpoint()
    loc = np.arange(total, dtype=np.int32) - np.repeat((np.cumsum(per_o) - per_o).astype(np.int32), per_o)
    cxo = np.repeat(cx[order].astype(np.int32), per_o)
    row = loc // cxo
    checkpoint()
    cix = np.repeat(i0[order, 0].astype(np.int32), per_o) + (loc - row * cxo)
    ciy = np.repeat(i0[order, 1].astype(np.int32), per_o) + row
    del loc, row, cxo
    checkpoint()
    # a triangle's box covers cells the triangle does not (a long sliver): keep only the cells
    # (widened by the margin) that no edge of it leaves outside
    big = (per >= SLIVER_CELLS) & np.any(it.normals != 0, axis=(1, 2))
    test = np.nonzero(np.repeat(big[order], per_o))[0]
    if len(test):
        t = own[test]
        px = (cix[test] + 0.5) * cs + g0[0]
        py = (ciy[test] + 0.5) * cs + g0[1]
        out = np.zeros(len(test), bool)
        for k in range(3):
            nxk, nyk = np.ascontiguousarray(it.normals[:, k, 0]), np.ascontiguousarray(it.normals[:, k, 1])
            lim = it.offsets[:, k] + (np.abs(nxk) + np.abs(nyk)) * (0.5 * cs + it.margin)
            checkpoint()
            out |= nxk[t] * px + nyk[t] * py > lim[t]
        if out.any():
            keep = np.ones(total, bool)
            keep[test[out]] = False
            own, cix, ciy = own[keep], cix[keep], ciy[keep]
            total = len(own)
    checkpoint()
    # cells in TILE x TILE tiles, tile after tile (row-major), row-major within a tile: the cells
    # of neighbouring pixels, and so their lists, lie close together (texel cache)
    ntx, nty = -(-nx // TILE), -(-ny // TILE)
    cell = ((ciy >> TILE_LOG2) * np.int32(ntx) + (cix >> TILE_LOG2)) * np.int32(TILE * TILE) \
        + (ciy & (TILE - 1)) * np.int32(TILE) + (cix & (TILE - 1))
    checkpoint()
    # each entry's box within its cell, in 1/SUB of the cell, rounded outward
    sub = np.zeros(total, np.uint32)
    for shift, (ci, axis) in enumerate(((cix, 0), (ciy, 1))):
        # (item boxes in cells relative to the grid's corner; the entry's cell subtracted)
        lo_c = np.ascontiguousarray((it.lo[:, axis] - g0[axis]) * inv)
        hi_c = np.ascontiguousarray((it.hi[:, axis] - g0[axis]) * inv)
        checkpoint()
        a = np.clip(np.floor((lo_c[own] - ci) * SUB), 0, SUB).astype(np.uint32)
        b = np.clip(np.ceil((hi_c[own] - ci) * SUB), 0, SUB).astype(np.uint32)
        sub |= (a << np.uint32(16 * shift)) | (b << np.uint32(16 * shift + 8))
    del cix, ciy
    checkpoint()
    srt = np.argsort(cell, kind="stable")
    checkpoint()
    cell = cell[srt]
    own = own[srt]
    sub = sub[srt]
    checkpoint()
    counts = np.bincount(cell, minlength=ntx * nty * TILE * TILE)
    max_cell = int(counts.max()) if total else 0
    if max_cell > MAX_CELL:
        return None
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint32)
    cells = np.stack([start, counts.astype(np.uint32)], axis=1)
    checkpoint()
    cst = it.caster[own]
    code = cst.astype(np.uint32)
    sp = cst >= n_tri
    if sp.any():
        code[sp] = SPHERE_FLAG | sphere_codes[cst[sp] - n_tri].astype(np.uint32)
    checkpoint()
    key_bits = f32_bits(f32_up(it.key))
    checkpoint()
    entries = np.stack([code, key_bits[own], sub], axis=1) if total else np.zeros((0, 3), np.uint32)
    return cells, entries, (nx, ny), ntx, inv, max_cell


def _grid(wc, filed, tex_width, uniforms, defines, t0) -> LightGrid | None:
    if filed is None:
        return None
    cells, entries, dims, ntx, inv, max_cell = filed
    defines = dict(defines, HS_LIGHT_GRID=1)
    if len(wc.tris):
        defines["HS_LG_TRIS"] = 1
    if len(wc.sphere_inst):
        defines["HS_LG_SPHERES"] = 1
    uniforms = dict(uniforms, hs_lg_dims=np.array(dims, np.int32), hs_lg_tiles_x=np.int32(ntx),
                    hs_lg_inv_cell=np.float32(inv))
    textures = {"lg_cell": _texture("lg_cell", cells, "u4", tex_width),
                "lg_entry": _texture("lg_entry", entries, "u4", tex_width)}
    return LightGrid(textures, uniforms, defines, dims, len(entries), max_cell, (time.perf_counter() - t0) * 1e3)


# ------------------------------------------------------------------------------------------
# a sun
# ------------------------------------------------------------------------------------------
def caster_boxes(wc: WorldCasters, basis: np.ndarray):
    """Light-space boxes (lo, hi) (N, 3) of triangles then spheres: x, y across the sun, z the
    depth towards it (float64 of the float32 vertices), and the triangles' edge planes across
    the sun (:func:`edge_planes`; zero for the spheres)."""
    t = wc.tris
    p0, p1, p2 = (t[:, k].astype(np.float64) @ basis.T for k in range(3))
    checkpoint()
    lo = np.minimum(np.minimum(p0, p1), p2)
    hi = np.maximum(np.maximum(p0, p1), p2)
    checkpoint()
    normals, offsets = edge_planes(p0[:, :2], p1[:, :2], p2[:, :2])
    if len(wc.sphere_inst):
        c = wc.sphere_center @ basis.T
        r = wc.sphere_radius[:, None]
        lo = np.concatenate([lo, c - r])
        hi = np.concatenate([hi, c + r])
        k = len(wc.sphere_inst)
        normals = np.concatenate([normals, np.zeros((k, 3, 2))])
        offsets = np.concatenate([offsets, np.zeros((k, 3))])
    return lo, hi, normals, offsets


def build_sun_grid(wc: WorldCasters, direction, tex_width: int = 4096,
                   cells_per_caster: float | None = None, keep=None) -> LightGrid | None:
    """The grid of a sun shining from ``direction`` (towards the sun, the shader's
    ``u_light_vec``), or None where it does not fit; ``keep``: the casters it files
    (:func:`caster_keep`; None: all)."""
    t0 = time.perf_counter()
    basis = sun_basis(direction)
    n = wc.count
    margin = REL_MARGIN * max(wc.scale, 1e-6)
    if n:
        checkpoint()
        lo, hi, normals, offsets = caster_boxes(wc, basis)
        lo, hi = lo - margin, hi + margin
        g0 = lo[:, :2].min(axis=0)
        ext = np.maximum(hi[:, :2].max(axis=0) - g0, margin)
    else:
        lo = hi = np.zeros((0, 3))
        normals, offsets = np.zeros((0, 3, 2)), np.zeros((0, 3))
        g0, ext = np.zeros(2), np.ones(2)
    items = _Items(np.arange(n), lo[:, :2], hi[:, :2], hi[:, 2], np.full(n, margin), normals, offsets)
    checkpoint()
    filed = _file(_kept(items, keep), g0, ext, n, len(wc.tris), wc.sphere_inst, cells_per_caster)
    b32 = basis.astype(np.float32)
    uniforms = {"hs_lg_ux": b32[0], "hs_lg_uy": b32[1], "hs_lg_dz": b32[2], "hs_lg_base": g0.astype(np.float32)}
    return _grid(wc, filed, tex_width, uniforms, {}, t0)


# ------------------------------------------------------------------------------------------
# a local light: a cube of directions
# ------------------------------------------------------------------------------------------
def _on_face(f: int, ulo, uhi, vlo, vhi, everywhere):
    """Boxes (lo, hi) in the cube's grid units of face ``f`` from face coordinates (clamped to
    the face; the whole face where ``everywhere``)."""
    lo = np.stack([np.clip(ulo, -1.0, 1.0) + 1.0, np.clip(vlo, -1.0, 1.0) + 1.0 + 2.0 * f], axis=1)
    hi = np.stack([np.clip(uhi, -1.0, 1.0) + 1.0, np.clip(vhi, -1.0, 1.0) + 1.0 + 2.0 * f], axis=1)
    lo[everywhere] = (0.0, 2.0 * f)
    hi[everywhere] = (2.0, 2.0 * f + 2.0)
    return lo, hi


def _face_items(q, dist, margin_face, everywhere, f: int):
    """Items of triangles on cube face ``f``: ``q`` (N, 3, 3) their vertices relative to the
    light, ``dist`` their distances (a lower bound). Returns (indices into q, lo, hi, key, edge
    normals, offsets).

    A triangle is clipped to depth >= dist / 2 along the face's axis first (no point of it in
    the face's pyramid lies nearer: those would be within sqrt(3) dist / 2 of the light), so it
    projects to a bounded polygon: the box of its points' projections (vertices beyond the
    plane, and the edges' crossings of it), clamped to the face."""
    axis, sign, ua, va = FACES[f]
    z = sign * q[:, :, axis]
    b, c = q[:, :, ua], q[:, :, va]
    delta = 0.5 * dist
    inside = z >= delta[:, None]
    big = np.inf
    zs = np.where(inside, z, 1.0)
    pu, pv = b / zs, c / zs
    checkpoint()
    ulo = np.where(inside, pu, big).min(axis=1)
    uhi = np.where(inside, pu, -big).max(axis=1)
    vlo = np.where(inside, pv, big).min(axis=1)
    vhi = np.where(inside, pv, -big).max(axis=1)
    zmin = np.where(inside, z, big).min(axis=1)
    some = inside.any(axis=1)
    clipped = some & ~inside.all(axis=1)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # edges crossing the plane z = delta
        checkpoint()
        cross = inside[:, i] != inside[:, j]
        if not cross.any():
            continue
        dz = z[:, j] - z[:, i]
        s_ = np.where(cross, (delta - z[:, i]) / np.where(cross, dz, 1.0), 0.0)
        d0 = np.where(cross & (delta > 0), delta, 1.0)  # (dist 0: filed everywhere)
        cu = (b[:, i] + s_ * (b[:, j] - b[:, i])) / d0
        cv = (c[:, i] + s_ * (c[:, j] - c[:, i])) / d0
        ulo = np.where(cross, np.minimum(ulo, cu), ulo)
        uhi = np.where(cross, np.maximum(uhi, cu), uhi)
        vlo = np.where(cross, np.minimum(vlo, cv), vlo)
        vhi = np.where(cross, np.maximum(vhi, cv), vhi)
    checkpoint()
    zmin = np.where(clipped, np.minimum(zmin, delta), zmin)
    m = margin_face
    ulo, uhi, vlo, vhi = ulo - m, uhi + m, vlo - m, vhi + m
    on = (some & (ulo <= 1.0) & (uhi >= -1.0) & (vlo <= 1.0) & (vhi >= -1.0)) | everywhere
    idx = np.nonzero(on)[0]
    ev = everywhere[idx]
    lo, hi = _on_face(f, ulo[idx], uhi[idx], vlo[idx], vhi[idx], ev)
    key = -np.where(ev, 0.0, zmin[idx])
    normals = np.zeros((len(idx), 3, 2))
    offsets = np.zeros((len(idx), 3))
    tri = ~ev & ~clipped[idx]
    if tri.any():
        j = idx[tri]
        qu, qv = pu[j] + 1.0, pv[j] + 1.0 + 2.0 * f
        checkpoint()
        normals[tri], offsets[tri] = edge_planes(np.stack([qu[:, 0], qv[:, 0]], 1),
                                                 np.stack([qu[:, 1], qv[:, 1]], 1),
                                                 np.stack([qu[:, 2], qv[:, 2]], 1))
    return idx, lo, hi, key, normals, offsets


def _face_spheres(c, r, dist, margin_face, everywhere, f: int):
    """Items of the spheres (centres ``c`` relative to the light, radii ``r``) on cube face
    ``f``: the exact range of each sphere's projection along each face axis (the two planes
    through the light's line across the face that touch the sphere), the whole face where it
    reaches the face's plane through the light. Returns what :func:`_face_items` does."""
    axis, sign, ua, va = FACES[f]
    cz = sign * c[:, axis]
    on = (cz + r > 0) | everywhere
    crossing = cz - r <= 0
    rng = []
    for cb in (c[:, ua], c[:, va]):
        a = np.where(crossing, 1.0, cz * cz - r * r)
        root = r * np.sqrt(np.maximum(cb * cb + cz * cz - r * r, 0.0))
        lo = np.where(crossing, -np.inf, (cb * cz - root) / a)
        hi = np.where(crossing, np.inf, (cb * cz + root) / a)
        rng.append((lo - margin_face, hi + margin_face))
    (ulo, uhi), (vlo, vhi) = rng
    on &= ((ulo <= 1.0) & (uhi >= -1.0) & (vlo <= 1.0) & (vhi >= -1.0)) | everywhere
    idx = np.nonzero(on)[0]
    lo, hi = _on_face(f, ulo[idx], uhi[idx], vlo[idx], vhi[idx], everywhere[idx] | crossing[idx])
    # (points in the face's pyramid lie at depth >= their distance / sqrt(3) >= dist / sqrt(3))
    zmin = np.maximum(cz[idx] - r[idx], dist[idx] * (1.0 - 1e-9) / np.sqrt(3.0))
    key = -np.where(everywhere[idx], 0.0, zmin)
    return idx, lo, hi, key, np.zeros((len(idx), 3, 2)), np.zeros((len(idx), 3))


def build_local_grid(wc: WorldCasters, position, tex_width: int = 4096,
                     cells_per_caster: float | None = None, keep=None) -> LightGrid | None:
    """The cube grid of a point, spot or (hard) area light at bake-space ``position`` (the
    shader's ``u_light_vec``), or None where it does not fit; ``keep`` as
    :func:`build_sun_grid`'s."""
    t0 = time.perf_counter()
    L = np.asarray(np.asarray(position, np.float32), np.float64)
    n_tri = len(wc.tris)
    size = max(wc.scale, float(np.abs(L).max()), 1e-6)
    # casters' points relative to the light, their boxes and distances
    q_t = wc.tris.astype(np.float64) - L  # (T, 3, 3)
    checkpoint()
    lo_t, hi_t = q_t.min(axis=1), q_t.max(axis=1)
    # spheres widened by the float32 error of their centre and of the sphere test
    s_c = wc.sphere_center - L
    s_r = wc.sphere_radius * (1.0 + 2.0 ** -20) + REL_MARGIN * size
    lo_b = np.concatenate([lo_t, s_c - s_r[:, None]])
    hi_b = np.concatenate([hi_t, s_c + s_r[:, None]])
    checkpoint()
    dist = np.linalg.norm(np.maximum(np.maximum(lo_b, -hi_b), 0.0), axis=1)  # box to the light
    margin_face = FACE_MARGIN + DIR_ERROR * size / np.maximum(dist, 1e-300)
    everywhere = margin_face > 0.25  # (touching the light, or nearly: filed in every cell)
    margin_face = np.minimum(margin_face, 0.25)
    zpad = REL_MARGIN * size
    parts = []
    ts, ss = slice(0, n_tri), slice(n_tri, None)
    # most triangles lie well inside one face's pyramid (their vertices do, with the margin to
    # spare): they are filed on that face alone; the others are tried on all six
    home = np.full(n_tri, -1)
    if n_tri:
        a = np.abs(q_t)
        major = np.argmax(a, axis=2)  # (T, 3)
        fv = 2 * major + (np.take_along_axis(q_t, major[:, :, None], axis=2)[:, :, 0] < 0)
        checkpoint()
        srt = np.sort(a, axis=2)  # (the major component last, the larger of the other two before it)
        checkpoint()
        room = srt[:, :, 2] * (1.0 - 2.0 * margin_face[:n_tri, None]) - srt[:, :, 1]
        single = (fv[:, 0] == fv[:, 1]) & (fv[:, 1] == fv[:, 2]) & np.all(room > 0, axis=1) & ~everywhere[:n_tri]
        home = np.where(single, fv[:, 0], -1)
    for f in range(6):
        checkpoint()
        found = []
        if n_tri:
            sel = np.nonzero((home == f) | (home < 0))[0]
            idx, lo, hi, key, nn, oo = _face_items(q_t[sel], dist[sel], margin_face[sel], everywhere[sel], f)
            found.append((0, ts, (sel[idx], lo, hi, key, nn, oo)))
        if len(s_c):
            found.append((n_tri, ss, _face_spheres(s_c, s_r, dist[ss], margin_face[ss], everywhere[ss], f)))
        for base, sl, (idx, lo, hi, key, nn, oo) in found:
            parts.append(_Items(idx + base, lo, hi, key + zpad, margin_face[sl][idx], nn, oo,
                                np.full(len(idx), f, np.int64)))
    items = _Items(*(np.concatenate([getattr(p, k.name) for p in parts]) for k in fields(_Items))) if parts \
        else _Items(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
                    np.zeros((0, 3, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))
    checkpoint()
    filed = _file(_kept(items, keep), np.zeros(2), np.array([2.0, 12.0]), wc.count, n_tri, wc.sphere_inst,
                  cells_per_caster)
    uniforms = {"hs_lg_pos": L.astype(np.float32)}
    return _grid(wc, filed, tex_width, uniforms, {"HS_LG_LOCAL": 1}, t0)
