"""The error-against-time plot drawn with numpy alone (for Blender's Python, which has no
matplotlib): log-log panels with decade grid lines, one dot per variant in its mode's colour
(ringed in black on the Pareto front), the front as a dashed step line and the Cycles
reference's time as a green vertical line. Labels are the report table's job."""
from __future__ import annotations

import numpy as np

from ..core.image import write_png

PANEL_W, PANEL_H, MARGIN = 560, 360, 24
COLOURS = {"raytrace": (214, 39, 40), "shadowmap": (31, 119, 180), "none": (127, 127, 127)}
BLACK, GRID, GREEN = (0, 0, 0), (225, 225, 225), (44, 160, 44)


class Canvas:
    """An RGB image with log-log axes mapping (time, error) into one panel's box."""

    def __init__(self, width: int, height: int):
        self.rgb = np.full((height, width, 3), 255, np.uint8)

    def axes(self, x0: int, box_w: int, box_h: int, xr, yr) -> None:
        self.x0, self.w, self.h = x0 + MARGIN, box_w - 2 * MARGIN, box_h - 2 * MARGIN
        self.lx, self.ly = np.log10(xr), np.log10(yr)

    def to_px(self, x, y):
        fx = (np.log10(x) - self.lx[0]) / (self.lx[1] - self.lx[0])
        fy = (np.log10(y) - self.ly[0]) / (self.ly[1] - self.ly[0])
        return (self.x0 + fx * self.w).round().astype(int), (MARGIN + (1 - fy) * self.h).round().astype(int)

    def line(self, xs, ys, colour, dash: int = 0) -> None:
        """A polyline through pixel points, every ``dash`` pixels on and off when ``dash``."""
        for (ax, ay), (bx, by) in zip(zip(xs, ys), list(zip(xs, ys))[1:]):
            n = max(abs(bx - ax), abs(by - ay), 1) + 1
            px = np.linspace(ax, bx, n).round().astype(int)
            py = np.linspace(ay, by, n).round().astype(int)
            keep = (np.arange(n) // dash) % 2 == 0 if dash else np.ones(n, bool)
            self.put(px[keep], py[keep], colour)

    def put(self, px, py, colour) -> None:
        h, w = self.rgb.shape[:2]
        ok = (px >= 0) & (px < w) & (py >= 0) & (py < h)
        self.rgb[py[ok], px[ok]] = colour

    def disc(self, cx: int, cy: int, r: int, colour) -> None:
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        inside = xx ** 2 + yy ** 2 <= r * r
        self.put(cx + xx[inside], cy + yy[inside], colour)

    def box(self) -> None:
        x1, y1 = self.x0 + self.w, MARGIN + self.h
        self.line([self.x0, x1, x1, self.x0, self.x0], [MARGIN, MARGIN, y1, y1, MARGIN], BLACK)

    def decades(self) -> None:
        for d in range(int(np.ceil(self.lx[0])), int(np.floor(self.lx[1])) + 1):
            x = int(round(self.x0 + (d - self.lx[0]) / (self.lx[1] - self.lx[0]) * self.w))
            self.line([x, x], [MARGIN, MARGIN + self.h], GRID)
        for d in range(int(np.ceil(self.ly[0])), int(np.floor(self.ly[1])) + 1):
            y = int(round(MARGIN + (1 - (d - self.ly[0]) / (self.ly[1] - self.ly[0])) * self.h))
            self.line([self.x0, self.x0 + self.w], [y, y], GRID)


def _log_range(values) -> tuple:
    """A range of whole decades around positive ``values``."""
    lo, hi = np.log10(np.min(values)), np.log10(np.max(values))
    return 10.0 ** np.floor(lo - 0.05), 10.0 ** np.ceil(hi + 0.05)


def plot_error_vs_time_png(m: dict, path, panels: list) -> None:
    """``panels``: ``(metric key, label, floor)`` per panel, as :func:`.report.plot_axes`."""
    rows = sorted(m["variants"], key=lambda r: r["total_ms"])
    cyc = m["reference"]["total_ms"]
    times = [max(r["total_ms"], 1e-3) for r in rows] + ([cyc] if cyc > 0 else [])
    canvas = Canvas(PANEL_W * len(panels), PANEL_H)
    primary = m.get("error_metric", panels[0][0])
    for i, (key, _label, floor) in enumerate(panels):
        errors = [max(r["overall"][key], floor) for r in rows]
        canvas.axes(i * PANEL_W, PANEL_W, PANEL_H, _log_range(times), _log_range(errors + [floor]))
        canvas.decades()
        if cyc > 0:
            x, _ = canvas.to_px(np.array([cyc]), np.array([floor]))
            canvas.line([int(x[0])] * 2, [MARGIN, MARGIN + canvas.h], GREEN)
        front = [(max(r["total_ms"], 1e-3), e) for r, e in zip(rows, errors) if r.get("pareto")]
        if len(front) > 1 and key == primary:
            xs, ys = canvas.to_px(np.array([t for t, _ in front]), np.array([e for _, e in front]))
            sx = np.repeat(xs, 2)[1:]
            sy = np.repeat(ys, 2)[:-1]
            canvas.line(list(sx), list(sy), BLACK, dash=4)
        for r, e in zip(rows, errors):
            x, y = canvas.to_px(np.array([max(r["total_ms"], 1e-3)]), np.array([e]))
            if r.get("pareto"):
                canvas.disc(int(x[0]), int(y[0]), 6, BLACK)
            canvas.disc(int(x[0]), int(y[0]), 4, COLOURS.get(r["settings"]["mode"], BLACK))
        canvas.box()
    write_png(path, canvas.rgb)
