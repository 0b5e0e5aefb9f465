"""The deferred passes: G-buffer, shadow masks (ray traced, shadow maps, none), upsample, lighting.

The common shadow-mask interface: every mask pass returns ``dict[light_index, moderngl.Texture]``
of R32F textures (1 = lit, 0 = shadowed, fractions from filtering), at G-buffer resolution or at
``Settings.mask_size`` for a reduced-quality ray-traced mask (then :class:`UpsamplePass` brings it
to full resolution). Lights without an entry are unshadowed. ``read_mask`` reads one to numpy.

A reduced-resolution mask texel (x, y) (GL coordinates, bottom-up) stands for full-resolution
pixel ``min((x, y) * scale + scale // 2, size - 1)``: see ``mask_source_pixels`` and
``mask_source_pixel`` in ``shaders/common/gbuffer.glsl``.
"""
from __future__ import annotations

import moderngl
import numpy as np

from .gbuffer import GBuffer, read_texture


def create_mask_texture(ctx: moderngl.Context, width: int, height: int, fill: float | None = None) -> moderngl.Texture:
    """An R32F mask texture (nearest filtering, clamped), optionally filled with ``fill``."""
    tex = ctx.texture((int(width), int(height)), 1, dtype="f4")
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    tex.repeat_x = tex.repeat_y = False
    if fill is not None:
        tex.write(np.full((int(height), int(width)), fill, np.float32).tobytes())
    return tex


def mask_source_pixels(mask_size, full_size, scale: int):
    """Full-resolution (rows, cols) in numpy (top-down) order sampled by each mask texel,
    as two (h, w) int arrays for a mask of ``mask_size`` = (w, h)."""
    mw, mh = mask_size
    fw, fh = full_size
    xs = np.minimum(np.arange(mw) * scale + scale // 2, fw - 1)
    ys_gl = np.minimum(np.arange(mh) * scale + scale // 2, fh - 1)  # bottom-up
    rows_gl = np.broadcast_to(ys_gl[:, None], (mh, mw))
    cols = np.broadcast_to(xs[None, :], (mh, mw))
    rows = (fh - 1 - rows_gl)[::-1]  # numpy row 0 = top = GL row mh-1
    return np.ascontiguousarray(rows), np.ascontiguousarray(cols)


def read_mask(tex: moderngl.Texture, gbuffer: GBuffer | None = None, coverage: np.ndarray | None = None) -> np.ndarray:
    """float32 (H, W), row 0 = top; NaN where the G-buffer has no geometry (when given; pass its
    ``coverage()`` too when reading several masks, to read the G-buffer once).

    A reduced-resolution mask gets NaN where its source pixel has no geometry."""
    m = read_texture(tex)
    if gbuffer is not None:
        cov = gbuffer.coverage() if coverage is None else coverage
        if m.shape != cov.shape:
            scale = max(1, round(gbuffer.width / tex.width))
            rows, cols = mask_source_pixels((tex.width, tex.height), gbuffer.size, scale)
            cov = cov[rows, cols]
        m = np.where(cov, m, np.nan).astype(np.float32)
    return m


def select_shadowed_lights(scene, settings=None) -> list:
    """Indices of the lights that get a mask: ``use_shadow`` lights; with
    ``settings.max_shadowed_lights`` = N only N of them: suns first (always kept, thesis 3.2),
    then the others nearest to the camera."""
    idx = [i for i, l in enumerate(scene.lights) if l.use_shadow]
    limit = None if settings is None else settings.max_shadowed_lights
    if settings is not None and settings.mode == "none":
        return idx
    if limit is None or len(idx) <= limit:
        return idx
    cam = np.zeros(3) if scene.camera is None else scene.camera.matrix[:3, 3]

    def key(i):
        light = scene.lights[i]
        if light.type == "SUN":
            return (0, 0.0, i)
        return (1, float(np.linalg.norm(light.position - cam)), i)

    return sorted(sorted(idx, key=key)[:limit])


from .noshadow import NoShadowPass  # noqa: E402
from .shadowmap import ShadowMapPass  # noqa: E402
from .upsample import UpsamplePass  # noqa: E402
from .lighting import LightingPass, to_srgb8, write_png  # noqa: E402
from .gbuffer import GBufferPass  # noqa: E402

__all__ = ["GBuffer", "GBufferPass", "NoShadowPass", "ShadowMapPass", "UpsamplePass", "LightingPass",
           "create_mask_texture", "read_mask", "read_texture", "mask_source_pixels", "select_shadowed_lights",
           "to_srgb8", "write_png"]
