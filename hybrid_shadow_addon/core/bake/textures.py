"""Texture containers and the texel packing shared by the bake and the incremental update.

THE layout of every texel is documented once, next to the GLSL that reads it: the addressing in
``shaders/common/scene_data.glsl``, each structure's records in its own file (``scene_grid.glsl``
"GRID TEXTURE LAYOUT", ``scene_bvh.glsl`` "BVH TEXTURE LAYOUT"); the constants below follow it
and name the section they implement.

Every texture is held as a 2D array (``sampler2DArray`` / ``usampler2DArray``) of ``width`` =
``BakeConfig.tex_width`` texels (a power of two <= 16384); the GPU side uploads the record
textures as buffer textures where it can (``core/gpu/scene_textures.py``), whose element ``i`` is
the same texel. Records are addressed by a *linear texel index* ``i``::

    x = i & (W - 1);  row = i >> log2(W);  y = row & (16384 - 1);  layer = row >> 14

so a texture holds ``layers * height * W`` texels; ``height`` is the number of rows used (<= 16384)
while one layer is enough, and exactly 16384 when several layers are needed. ``TextureData.linear()``
is the flat ``(texels, components)`` view in exactly that order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import GPUError

MAX_TEX_SIZE = 16384
MAX_ROWS_LOG2 = 14
MAX_LAYERS = 2048  # GL 4.1 guarantees GL_MAX_ARRAY_TEXTURE_LAYERS >= 2048

# texels per record of the grid (see scene_grid.glsl)
GRID_TEXELS = 1        # 'grid'        u4 x4: offset, count, bits(max height), capacity
INDEX_TEXELS = 1       # 'grid_index'  u4 x2: object id, model id | SPHERE_FLAG
OBJECT_TEXELS = 4      # 'object'      f4 x4: 3 rows of the inverse world matrix, world sphere
MODEL_TEXELS = 2       # 'model'       u4 x4: bits(sphere), (bvh root, bvh nodes, tri start, tri count)
BVH_TEXELS = 2         # 'bvh'         u4 x4: (bits(min), escape), (bits(max), leaf)
TRI_TEXELS = 3         # 'tri'         f4 x3: v0, v1, v2 (model space, BVH leaf order)

SPHERE_FLAG = np.uint32(1 << 31)
EMPTY_HEIGHT = np.float32(-3.4028235e38)  # max height of an empty node: lowest finite float
FLT_BIG = np.float32(3.0e38)  # "infinite" tmax is clamped to this (GLSL has no portable inf)
#: relative enlargement of stored boxes, spheres and heights: float32 rounding never culls a hit
REL_EPS = 2.0 ** -20

FORMATS = {"f4": np.float32, "u4": np.uint32, "f1": np.uint8}  # f1: normalised RGBA8 (the atlas)


@dataclass
class TextureData:
    """One texture: ``data`` is (layers, height, width, components), float32 or uint32.

    ``fmt`` is moderngl's dtype ('f4' / 'u4'); upload each layer ``data[l]`` (or row ranges of it)
    into a ``texture_array((width, height, layers), components, dtype=fmt)``.
    ``used`` is how many texels (from linear index 0) hold data; the rest is zero padding or
    reserve for incremental updates.
    """

    name: str
    data: np.ndarray
    fmt: str
    used: int = 0

    @property
    def layers(self) -> int:
        return int(self.data.shape[0])

    @property
    def height(self) -> int:
        return int(self.data.shape[1])

    @property
    def width(self) -> int:
        return int(self.data.shape[2])

    @property
    def components(self) -> int:
        return int(self.data.shape[3])

    @property
    def capacity(self) -> int:
        """Texels addressable (layers * height * width)."""
        return self.layers * self.height * self.width

    @property
    def nbytes(self) -> int:
        return int(self.data.nbytes)

    @property
    def gl_internal_format(self) -> str:
        base = "RGBA"[: self.components] if self.components > 1 else "R"
        if self.fmt == "f1":
            return f"{base}8"
        return f"{base}32{'F' if self.fmt == 'f4' else 'UI'}"

    def linear(self) -> np.ndarray:
        """(capacity, components) view in linear texel order (writes go to the texture)."""
        return self.data.reshape(-1, self.components)

    def records(self, texels_per_record: int) -> np.ndarray:
        """(capacity // tpr, tpr * components) view: one row per record."""
        lin = self.data.reshape(-1)
        per = texels_per_record * self.components
        n = lin.size // per
        return lin[: n * per].reshape(n, per)


def texture_shape(n_texels: int, width: int) -> tuple[int, int]:
    """(layers, height) for ``n_texels`` (at least one texel)."""
    rows = max(1, -(-int(n_texels) // width))
    if rows <= MAX_TEX_SIZE:
        return 1, rows
    layers = -(-rows // MAX_TEX_SIZE)
    if layers > MAX_LAYERS:
        raise GPUError(f"scene too large for the GPU textures: {n_texels} texels need {layers} layers "
                       f"(limit {MAX_LAYERS})")
    return layers, MAX_TEX_SIZE


def alloc_texture(name: str, n_texels: int, components: int, fmt: str, width: int) -> TextureData:
    layers, height = texture_shape(n_texels, width)
    data = np.zeros((layers, height, width, components), FORMATS[fmt])
    return TextureData(name, data, fmt, int(n_texels))


def grow_texture(tex: TextureData, n_texels: int, slack: float = 0.25) -> bool:
    """Make ``tex`` hold at least ``n_texels`` (keeping its content), plus ``slack`` of that and
    a row when it has to grow. True when it was resized."""
    if n_texels <= tex.capacity:
        return False
    layers, height = texture_shape(int(n_texels * (1.0 + slack)) + tex.width, tex.width)
    new = np.zeros((layers, height, tex.width, tex.components), tex.data.dtype)
    old = tex.linear()
    new.reshape(-1, tex.components)[: old.shape[0]] = old
    tex.data = new
    return True


def f32_bits(a) -> np.ndarray:
    """float32 bit patterns as uint32 (what GLSL's ``uintBitsToFloat`` turns back)."""
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def f32_up(x) -> np.ndarray:
    """Smallest float32 >= x (elementwise, x float64)."""
    x = np.asarray(x, np.float64)
    f = x.astype(np.float32)
    low = f.astype(np.float64) < x
    return np.where(low, np.nextafter(f, np.float32(np.inf)), f).astype(np.float32)


def f32_down(x) -> np.ndarray:
    x = np.asarray(x, np.float64)
    f = x.astype(np.float32)
    high = f.astype(np.float64) > x
    return np.where(high, np.nextafter(f, np.float32(-np.inf)), f).astype(np.float32)


def texel_rows(name: str, lo: int, hi: int, width: int) -> list[tuple[str, int, int, int]]:
    """Row ranges ``(name, layer, y0, y1)`` (y1 exclusive) covering linear texels [lo, hi)."""
    if hi <= lo:
        return []
    r0, r1 = lo // width, (hi - 1) // width + 1
    out = []
    while r0 < r1:
        layer = r0 >> MAX_ROWS_LOG2
        end = min(r1, (layer + 1) << MAX_ROWS_LOG2)
        out.append((name, layer, r0 - (layer << MAX_ROWS_LOG2), end - (layer << MAX_ROWS_LOG2)))
        r0 = end
    return out


def rows_of_texels(name: str, texels: np.ndarray, width: int) -> list[tuple[str, int, int, int]]:
    """Coalesced row ranges covering the given linear texel indices."""
    texels = np.asarray(texels, np.int64)
    if texels.size == 0:
        return []
    rows = np.unique(texels // width)
    breaks = np.nonzero(np.diff(rows) != 1)[0]
    starts = np.concatenate([[rows[0]], rows[breaks + 1]])
    ends = np.concatenate([rows[breaks], [rows[-1]]]) + 1
    out = []
    for a, b in zip(starts.tolist(), ends.tolist()):
        out.extend(texel_rows(name, a * width, b * width, width))
    return out


def merge_ranges(ranges) -> list[tuple[str, int, int, int]]:
    """Sort and merge overlapping/adjacent ``(name, layer, y0, y1)`` ranges."""
    out: list[list] = []
    for name, layer, y0, y1 in sorted(ranges):
        if out and out[-1][0] == name and out[-1][1] == layer and y0 <= out[-1][3]:
            out[-1][3] = max(out[-1][3], y1)
        else:
            out.append([name, layer, y0, y1])
    return [tuple(r) for r in out]
