"""numpy reference for textured materials: image sampling, material alpha, shadow transmittance
and albedo (the oracle the GPU's alpha-tested shadows and G-buffer albedo are checked against).

Everything follows the rules documented on :class:`core.scene.Image` and
:class:`core.scene.Material`, in float64:

- :func:`sample_image`: texel (i, j) has its centre at ``((i + 0.5) / W, (j + 0.5) / H)``, row 0
  is v near 0 (the bottom); ``"Linear"`` blends the 4 nearest texels bilinearly (the extension
  rule applied to each texel index), ``"Closest"`` takes ``floor(u W), floor(v H)``, ``"Cubic"``
  weighs the 4x4 nearest with Cycles' cubic B-spline (``kernel/device/cpu/image.h``).
  ``REPEAT`` wraps the index, ``EXTEND`` clamps it, ``MIRROR`` reflects it (period 2W),
  ``CLIP`` gives (0, 0, 0, 0) for a UV outside [0, 1) and, for ``"Linear"`` and ``"Cubic"``,
  reads texels beyond the image as transparent black. Values are the stored ones in [0, 1] (no colour-space
  decoding; a non-finite UV samples (0, 0, 0, 0)).
- :func:`material_alpha`: the material's alpha at mesh UVs (its ``uv_transform`` applied).
- :func:`transmittance`: what a shadow ray keeps crossing the surface: 0 when opaque (no
  material, a material without alpha, or ``transparent_shadow`` off); BLEND ``1 - alpha``;
  CLIP ``1 if alpha < alpha_threshold else 0``.
- :func:`camera_keeps`: whether a camera ray keeps the surface (the G-buffer's cut): CLIP at its
  threshold; BLEND at ``alpha >= 0.5``, or on sample ``s`` of a see-through accumulation where
  ``alpha > see_through_threshold(pixel, s, surface)`` (stochastic transparency).
- :func:`albedo`: instance base colour x the colour image's (decoded) RGB, bilinear in place of
  cubic (as the G-buffer's mip-mapped colour).

Colour-space order: the sRGB decoding is applied to the *filtered* sample (as Cycles does for
byte sRGB images: interpolate the stored values, then convert to scene linear).
"""
from __future__ import annotations

import numpy as np

from ..scene import LUMA

__all__ = ["sample_image", "srgb_to_linear", "apply_uv_transform", "material_alpha", "transmittance",
           "albedo", "is_opaque", "see_through_threshold", "camera_keeps"]


# ------------------------------------------------------------------------------------------
# image sampling
# ------------------------------------------------------------------------------------------
def _wrap(i: np.ndarray, n: int, extension: str):
    """Texel index ``i`` (int64) through the extension rule: (index in [0, n), valid mask)."""
    if extension == "REPEAT":
        return np.mod(i, n), np.ones(i.shape, bool)
    if extension == "EXTEND":
        return np.clip(i, 0, n - 1), np.ones(i.shape, bool)
    if extension == "MIRROR":
        m = np.mod(i, 2 * n)
        return np.where(m < n, m, 2 * n - 1 - m), np.ones(i.shape, bool)
    if extension == "CLIP":
        ok = (i >= 0) & (i < n)
        return np.clip(i, 0, n - 1), ok
    raise ValueError(f"unsupported image extension {extension!r}")


def _bspline(t: np.ndarray) -> np.ndarray:
    """(N, 4) Cycles' cubic B-spline weights of the 4 texels around samples ``t`` (N,) of the way
    past the second."""
    return np.stack([(((-1.0 / 6.0) * t + 0.5) * t - 0.5) * t + 1.0 / 6.0,
                     ((0.5 * t - 1.0) * t) * t + 2.0 / 3.0,
                     ((-0.5 * t + 0.5) * t + 0.5) * t + 1.0 / 6.0,
                     t ** 3 / 6.0], axis=1)


def sample_image(image, uv, interpolation=None) -> np.ndarray:
    """(N, 4) float64 RGBA of ``image`` (a :class:`core.scene.Image`) at ``uv`` (N, 2), the
    stored values in [0, 1] (``Image.values``; sRGB colour channels are *not* decoded here), with the image's
    interpolation or ``interpolation``."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    px = image.values()
    H, W = int(px.shape[0]), int(px.shape[1])
    tex = px.reshape(H * W, -1)
    ext = str(image.extension).upper()
    interp = str(interpolation or image.interpolation).capitalize()
    n = len(uv)
    out = np.zeros((n, 4), np.float64)
    if n == 0:
        return out
    finite = np.isfinite(uv).all(axis=1)
    if ext == "CLIP":
        finite &= (uv >= 0).all(axis=1) & (uv < 1).all(axis=1)
    sel = np.nonzero(finite)[0]
    if not sel.size:
        return out
    u, v = uv[sel, 0], uv[sel, 1]
    if interp == "Closest":
        i, j = np.floor(u * W).astype(np.int64), np.floor(v * H).astype(np.int64)
        if ext == "CLIP":  # u < 1 but u * W rounding up to W: still the last texel
            i, j = np.clip(i, 0, W - 1), np.clip(j, 0, H - 1)
        i, _ = _wrap(i, W, ext)
        j, _ = _wrap(j, H, ext)
        out[sel] = tex[j * W + i]
        return out
    if interp not in ("Linear", "Cubic"):
        raise ValueError(f"unsupported image interpolation {interp!r}")
    x = u * W - 0.5
    y = v * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if interp == "Cubic":
        wx, wy = _bspline(fx[:, 0]), _bspline(fy[:, 0])
        acc = np.zeros((len(sel), 4), np.float64)
        for b in range(4):
            j, okj = _wrap(y0 - 1 + b, H, ext)
            for a in range(4):
                i, oki = _wrap(x0 - 1 + a, W, ext)
                acc += (wx[:, a] * wy[:, b] * (oki & okj))[:, None] * tex[j * W + i]
        out[sel] = acc
        return out
    ia, oka = _wrap(x0, W, ext)
    ib, okb = _wrap(x0 + 1, W, ext)
    ja, okc = _wrap(y0, H, ext)
    jb, okd = _wrap(y0 + 1, H, ext)

    def texel(i, j, ok):
        return np.where(ok[:, None], tex[j * W + i], 0.0)

    t00 = texel(ia, ja, oka & okc)
    t10 = texel(ib, ja, okb & okc)
    t01 = texel(ia, jb, oka & okd)
    t11 = texel(ib, jb, okb & okd)
    out[sel] = (t00 * (1 - fx) + t10 * fx) * (1 - fy) + (t01 * (1 - fx) + t11 * fx) * fy
    return out


def srgb_to_linear(c) -> np.ndarray:
    """The standard sRGB EOTF, elementwise (float64)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4)


# ------------------------------------------------------------------------------------------
# materials
# ------------------------------------------------------------------------------------------
def apply_uv_transform(material, uv) -> np.ndarray:
    """(N, 2) float64: ``material.uv_transform @ (u, v, 1)`` of mesh UVs ``uv`` (N, 2)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    m = np.asarray(material.uv_transform, np.float64).reshape(2, 3)
    return uv @ m[:, :2].T + m[:, 2]


def is_opaque(scene, material_index: int) -> bool:
    """True when a surface of this material blocks shadow rays outright (transmittance 0
    everywhere): no material (-1), a material without alpha, or ``transparent_shadow`` off."""
    k = int(material_index)
    if k < 0:
        return True
    mat = scene.materials[k]
    return not (mat.has_alpha and mat.transparent_shadow)


def material_alpha(scene, material_index: int, uv) -> np.ndarray:
    """(N,) float64 alpha of ``scene.materials[material_index]`` at mesh UVs ``uv`` (N, 2):
    ``alpha_image`` sampled at the transformed UV (channel "A": its alpha; "LUMA": Rec. 709
    luminance of its RGB, sRGB-decoded first when the image is sRGB) times ``material.alpha``;
    with no alpha image, ``material.alpha``. ``material_index`` -1 (plain colour) gives 1."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    n = len(uv)
    k = int(material_index)
    if k < 0:
        return np.ones(n, np.float64)
    mat = scene.materials[k]
    if mat.alpha_image < 0:
        return np.full(n, float(mat.alpha), np.float64)
    img = scene.images[int(mat.alpha_image)]
    s = sample_image(img, apply_uv_transform(mat, uv))
    if mat.alpha_channel == "LUMA":
        rgb = srgb_to_linear(s[:, :3]) if img.srgb else s[:, :3]
        a = rgb @ np.asarray(LUMA, np.float64)
    else:
        a = s[:, 3]
    return a * float(mat.alpha)


def transmittance(scene, material_index: int, uv) -> np.ndarray:
    """(N,) float64 in [0, 1]: the fraction of a shadow ray's light that passes a surface of
    material ``material_index`` at mesh UVs ``uv`` (N, 2). Opaque (see :func:`is_opaque`): 0;
    BLEND: ``1 - alpha`` (alpha clamped to [0, 1]); CLIP: 1 where ``alpha < alpha_threshold``
    else 0."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    n = len(uv)
    if is_opaque(scene, material_index):
        return np.zeros(n, np.float64)
    mat = scene.materials[int(material_index)]
    a = material_alpha(scene, material_index, uv)
    if mat.alpha_mode == "CLIP":
        return (a < float(mat.alpha_threshold)).astype(np.float64)
    return 1.0 - np.clip(a, 0.0, 1.0)


def albedo(scene, instance_rows, uv) -> np.ndarray:
    """(N, 3) float64 albedo of instances ``instance_rows`` (N,) at mesh UVs ``uv`` (N, 2):
    the instance's linear base colour RGB x its material's colour image RGB (sampled at the
    transformed UV, mip level 0, bilinear in place of cubic, sRGB-decoded when the image is
    sRGB). Rows with no material or no colour image get the base colour alone."""
    rows = np.asarray(instance_rows, np.int64).reshape(-1)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    inst = scene.instances
    out = np.asarray(inst.base_color, np.float64)[rows, :3].copy()
    mids = np.asarray(inst.material_ids)[rows]
    for k in np.unique(mids[mids >= 0]).tolist():
        mat = scene.materials[k]
        if mat.color_image < 0:
            continue
        img = scene.images[int(mat.color_image)]
        sel = np.nonzero(mids == k)[0]
        rgb = sample_image(img, apply_uv_transform(mat, uv[sel]), "Closest" if img.interpolation == "Closest"
                           else "Linear")[:, :3]
        if img.srgb:
            rgb = srgb_to_linear(rgb)
        out[sel] *= rgb
    return out


# ------------------------------------------------------------------------------------------
# the camera's cut (stochastic transparency)
# ------------------------------------------------------------------------------------------
def _hash(x: np.ndarray) -> np.ndarray:
    """lowbias32 on uint32 arrays (``shaders/common/alpha.glsl`` hs_hash)."""
    x = np.asarray(x, np.uint32).copy()
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def _bit_reverse(s: np.ndarray) -> np.ndarray:
    s = np.asarray(s, np.uint32)
    out = np.zeros_like(s)
    for b in range(32):
        out |= ((s >> np.uint32(b)) & np.uint32(1)) << np.uint32(31 - b)
    return out


def see_through_threshold(x, y, sample, surface) -> np.ndarray:
    """float32 thresholds in (0, 1) of sample ``sample`` at GL pixels (``x``, ``y``: column, row
    from the bottom) of surface ``surface`` (the instance index): the bit-reversed sample index
    (a van der Corput sequence) plus a hash of pixel and surface, modulo 2^32, its top 23 bits
    as ``(k + 0.5) / 2^23`` (hs_alpha_threshold)."""
    x, y, surface = np.broadcast_arrays(np.asarray(x, np.int64), np.asarray(y, np.int64),
                                        np.asarray(surface, np.int64))
    with np.errstate(over="ignore"):
        h = _hash(surface.astype(np.uint32) + np.uint32(0x9E3779B9))
        r = _hash(_hash(h ^ y.astype(np.uint32)) ^ x.astype(np.uint32))
        t = _bit_reverse(np.full(r.shape, int(sample), np.uint32)) + r
    return ((t >> np.uint32(9)).astype(np.float32) + np.float32(0.5)) * np.float32(1.0 / 8388608.0)


def camera_keeps(scene, material_index: int, uv, sample=None, x=None, y=None, surface=None) -> np.ndarray:
    """(N,) bool: whether a camera ray keeps a surface of material ``material_index`` at mesh
    UVs ``uv`` (N, 2). CLIP: ``alpha >= alpha_threshold``; BLEND: ``alpha >= 0.5``, or with
    ``sample`` (a see-through sub-frame) ``alpha > see_through_threshold(x, y, sample, surface)``,
    the alpha in float32 as the GPU holds it. No material (-1): kept."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    k = int(material_index)
    if k < 0:
        return np.ones(len(uv), bool)
    mat = scene.materials[k]
    a = material_alpha(scene, k, uv)
    if mat.alpha_mode == "CLIP":
        return a >= np.float32(mat.alpha_threshold)
    if sample is None:
        return a >= 0.5
    return a.astype(np.float32) > see_through_threshold(x, y, sample, surface)
