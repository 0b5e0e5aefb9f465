"""Textured and alpha-cut materials on the GPU: the image atlas, the material / image records and
the per-triangle UVs of the models whose shadows the alpha cuts.

Only what the scene has is baked: a scene without ``Scene.materials`` gets nothing (no atlas, no
records, no UVs, no ``HS_HAS_ALPHA``), a scene whose materials cut no shadow (textured colour
only) gets the atlas and records for the G-buffer but no UVs in the traversal.

Textures (layouts documented in ``shaders/common/alpha.glsl``):

- ``atlas``: RGBA8 2D array (``sampler2DArray`` ``hs_atlas_tex``), the images' stored bytes.
  Colour images carry their mip levels (2x2 box filter, averaged in linear light for sRGB
  images), alpha-only images level 0 only. Rectangles are shelf-packed into square layers;
  the sampling code wraps and filters on the image's own texel indices, so rectangles need no
  padding and never bleed into each other.
- ``mat``: RGBA32UI records (linear texel addressing as the scene textures, ``hs_texel``):
  material ``k`` at texels ``MAT_TEXELS * k``, then one record per image.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np

from ..errors import GPUError
from ..progress import checkpoint
from .textures import TextureData, alloc_texture, f32_bits

# (bits(uv row 0), bits(alpha)), (bits(uv row 1), bits(threshold)), (colour image, alpha image, flags, 0)
MAT_TEXELS = 3
MAX_LEVELS = 16
FLAG_CLIP = 1
FLAG_LUMA = 2
FLAG_TRANSPARENT_SHADOW = 4
EXTENSION_CODES = {"REPEAT": 0, "EXTEND": 1, "CLIP": 2, "MIRROR": 3}
INTERP_CODES = {"Linear": 0, "Closest": 1, "Cubic": 2}
DEFAULT_LAYER_SIZE = 4096


def srgb_decode(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def srgb_encode(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


def mip_chain(pixels: np.ndarray, srgb: bool, levels: int | None = None) -> list:
    """Level 0 (the image) and its 2x2 box-filtered reductions down to 1x1 (or ``levels``),
    (H, W, 4) each in the image's dtype (uint8, or float32 kept unquantised). sRGB colour is
    averaged in linear light; alpha linearly."""
    out = [pixels]
    byte = pixels.dtype == np.uint8
    cur = pixels.astype(np.float64) / (255.0 if byte else 1.0)
    if srgb:
        cur[..., :3] = srgb_decode(cur[..., :3])
    limit = MAX_LEVELS if levels is None else levels
    while len(out) < limit and (cur.shape[0] > 1 or cur.shape[1] > 1):
        h, w = cur.shape[:2]
        h2, w2 = max(1, h // 2), max(1, w // 2)
        ys = np.minimum(np.arange(h2)[:, None] * 2 + np.array([0, 1]), h - 1)  # (h2, 2)
        xs = np.minimum(np.arange(w2)[:, None] * 2 + np.array([0, 1]), w - 1)
        cur = cur[ys[:, :, None, None], xs[None, None, :, :]].mean(axis=(1, 3))
        lvl = cur.copy()
        if srgb:
            lvl[..., :3] = srgb_encode(lvl[..., :3])
        lvl = np.clip(lvl, 0, 1)
        out.append(np.round(lvl * 255.0).astype(np.uint8) if byte else lvl.astype(np.float32))
    return out


def shelf_pack(sizes: list, layer: int) -> np.ndarray:
    """(N, 3) int (x, y, layer) of rectangles ``sizes`` [(w, h)] in square layers of side
    ``layer``: tallest first, left to right on shelves, a new layer when one is full."""
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0]))
    pos = np.zeros((len(sizes), 3), np.int64)
    x = y = shelf = lay = 0
    for i in order:
        w, h = sizes[i]
        if w > layer or h > layer:
            raise GPUError(f"an image of {w}x{h} texels does not fit the texture atlas ({layer}x{layer})")
        if x + w > layer:
            x, y, shelf = 0, y + shelf, 0
        if y + h > layer:
            x, y, shelf, lay = 0, 0, 0, lay + 1
        pos[i] = (x, y, lay)
        x += w
        shelf = max(shelf, h)
    return pos


def image_signature(img) -> tuple:
    """Content key of an :class:`~..scene.Image` (its pixels' CRC, cached on the object)."""
    crc = getattr(img, "_crc", None)
    if crc is None or crc[0] is not img.pixels:
        crc = (img.pixels, zlib.crc32(np.ascontiguousarray(img.pixels).data))
        img._crc = crc
    return (img.name, img.pixels.shape, crc[1], bool(img.srgb), img.extension, img.interpolation)


def material_signature(scene) -> tuple:
    """Content key of the scene's materials and images: equal keys bake to equal textures."""
    mats = tuple((m.name, m.color_image, m.alpha_image, m.alpha, m.alpha_channel, m.alpha_mode,
                  m.alpha_threshold, m.transparent_shadow, m.uv_transform.tobytes()) for m in scene.materials)
    return mats + tuple(image_signature(i) for i in scene.images)


@dataclass
class MaterialBake:
    atlas: TextureData  # RGBA8 "f1" (RGBA32F "f4" when an image is float), (layers, S, S, 4)
    mat: TextureData  # RGBA32UI records
    image_record: np.ndarray  # (I,) first [mat] texel of each image's record (-1: unused)
    alpha_slot: np.ndarray  # (K,) per material: 1 + its index when it cuts shadows, else 0
    atlas_ms: float = 0.0
    signature: tuple = ()  # material_signature() of the scene baked

    @property
    def cuts_shadows(self) -> bool:
        return bool((self.alpha_slot > 0).any())

    def instance_slots(self, material_ids: np.ndarray) -> np.ndarray:
        """(N,) uint32 per instance: 1 + material index when its material cuts its shadow."""
        table = np.concatenate([self.alpha_slot, [0]]).astype(np.uint32)
        return table[np.asarray(material_ids, np.int64)]

    @property
    def nbytes(self) -> int:
        return int(self.atlas.nbytes + self.mat.nbytes)


def bake_materials(scene, width: int, layer_size: int = DEFAULT_LAYER_SIZE) -> MaterialBake | None:
    """The atlas and records of ``scene``'s materials, or None when it has none."""
    t0 = time.perf_counter()
    mats = list(scene.materials)
    if not mats:
        return None
    images = list(scene.images)
    color_use = np.zeros(len(images), bool)
    alpha_use = np.zeros(len(images), bool)
    for m in mats:
        if m.color_image >= 0:
            color_use[m.color_image] = True
        if m.alpha_image >= 0:
            alpha_use[m.alpha_image] = True
    levels = {}
    for i, img in enumerate(images):
        checkpoint()
        if color_use[i]:
            levels[i] = mip_chain(img.pixels, img.srgb)
        elif alpha_use[i]:
            levels[i] = [img.pixels]
    rects = [(i, level) for i in sorted(levels) for level in range(len(levels[i]))]
    sizes = [(levels[i][level].shape[1], levels[i][level].shape[0]) for i, level in rects]
    biggest = max([max(s) for s in sizes], default=1)
    side = 1 << max(0, (max(biggest, 1) - 1).bit_length())
    area = sum(w * h for w, h in sizes)
    side = max(side, min(layer_size, 1 << max(0, int(np.ceil(np.sqrt(max(area, 1)))) - 1).bit_length()))
    pos = shelf_pack(sizes, side) if rects else np.zeros((0, 3), np.int64)
    n_layers = int(pos[:, 2].max()) + 1 if len(pos) else 1
    # RGBA8 unless an image is float: then every image as RGBA32F (bytes / 255, as GL reads them)
    floats = any(levels[i][0].dtype != np.uint8 for i in levels)
    atlas = np.zeros((n_layers, side, side, 4), np.float32 if floats else np.uint8)
    for (i, level), (x, y, lay), (w, h) in zip(rects, pos.tolist(), sizes):
        px = levels[i][level]
        atlas[lay, y:y + h, x:x + w] = px / np.float32(255.0) if floats and px.dtype == np.uint8 else px
    # records: materials, then images
    image_record = np.full(len(images), -1, np.int64)
    nxt = MAT_TEXELS * len(mats)
    for i in sorted(levels):
        image_record[i] = nxt
        nxt += 1 + len(levels[i])
    rec = alloc_texture("mat", max(nxt, 1), 4, "u4", width)
    lin = rec.linear()
    alpha_slot = np.zeros(len(mats), np.int64)
    for k, m in enumerate(mats):
        t = MAT_TEXELS * k
        uvt = m.uv_transform.astype(np.float32)
        lin[t, :3] = f32_bits(uvt[0])
        lin[t, 3] = f32_bits(np.float32([m.alpha]))[0]
        lin[t + 1, :3] = f32_bits(uvt[1])
        lin[t + 1, 3] = f32_bits(np.float32([m.alpha_threshold]))[0]
        flags = ((FLAG_CLIP if m.alpha_mode == "CLIP" else 0) | (FLAG_LUMA if m.alpha_channel == "LUMA" else 0)
                 | (FLAG_TRANSPARENT_SHADOW if m.transparent_shadow else 0))
        lin[t + 2] = (image_record[m.color_image] + 1 if m.color_image >= 0 else 0,
                      image_record[m.alpha_image] + 1 if m.alpha_image >= 0 else 0, flags, 0)
        alpha_slot[k] = k + 1 if (m.has_alpha and m.transparent_shadow) else 0
    at = {}
    for (i, level), p in zip(rects, pos.tolist()):
        at[(i, level)] = p
    for i in sorted(levels):
        img = images[i]
        r = int(image_record[i])
        lin[r] = (len(levels[i]), EXTENSION_CODES[img.extension], INTERP_CODES[img.interpolation], int(bool(img.srgb)))
        for level, px in enumerate(levels[i]):
            x, y, lay = at[(i, level)]
            lin[r + 1 + level] = (x, y, lay, px.shape[1] | (px.shape[0] << 16))
    rec.used = nxt
    atlas_data = TextureData("atlas", atlas, "f4" if floats else "f1", n_layers * side * side)
    return MaterialBake(atlas_data, rec, image_record, alpha_slot, (time.perf_counter() - t0) * 1e3,
                        material_signature(scene))


def model_uvs(model) -> np.ndarray:
    """(T, 3, 2) float32 UVs of ``model`` (zeros without a UV map)."""
    if model.uvs is None:
        return np.zeros((model.triangle_count, 3, 2), np.float32)
    return model.uvs.astype(np.float32)
