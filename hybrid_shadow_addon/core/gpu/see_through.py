"""See-through surfaces seen by the camera: stochastic transparency over sub-frames.

Cycles shows a surface of alpha ``a`` (a blended material: Principled Alpha below 1, an alpha
image without a clip threshold) as ``a`` x the surface + ``(1 - a)`` x what lies behind it, each
lit as it is lit. The G-buffer holds one surface per pixel, so a frame that has such surfaces in
view is rendered as ``Settings.transparency_samples`` sub-frames: on sample ``s`` the G-buffer
keeps a BLEND fragment where its alpha exceeds a hashed threshold (``shaders/common/alpha.glsl``
``hs_alpha_threshold``; oracle: ``core/oracle/alpha.py``), and the lit images and the masks of
the sub-frames are averaged (a mask over the sub-frames that saw geometry at the pixel). A scene
without see-through surfaces in view renders one frame, cut at 0.5 as before.

A final render renders all the sub-frames at once; ``Settings.accumulate`` (the viewport) adds
one per render until the target, and starts afresh on any change (``Pipeline.reset_history``) or
other settings or size. The sub-frames trace without history (no interlacing, no soft-shadow
accumulation: those reuse earlier frames' rays for pixels whose surface would now differ).
"""
from __future__ import annotations

import numpy as np

from ..bake.materials import srgb_decode
from ..scene import LUMA
from .frame import CameraUniforms, mask_source_pixels
from .passes.gbuffer import frustum_visible
from .targets import create_mask_texture


class SeeThroughScene:
    """Which materials and instances of a scene are see-through (cached per image array)."""

    def __init__(self):
        self._fractional: dict = {}  # (id of the pixels, channel, srgb) -> (pixels, bool)

    def _image_fractional(self, image, channel: str) -> bool:
        """Whether the image's alpha (its A channel, or the Rec. 709 luminance of its RGB) holds
        values strictly between 0 and 1."""
        key = (id(image.pixels), channel, bool(image.srgb))
        got = self._fractional.get(key)
        if got is not None and got[0] is image.pixels:
            return got[1]
        px = image.values()
        if channel == "LUMA":
            rgb = px[..., :3]
            v = (srgb_decode(rgb) if image.srgb else rgb) @ np.asarray(LUMA, np.float64)
            frac = bool(((v > 1e-6) & (v < 1.0 - 1e-6)).any())
        else:
            a = px[..., 3]
            frac = bool(((a > 0) & (a < 1)).any())
        if len(self._fractional) > 256:
            self._fractional.clear()
        self._fractional[key] = (image.pixels, frac)
        return frac

    def materials(self, scene) -> np.ndarray:
        """(K,) bool per material: BLEND with an alpha strictly between 0 and 1 somewhere (a
        constant, or an alpha image that holds such values)."""
        out = np.zeros(len(scene.materials), bool)
        for k, m in enumerate(scene.materials):
            if m.alpha_mode != "BLEND" or not m.alpha > 0.0:
                continue
            if m.alpha_image < 0:
                out[k] = m.alpha < 1.0
            else:
                out[k] = m.alpha < 1.0 or self._image_fractional(scene.images[int(m.alpha_image)], m.alpha_channel)
        return out

    def in_view(self, scene, width: int, height: int) -> bool:
        """Whether the camera may see a see-through surface: an instance drawn with the G-buffer's
        TEXTURED variant (a mesh with UVs, or a material without images) whose material is
        see-through, inside the view."""
        if not scene.materials or scene.camera is None or not len(scene.instances):
            return False
        mats = self.materials(scene)
        if not mats.any():
            return False
        inst = scene.instances
        ids = np.asarray(inst.material_ids)
        rows = (ids >= 0) & mats[np.maximum(ids, 0)] & ~np.asarray(inst.sphere, bool)
        if not rows.any():
            return False
        drawn = np.array([m.triangle_count > 0 for m in scene.models] + [False])
        uvs = np.array([m.uvs is not None for m in scene.models] + [False])
        imaged = np.array([m.alpha_image >= 0 or m.color_image >= 0 for m in scene.materials])
        mid = np.asarray(inst.model_ids)
        rows &= drawn[mid] & (uvs[mid] | ~imaged[np.maximum(ids, 0)])
        if not rows.any():
            return False
        cam = CameraUniforms.from_camera(scene.camera, width, height)
        return bool((rows & frustum_visible(scene, cam.clip_from_rel, cam.cam_pos)).any())


def sub_frame_settings(settings):
    """The settings of a see-through sub-frame: no history across sub-frames (their surfaces
    differ), and in the viewport no noise check (each redraw stays one frame's work)."""
    changes = {"interlace": False, "accumulate": False}
    if settings.accumulate:
        changes["noise_target"] = 0.0
    return settings.replace(**changes)


class SeeThroughAccumulation:
    """The running averages of the sub-frames' lit images and masks (float64 sums on the CPU),
    and the mask textures of the averaged frame."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._textures: dict = {}  # light -> R32F texture of the averaged mask
        self.reset()

    def reset(self, key=None) -> None:
        self.key = key
        self.count = 0
        self.image = None
        self.mask_sum: dict = {}
        self.mask_n: dict = {}
        self.lights: list = []
        self.timings: dict = {}
        self.frame = None  # the averaged frame after the last add

    def add(self, frame) -> None:
        """Add a sub-frame (its image read back)."""
        img = np.asarray(frame.image, np.float64)
        self.image = img if self.image is None else self.image + img
        for li in frame.lights:
            m = frame.mask_array(li)
            ok = np.isfinite(m)
            v = np.where(ok, m, 0.0)
            if li in self.mask_sum and self.mask_sum[li].shape == m.shape:
                self.mask_sum[li] += v
                self.mask_n[li] += ok
            else:
                self.mask_sum[li], self.mask_n[li] = v.astype(np.float64), ok.astype(np.int32)
            if li not in self.lights:
                self.lights.append(li)
        for k, v in frame.timings.items():
            self.timings[k] = self.timings.get(k, 0.0) + v
        self.count += 1

    def mask(self, li, coverage: np.ndarray | None = None) -> np.ndarray:
        """float32 (H, W): the mean of light ``li``'s masks over the sub-frames with geometry at
        the pixel, NaN where none had, or (``coverage``: full-resolution bool, row 0 = top) where
        ``coverage`` has none."""
        n = self.mask_n[li]
        ok = n > 0
        if coverage is not None:
            if coverage.shape != n.shape:
                scale = max(1, round(coverage.shape[1] / n.shape[1]))
                rows, cols = mask_source_pixels((n.shape[1], n.shape[0]), coverage.shape[::-1], scale)
                coverage = coverage[rows, cols]
            ok &= coverage
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(ok, self.mask_sum[li] / np.maximum(n, 1), np.nan).astype(np.float32)

    def mask_textures(self, coverage: np.ndarray | None = None) -> dict:
        """{light: R32F texture} of the averaged masks (:meth:`mask`; 1 where NaN)."""
        out = {}
        for li in self.lights:
            m = self.mask(li, coverage)
            h, w = m.shape
            t = self._textures.get(li)
            if t is None or t.size != (w, h):
                if t is not None:
                    t.release()
                t = self._textures[li] = create_mask_texture(self.ctx, w, h)
            t.write(np.ascontiguousarray(np.nan_to_num(m, nan=1.0)[::-1], np.float32).tobytes())
            out[li] = t
        return out

    def release(self) -> None:
        for t in self._textures.values():
            t.release()
        self._textures.clear()


def target_samples(settings) -> int:
    """Sub-frames a see-through frame averages."""
    return max(1, int(settings.transparency_samples))


def split_progress(progress, i: int, n: int):
    """``progress(done, total, label)`` of sub-frame ``i`` of ``n`` as a share of the whole."""
    if progress is None:
        return None

    def sub(done, total, label):
        progress(i * total + done, n * total, f"{label} (see-through {i + 1}/{n})")
    return sub


__all__ = ["SeeThroughScene", "SeeThroughAccumulation", "sub_frame_settings", "target_samples",
           "split_progress"]
