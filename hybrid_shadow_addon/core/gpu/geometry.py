"""Geometry on the GPU: indexed model buffers, growable instance batches, the proxy meshes of
sphere primitives, and the caster draw lists of the light-space passes."""
from __future__ import annotations

import numpy as np


def unit_cube() -> np.ndarray:
    """De-indexed (36, 3) float32 triangles of the cube [-1, 1]^3."""
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(a, b, c_) for q in quads for (a, b, c_) in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return c[np.array(tris).ravel()]


# The vertex layout of the proxy meshes: positions only, de-indexed (3 vertices per triangle).
PROXY_FORMAT = "3f"
PROXY_ATTRS = ("in_pos",)


# The G-buffer's indexed layout: the model's distinct corners (position, smooth corner normal
# or zeros on a flat model, UV or zeros, face normal), an index buffer. The face normal is a flat
# attribute of each triangle's provoking (last) corner, which is a vertex of that triangle alone
# or of triangles with the same face normal (indexed_vertex_data), cheaper than a texture read by
# gl_PrimitiveID on a software rasteriser.
INDEXED_FORMAT = "3f 3f 2f 3f"
INDEXED_ATTRS = ("in_pos", "in_shading_normal", "in_uv", "in_face_normal")
INDEXED_FORMAT_NO_UV = "3f 3f 8x 3f"
INDEXED_ATTRS_NO_UV = ("in_pos", "in_shading_normal", "in_face_normal")


def face_normals(model) -> np.ndarray:
    """(T, 3) float32 unit face normals (zero on a degenerate triangle), computed in float64."""
    v = model.vertices.astype(np.float64)
    tris = model.triangles
    a = np.take(v, tris[:, 0], axis=0)
    e1 = np.take(v, tris[:, 1], axis=0) - a
    e2 = np.take(v, tris[:, 2], axis=0) - a
    n = np.empty_like(a)
    n[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    n[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    n[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ln = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
    return np.where(ln > 0, n / np.where(ln > 0, ln, 1), 0.0).astype(np.float32)


def indexed_vertex_data(model):
    """``(vertices (V', 11) float32, indices (3T,) uint32, source (V',) int64)``: the model's corners in
    :data:`INDEXED_FORMAT` (a flat model's normals are zeros: the G-buffer then shades with the
    face normal), shared where they are equal, and each triangle's three corners in order (its
    last corner, GL's provoking vertex, gives the G-buffer its plane point and its face normal).
    (:meth:`ModelBufferCache.chunks` later puts the triangles in :func:`chunk_order`: each keeps
    its corners, so the vertices stay valid.)

    The model's own vertices carry each vertex's normal and UV; a corner whose normal or UV
    differs from its vertex's (a sharp edge, a UV seam) gets a vertex of its own (equal such
    corners one together). A triangle's last corner carries its face normal (:func:`face_normals`):
    the first triangle ending on a vertex claims it, later ones share it where their face normal
    is the same bits (a flat stretch) and get a copy of it otherwise; ``source`` maps each vertex
    to the one it copies (itself if none), so ``source[indices]`` draws the same corners without
    the copies (passes that need no face normal). Linear in the corners: no sort of the whole
    mesh."""
    tri = model.triangles.astype(np.int64).ravel()
    nv = len(model.vertices)
    verts = np.zeros((nv, 8), np.float32)
    verts[:, :3] = model.vertices
    idx = tri.copy()
    if model.normals is not None or model.uvs is not None:
        attrs = np.zeros((len(tri), 5), np.float32)
        if model.normals is not None:
            attrs[:, :3] = model.normals.reshape(-1, 3)
        if model.uvs is not None:
            attrs[:, 3:] = model.uvs.reshape(-1, 2)
        per_vertex = np.zeros((nv, 5), np.float32)
        per_vertex[tri] = attrs
        bits = attrs.view(np.int32)
        own = (per_vertex[tri].view(np.int32) != bits).any(axis=1)  # (bitwise: -0.0 and NaN kept as given)
        verts[:, 3:] = per_vertex
        if own.any():
            keys = np.concatenate([tri[own, None].astype(np.int32), bits[own]], axis=1)
            keys = np.ascontiguousarray(keys).view(np.dtype((np.void, 24))).ravel()
            _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            rows = np.nonzero(own)[0][first]
            extra = np.concatenate([model.vertices[tri[rows]], attrs[rows]], axis=1)
            verts = np.concatenate([verts, extra])
            idx[own] = nv + inverse.ravel()
    # the face normals on the provoking corners
    fn = face_normals(model)
    t = len(fn)
    nv = len(verts)
    last = idx[2::3]
    claim = np.full(nv, -1, np.int64)
    claim[last[::-1]] = np.arange(t - 1, -1, -1)  # the first triangle ending on each vertex
    fbits = fn.view(np.int32)
    mine = (fbits[claim[last]] == fbits).all(axis=1)  # (its own claim, or the same face normal)
    copies = np.nonzero(~mine)[0]
    out = np.zeros((nv + len(copies), 11), np.float32)
    out[:nv, :8] = verts
    out[last[mine], 8:] = fn[mine]
    out[nv:, :8] = verts[last[copies]]
    out[nv:, 8:] = fn[copies]
    source = np.concatenate([np.arange(nv), last[copies]])
    idx[3 * copies + 2] = nv + np.arange(len(copies))
    return out, idx.astype(np.uint32), source


#: models of at least CHUNK_MIN triangles are drawn in chunks of CHUNK_TRIS spatially close
#: triangles, each left out where its bounding sphere misses the view (a terrain seen from
#: within: a software rasteriser shades vertices and sets up triangles on one thread, culled or not)
CHUNK_TRIS = 2048
CHUNK_MIN = 4 * CHUNK_TRIS


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """The 10 low bits of ``x`` (int64) spread to every third bit (a 30-bit Morton code's axis)."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    return (x | (x << 2)) & 0x09249249


def chunk_order(model, chunk: int | None = None, minimum: int | None = None):
    """``(order, starts, centres, radii)``: the model's triangles in Morton order of their
    centroids on a grid of cubic cells (a permutation, stable for equal codes), cut into chunks
    of ``chunk`` triangles starting at ``starts`` (the last one shorter), with each chunk's
    model-space bounding sphere (float64: its box's circumscribed sphere, rounded up). ``None``
    for a model of fewer than ``minimum`` triangles: it is drawn whole, in its own order
    (defaults: CHUNK_TRIS, CHUNK_MIN)."""
    chunk = CHUNK_TRIS if chunk is None else chunk
    minimum = CHUNK_MIN if minimum is None else minimum
    n = model.triangle_count
    if n < max(int(minimum), 2):
        return None
    v = model.vertices  # (float32: the order needs no more, the boxes are exact)
    tri = model.triangles
    cen = np.take(v, tri[:, 0], axis=0) + np.take(v, tri[:, 1], axis=0) + np.take(v, tri[:, 2], axis=0)
    # (3 x the centroids: only the order counts)
    lo = cen.min(axis=0)
    ext = float((cen.max(axis=0) - lo).max())
    scale = np.float32(1023.0 / ext) if ext > 0 else np.float32(0.0)
    q = np.minimum(((cen - lo) * scale).astype(np.int64), 1023)  # (cubic cells: compact chunks)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2)
    order = np.argsort(code, kind="stable")
    starts = np.arange(0, n, int(chunk))
    pts = np.take(v, np.take(tri, order, axis=0).ravel(), axis=0)  # the corners in chunk order, 3 rows each
    bmin = np.minimum.reduceat(pts, 3 * starts).astype(np.float64)  # (exact)
    bmax = np.maximum.reduceat(pts, 3 * starts).astype(np.float64)
    centres = 0.5 * (bmin + bmax)
    # the box's circumscribed sphere (float64 of exact float32 corners: a relative 1e-9 covers it)
    radii = 0.5 * np.linalg.norm(bmax - bmin, axis=1) * (1.0 + 1e-9) + 1e-12 * np.abs(centres).max(axis=1) + 1e-30
    return order, starts, centres, radii


class _Indexed:
    """A model's indexed buffers (:class:`ModelBufferCache`)."""

    def __init__(self, model, key):
        self.model, self.key = model, key
        self.vbo = self.ibo = self.shared_ibo = None
        self.count = 0
        self.idx = None  # the indices in the model's order, until the chunk order is settled
        self.chunks = None  # None: not settled yet; False: drawn whole; else (starts, counts, centres, radii)
        self.frames = 0  # frames that drew the model (chunks() calls)


class ModelBufferCache:
    """The indexed buffers of each model (:meth:`indexed`), shared by the passes that rasterise
    the scene. Keyed by model identity; :meth:`prune` drops the buffers of models no longer in
    the scene."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._indexed: dict = {}  # id(model) -> _Indexed
        #: a big model's index buffer is put in chunk order (:meth:`chunks`) from the frame after
        #: its first on: a single render does not pay for the order
        self.chunk_after = 1

    def indexed(self, model):
        """``(vbo, ibo, index_count)`` of :func:`indexed_vertex_data`, the triangles in
        :func:`chunk_order` once :meth:`chunks` gave the model's chunks; ``vbo`` is None for a
        model without triangles."""
        e = self._entry(model)
        return e.vbo, e.ibo, e.count

    def shared(self, model):
        """``(vbo, ibo, index_count)``: :meth:`indexed`'s corners without the face normals' copies
        (each copy's index turned back to its source vertex: fewer vertices to shade), for passes
        that read positions and UVs only; the triangles in the model's order."""
        e = self._entry(model)
        return e.vbo, e.shared_ibo, e.count

    def chunks(self, model):
        """``(starts, counts, centres, radii)`` of the chunks of ``model``'s index buffer (in
        triangles; model-space bounding spheres), or ``None``: drawn whole. Called once per
        frame that draws the model: after :attr:`chunk_after` such frames a model of
        CHUNK_MIN triangles or more has its index buffer's triangles put in chunk order (the
        same triangles and corners, in another order: the vertex buffer is unchanged)."""
        e = self._entry(model)
        if e.chunks is None and e.vbo is not None and e.frames >= self.chunk_after:
            got = chunk_order(model)
            if got is None:
                e.chunks = False
            else:
                order, starts, centres, radii = got
                e.ibo.write(np.ascontiguousarray(np.take(e.idx.reshape(-1, 3), order, axis=0)).tobytes())
                e.chunks = (starts, np.diff(np.append(starts, model.triangle_count)), centres, radii)
            e.idx = None
        e.frames += 1
        return e.chunks or None

    def _entry(self, model):
        key = (id(model.vertices), id(model.triangles), id(model.normals), id(model.uvs), len(model.triangles))
        e = self._indexed.get(id(model))
        if e is None or e.model is not model or e.key != key:
            if e is not None:
                self._release_indexed(e)
            e = _Indexed(model, key)
            if model.triangle_count:
                verts, e.idx, source = indexed_vertex_data(model)
                e.vbo = self.ctx.buffer(verts.tobytes())
                e.ibo = self.ctx.buffer(e.idx.tobytes())
                e.shared_ibo = self.ctx.buffer(source[e.idx].astype(np.uint32).tobytes())
                e.count = len(e.idx)
            self._indexed[id(model)] = e
        return e

    @staticmethod
    def _release_indexed(e) -> None:
        for o in (e.vbo, e.ibo, e.shared_ibo):
            if o is not None:
                o.release()

    def prune(self, models) -> None:
        keep = {id(m) for m in models}
        for k in [k for k in self._indexed if k not in keep]:
            self._release_indexed(self._indexed.pop(k))

    def buffer_ids(self) -> dict:
        return {k: id(e.vbo) for k, e in self._indexed.items()}

    def release(self) -> None:
        self.prune(())


class InstanceBatch:
    """A growable dynamic instance buffer and the VAO drawing one vertex buffer with it."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.ibuf = None
        self.vao = None
        self.capacity = 0
        self._key = None

    def upload(self, data: np.ndarray, prog, vbo, vbo_format, vbo_attrs, inst_format, inst_attrs,
               index_buffer=None):
        """``index_buffer``: uint32 indices (an indexed draw)."""
        nbytes = data.nbytes
        key = (id(prog), id(vbo), id(index_buffer))
        if self.ibuf is None or self.capacity < nbytes or key != self._key:
            if self.vao is not None:
                self.vao.release()
            if self.ibuf is None or self.capacity < nbytes:
                if self.ibuf is not None:
                    self.ibuf.release()
                self.capacity = max(nbytes, 2 * self.capacity, 256)
                self.ibuf = self.ctx.buffer(reserve=self.capacity, dynamic=True)
            self.vao = self.ctx.vertex_array(prog, [(vbo, vbo_format, *vbo_attrs),
                                                    (self.ibuf, inst_format, *inst_attrs)],
                                             index_buffer=index_buffer, index_element_size=4, skip_errors=True)
            self._key = key
        self.ibuf.write(data.tobytes())
        return self.vao

    def release(self):
        for o in (self.vao, self.ibuf):
            if o is not None:
                o.release()
        self.vao = self.ibuf = None
        self.capacity = 0


def sphere_proxy_matrices(scene, rows) -> np.ndarray:
    """World matrices mapping the unit sphere/cube onto each sphere primitive's bounding sphere."""
    inst = scene.instances
    mids = inst.model_ids[rows]
    c = np.array([scene.models[i].sphere_center for i in mids], np.float64).reshape(-1, 3)
    r = np.array([scene.models[i].sphere_radius for i in mids], np.float64)
    local = np.tile(np.eye(4), (len(rows), 1, 1))
    local[:, [0, 1, 2], [0, 1, 2]] = r[:, None]
    local[:, :3, 3] = c
    return inst.matrices[rows] @ local


def icosphere(subdiv: int = 2) -> np.ndarray:
    """De-indexed (3T, 3) float32 unit-sphere triangles, scaled to circumscribe the sphere."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    tris = np.array([[v[a], v[b], v[c]] for a, b, c in faces])
    for _ in range(subdiv):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [(x + y) / np.linalg.norm(x + y, axis=1, keepdims=True) for x, y in ((a, b), (b, c), (c, a))]
        tris = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    # the flat faces lie inside the sphere: scale so the inscribed distance reaches radius 1
    centroid = np.linalg.norm(tris.mean(axis=1), axis=1).min()
    return (tris.reshape(-1, 3) / centroid).astype(np.float32)


class ProxyMesh:
    """A lazily created vertex buffer (:data:`PROXY_FORMAT`) of proxy geometry."""

    def __init__(self, ctx, make_points):
        self.ctx = ctx
        self._make = make_points
        self._vbo = None
        self.vertex_count = 0

    def get(self):
        """``(vbo, vertex_count)``."""
        if self._vbo is None:
            pts = self._make()
            self._vbo = self.ctx.buffer(np.ascontiguousarray(pts, np.float32).tobytes())
            self.vertex_count = len(pts)
        return self._vbo, self.vertex_count

    def release(self) -> None:
        if self._vbo is not None:
            self._vbo.release()
            self._vbo = None


CASTER_FORMAT = "4f 4f 4f/i"
CASTER_ATTRS = ("in_m0", "in_m1", "in_m2")
ALPHA_CASTER_FORMAT = "4f 4f 4f 1f/i"  # + the material whose alpha cuts the shadow
ALPHA_CASTER_ATTRS = CASTER_ATTRS + ("in_matid",)


def alpha_caster_rows(scene, rows) -> np.ndarray:
    """(len(rows),) bool: instances whose material cuts their shadow (alpha, transparent
    shadows) on a model with UVs; the light-space passes draw them with the alpha test."""
    inst = scene.instances
    rows = np.asarray(rows, np.int64)
    if not scene.materials or not len(rows):
        return np.zeros(len(rows), bool)
    cuts = np.array([m.has_alpha and m.transparent_shadow for m in scene.materials] + [False])
    has_uv = np.array([m.uvs is not None for m in scene.models] + [False])
    return cuts[inst.material_ids[rows]] & has_uv[inst.model_ids[rows]] & ~inst.sphere[rows]


class CasterDraws:
    """Instanced position-only draws of shadow casters for light-space passes (shadow maps,
    conservative maps): per model one indexed batch of world matrix rows relative to an origin
    (:meth:`ModelBufferCache.indexed`), sphere primitives as icospheres circumscribing their
    bounding spheres."""

    def __init__(self, ctx, models: ModelBufferCache):
        self.ctx = ctx
        self.models = models
        self._batches: dict = {}
        self._sphere = ProxyMesh(ctx, icosphere)

    def build(self, scene, rows: np.ndarray, origin, prog, tag=()) -> list:
        """``[(vao, vertex_count, instance_count)]`` drawing instances ``rows`` with ``prog``
        (attributes ``in_pos`` and :data:`CASTER_ATTRS`), ``origin`` subtracted in float64;
        ``tag``: draws of another set of rows kept beside these (a linked light's blockers)."""
        inst = scene.instances
        rows = np.asarray(rows, np.int64)
        draws = []
        if not len(rows):
            return draws
        sph = inst.sphere[rows]
        mids = inst.model_ids[rows]
        for mi in np.unique(mids[~sph]):
            model = scene.models[int(mi)]
            if not model.triangle_count:
                continue
            sel = rows[(~sph) & (mids == mi)]
            vbo, ibo, nidx = self.models.shared(model)
            draws.append((self._upload((*tag, "m", int(mi)), inst.matrices[sel], origin, prog, vbo, index_buffer=ibo),
                          nidx, len(sel)))
        srows = rows[sph]
        if len(srows):
            vbo, nverts = self._sphere.get()
            draws.append((self._upload((*tag, "spheres"), sphere_proxy_matrices(scene, srows), origin, prog, vbo),
                          nverts, len(srows)))
        return draws

    def build_alpha(self, scene, rows: np.ndarray, origin, prog, tag=()) -> list:
        """Like :meth:`build` for alpha-cut casters (:func:`alpha_caster_rows`): ``prog`` also
        reads ``in_uv`` and ``in_matid`` (its fragment stage drops what the alpha lets through)."""
        inst = scene.instances
        rows = np.asarray(rows, np.int64)
        draws = []
        mids = inst.model_ids[rows]
        for mi in np.unique(mids):
            model = scene.models[int(mi)]
            if not model.triangle_count:
                continue
            sel = rows[mids == mi]
            vbo, ibo, nidx = self.models.shared(model)
            mat = inst.material_ids[sel].astype(np.float32)[:, None]
            draws.append((self._upload((*tag, "a", int(mi)), inst.matrices[sel], origin, prog, vbo, mat,
                                       index_buffer=ibo), nidx, len(sel)))
        return draws

    def _upload(self, key, matrices, origin, prog, vbo, more=None, index_buffer=None):
        """``index_buffer`` given: ``vbo`` is a model's indexed buffer (:data:`INDEXED_FORMAT`,
        positions and, for alpha-cut casters, UVs read), else a proxy's positions."""
        m = np.array(matrices, np.float64)
        m[:, :3, 3] -= np.asarray(origin, np.float64)
        data = m[:, :3, :].reshape(len(m), 12)
        fmt, attrs = CASTER_FORMAT, CASTER_ATTRS
        if more is not None:
            data = np.concatenate([data, more], axis=1)
            fmt, attrs = ALPHA_CASTER_FORMAT, ALPHA_CASTER_ATTRS
        data = np.ascontiguousarray(data, dtype=np.float32)
        b = self._batches.get(key)
        if b is None:
            b = self._batches[key] = InstanceBatch(self.ctx)
        if index_buffer is None:
            return b.upload(data, prog, vbo, PROXY_FORMAT, PROXY_ATTRS, fmt, attrs)
        vfmt, vattrs = ("3f 12x 2f 12x", ("in_pos", "in_uv")) if more is not None else ("3f 32x", ("in_pos",))
        return b.upload(data, prog, vbo, vfmt, vattrs, fmt, attrs, index_buffer=index_buffer)

    def release(self) -> None:
        for b in self._batches.values():
            b.release()
        self._batches.clear()
        self._sphere.release()
