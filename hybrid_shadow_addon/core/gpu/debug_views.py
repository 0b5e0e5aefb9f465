"""The viewport's debug views (a light's mask, grid occupancy, G-buffer channels), made where the
frame's GPU targets are: in the renderer process (:class:`DebugView` is the render request's
``post``, picklable) or in the in-process worker."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


# ------------------------------------------------------------------------------------------------
def _heat(t: np.ndarray) -> np.ndarray:
    """0..1 → a blue-green-yellow-red ramp (H, W, 3)."""
    t = np.clip(t, 0.0, 1.0)[..., None]
    stops = np.float32([[0.0, 0.0, 0.3], [0.0, 0.6, 1.0], [0.1, 0.9, 0.2], [1.0, 0.9, 0.0], [1.0, 0.1, 0.0]])
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(np.int64), len(stops) - 2)[..., 0]
    f = x - i[..., None]
    return (stops[i] * (1 - f) + stops[i + 1] * f).astype(np.float32)


def grid_occupancy(baked, position: np.ndarray) -> np.ndarray:
    """Per pixel, the baked structure's occupancy over the pixel's world XY
    (:meth:`AccelerationStructure.occupancy`: the grid's casters in the nodes of every level over
    it, the two-level BVH's instance boxes over it); -1 where there is no geometry.
    ``position``: the G-buffer's (H, W, 4) world position."""
    valid = position[..., 3] > 0.5
    out = np.full(position.shape[:2], -1.0, np.float32)
    if valid.any():
        out[valid] = baked.occupancy(position[valid][:, :2])
    return out


def debug_image(view: str, frame, scene, pipeline, light_name: str | None = None) -> np.ndarray:
    """(H, W, 4) float32, row 0 = top: the ``view`` debug image of a rendered ``frame``.
    Raises ValueError with a readable message when the view cannot be shown."""
    gb = frame.gbuffer
    valid = gb.coverage()
    h, w = valid.shape
    rgb = np.zeros((h, w, 3), np.float32)
    if view == "LIGHT_MASK":
        if not frame.lights:
            raise ValueError("no shadowed light: nothing to show in the Light Mask view")
        names = [scene.lights[i].name for i in frame.lights]
        li = frame.lights[names.index(light_name)] if light_name in names else frame.lights[0]
        m = frame.mask_array(li)
        bad = np.isnan(m)
        rgb[:] = np.nan_to_num(m, nan=0.0)[..., None]
        rgb[bad] = (0.05, 0.1, 0.4)
    elif view == "GRID_HEAT":
        baked = getattr(pipeline, "baked", None)
        if baked is None:
            raise ValueError("the grid occupancy view needs the ray-traced mode (no structure is baked)")
        occ = grid_occupancy(baked, gb.read("position"))
        top = max(1.0, float(occ.max()))
        rgb[:] = _heat(np.log1p(np.maximum(occ, 0)) / np.log1p(top))
        rgb[occ < 0] = 0.0
    elif view == "NORMAL":
        rgb[:] = gb.read("shading_normal")[..., :3] * 0.5 + 0.5
    elif view == "ALBEDO":
        rgb[:] = gb.read("albedo")[..., :3]
    elif view == "DEPTH":
        d = gb.read("depth")
        d = d[..., 0] if d.ndim == 3 else d
        if valid.any():
            lo, hi = float(d[valid].min()), float(d[valid].max())
            rgb[:] = (1.0 - (d - lo) / max(hi - lo, 1e-9))[..., None]
    elif view == "POSITION":
        rgb[:] = np.mod(gb.read("position")[..., :3], 1.0)
    else:
        raise ValueError(f"unknown debug view {view!r}")
    rgb[~valid] = np.where(view == "LIGHT_MASK", rgb[~valid], 0.0)
    out = np.ones((h, w, 4), np.float32)
    out[..., :3] = rgb
    return out




@dataclass(frozen=True)
class DebugView:
    """A render request's ``post(frame, scene, pipeline) -> image``: the ``view`` debug image."""

    view: str
    light_name: str | None = None

    def __call__(self, frame, scene, pipeline) -> np.ndarray:
        return debug_image(self.view, frame, scene, pipeline, self.light_name)
