"""Error and frame-rate metrics: shadow masks against a reference, and the thesis' benchmark
statistics (chapter 4.6). Pure numpy, no bpy, no GL.

Masks are float (H, W) visibility: 1 lit, 0 shadowed, fractions in penumbrae, NaN invalid.

- A pixel is *valid* when the reference is not NaN (Cycles saw geometry there and the light
  reaches it unshadowed) **and** ours has geometry (not NaN).
- ``delta = ours - reference``. A *mismatch* is ``|delta| > threshold`` (0.5: one says lit, the
  other shadowed). ``delta > threshold`` is a *missed shadow* (we are lit, the reference is
  shadowed), ``delta < -threshold`` a *false shadow*.
- The mean absolute error is ``mean(|delta|)`` over the valid pixels.
- *Off* pixels (soft shadows, ``compare --soft``): ``|delta| > off_threshold`` (0.1: a
  penumbra's value clearly wrong, not just noisy); ``off_pct`` is their share of the valid pixels.

Frame-rate statistics follow the thesis: each mode is rendered along the same camera path in
several repetitions; ``frame_ms`` is a ``(repetitions, frames)`` array.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

MISMATCH_THRESHOLD = 0.5
#: ``|ours - reference|`` beyond this is an *off* pixel (the soft comparison's second metric)
OFF_THRESHOLD = 0.1


# ------------------------------------------------------------------------------------------------
# Mask error
# ------------------------------------------------------------------------------------------------
@dataclass
class MaskError:
    valid_pixels: int = 0
    mismatch_pixels: int = 0
    missed_pixels: int = 0  # ours lit, reference shadowed
    false_pixels: int = 0  # ours shadowed, reference lit
    abs_error_sum: float = 0.0
    off_pixels: int = 0  # |ours - reference| > OFF_THRESHOLD

    @property
    def off_pct(self) -> float:
        return 100.0 * self.off_pixels / self.valid_pixels if self.valid_pixels else 0.0

    @property
    def mismatch_pct(self) -> float:
        return 100.0 * self.mismatch_pixels / self.valid_pixels if self.valid_pixels else 0.0

    @property
    def missed_pct(self) -> float:
        return 100.0 * self.missed_pixels / self.valid_pixels if self.valid_pixels else 0.0

    @property
    def false_pct(self) -> float:
        return 100.0 * self.false_pixels / self.valid_pixels if self.valid_pixels else 0.0

    @property
    def mae(self) -> float:
        return self.abs_error_sum / self.valid_pixels if self.valid_pixels else 0.0

    def __add__(self, other: MaskError) -> MaskError:
        return MaskError(self.valid_pixels + other.valid_pixels, self.mismatch_pixels + other.mismatch_pixels,
                         self.missed_pixels + other.missed_pixels, self.false_pixels + other.false_pixels,
                         self.abs_error_sum + other.abs_error_sum, self.off_pixels + other.off_pixels)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.update(mismatch_pct=self.mismatch_pct, missed_pct=self.missed_pct, false_pct=self.false_pct,
                 mae=self.mae, off_pct=self.off_pct)
        return d


def _pair(reference, ours):
    ref = np.asarray(reference, np.float64)
    our = np.asarray(ours, np.float64)
    if ref.shape != our.shape:
        raise ValueError(f"mask shapes differ: reference {ref.shape}, ours {our.shape}")
    return ref, our


def valid_pixels(reference, ours) -> np.ndarray:
    """Boolean (H, W): valid in the reference and with geometry in ours."""
    ref, our = _pair(reference, ours)
    return np.isfinite(ref) & np.isfinite(our)


def mask_error(reference, ours, threshold: float = MISMATCH_THRESHOLD,
               off_threshold: float = OFF_THRESHOLD) -> MaskError:
    """Compare one light's masks (see the module doc for the definitions)."""
    ref, our = _pair(reference, ours)
    valid = np.isfinite(ref) & np.isfinite(our)
    d = our[valid] - ref[valid]
    return MaskError(valid_pixels=int(valid.sum()), mismatch_pixels=int((np.abs(d) > threshold).sum()),
                     missed_pixels=int((d > threshold).sum()), false_pixels=int((d < -threshold).sum()),
                     abs_error_sum=float(np.abs(d).sum()), off_pixels=int((np.abs(d) > off_threshold).sum()))


def combine(errors) -> MaskError:
    """Overall error over lights: pixel counts add up (so the MAE and percentages are weighted by
    each light's valid pixels)."""
    total = MaskError()
    for e in errors:
        total = total + e
    return total


# ------------------------------------------------------------------------------------------------
# False-colour difference images
# ------------------------------------------------------------------------------------------------
MISSED_COLOUR = np.array([235, 40, 40], np.float64)  # red: we are lit, the reference is shadowed
FALSE_COLOUR = np.array([30, 140, 255], np.float64)  # blue: we are shadowed, the reference is lit
INVALID_COLOUR = np.array([0, 0, 0], np.float64)


def visibility_image(mask) -> np.ndarray:
    """uint8 (H, W, 3) grey visibility (white lit, dark shadowed); invalid pixels black-ish blue."""
    m = np.asarray(mask, np.float64)
    ok = np.isfinite(m)
    g = np.where(ok, 40 + 215 * np.clip(np.nan_to_num(m), 0, 1), 0)
    out = np.repeat(g[..., None], 3, axis=2)
    out[~ok] = (20, 20, 40)
    return np.round(out).astype(np.uint8)


def diff_image(reference, ours, threshold: float = MISMATCH_THRESHOLD) -> np.ndarray:
    """uint8 (H, W, 3): the reference in dim grey where we agree, red where we miss a shadow,
    blue where we cast a false one (full colour beyond ``threshold``, tinted in proportion below
    it), black where the pixel is not valid."""
    ref, our = _pair(reference, ours)
    valid = np.isfinite(ref) & np.isfinite(our)
    base = 60 + 80 * np.clip(np.nan_to_num(ref), 0, 1)
    out = np.repeat(base[..., None], 3, axis=2)
    d = np.where(valid, np.nan_to_num(our - ref), 0.0)
    w = np.clip(np.abs(d) / threshold, 0, 1)[..., None]
    w = np.where(np.abs(d)[..., None] > threshold, 1.0, 0.6 * w)
    colour = np.where((d > 0)[..., None], MISSED_COLOUR, FALSE_COLOUR)
    out = out * (1 - w) + colour * w
    out[~valid] = INVALID_COLOUR
    return np.round(np.clip(out, 0, 255)).astype(np.uint8)


# ------------------------------------------------------------------------------------------------
# Error against time
# ------------------------------------------------------------------------------------------------
def pareto_front(points) -> list:
    """Indices of the points ``(time, error)`` not dominated by another (another is no slower and
    no worse, and better in one), sorted by time."""
    pts = [(float(t), float(e)) for t, e in points]
    front = []
    for i, (t, e) in enumerate(pts):
        dominated = any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for j, (t2, e2) in enumerate(pts) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (pts[i][0], pts[i][1]))


# ------------------------------------------------------------------------------------------------
# Benchmark statistics (thesis 4.6)
# ------------------------------------------------------------------------------------------------
def fps_of(frame_ms) -> np.ndarray:
    ms = np.asarray(frame_ms, np.float64)
    return 1000.0 / np.maximum(ms, 1e-9)


def erraticness(frame_ms) -> np.ndarray:
    """Per frame of the path (thesis 4.6): the absolute differences of each repetition's frame
    rate from the repetitions' average, added together, divided by that average frame rate.
    ``frame_ms``: (repetitions, frames). Zero with one repetition."""
    fps = fps_of(np.atleast_2d(frame_ms))
    mean = fps.mean(axis=0)
    return np.abs(fps - mean).sum(axis=0) / mean


def frame_stats(frame_ms, control_ms=None) -> dict:
    """The thesis' numbers for one mode. ``frame_ms`` (repetitions, frames); ``control_ms`` the
    no-shadow control's array of the same shape (for the extra time over the control).

    - ``min/avg/max_fps``: over the path, of the per-frame frame rate averaged over repetitions.
    - ``avg_frame_ms``: mean frame time; ``extra_ms``: mean of (frame time - control frame time).
    - ``std_rel``: sample standard deviation (n-1) of every frame-rate sample, over their mean.
    - ``erraticness``: mean over the path of :func:`erraticness`; ``erraticness_max`` its peak.
    """
    ms = np.atleast_2d(np.asarray(frame_ms, np.float64))
    fps = fps_of(ms)
    per_frame = fps.mean(axis=0)
    samples = fps.ravel()
    err = erraticness(ms)
    out = {
        "repetitions": int(ms.shape[0]),
        "frames": int(ms.shape[1]),
        "min_fps": float(per_frame.min()),
        "avg_fps": float(per_frame.mean()),
        "max_fps": float(per_frame.max()),
        "avg_frame_ms": float(ms.mean()),
        "median_frame_ms": float(np.median(ms)),
        "std_rel": float(samples.std(ddof=1) / samples.mean()) if samples.size > 1 else 0.0,
        "erraticness": float(err.mean()),
        "erraticness_max": float(err.max()),
    }
    if control_ms is not None:
        c = np.atleast_2d(np.asarray(control_ms, np.float64))
        if c.shape != ms.shape:
            raise ValueError(f"control shape {c.shape} differs from {ms.shape}")
        extra = (ms - c).mean(axis=0)
        out["extra_ms"] = float(extra.mean())
        out["extra_ms_per_frame"] = [float(v) for v in extra]
    return out


def frame_mismatch(a, b) -> tuple:
    """``(pixels whose masks differ, valid pixels)`` of two frames over ``b``'s shadowed lights:
    a pixel differs where the masks are more than 1e-3 apart; valid where ``b`` has geometry."""
    bad = valid = 0
    for li in b.lights:
        ma, mb = a.mask_array(li), b.mask_array(li)
        ok = ~np.isnan(mb)
        bad += int((np.abs(ma - mb)[ok] > 1e-3).sum())
        valid += int(ok.sum())
    return bad, valid
