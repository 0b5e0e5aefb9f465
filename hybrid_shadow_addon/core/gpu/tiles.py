"""Heavy draws split into tiles under a time budget (a final render's per-draw limit).

A final render's trace draws cover the whole frame with up to many rays per pixel: one such draw
can block a software rasteriser for seconds and, on a GPU, run into the driver's watchdog.
With a budget (:attr:`DrawBudget.max_draw_ms`) a draw is made band by band with ``ctx.scissor``,
each band finished before the next starts; the band size follows the time per pixel measured
on the bands before it, starting small. After each band :attr:`DrawBudget.tick` runs (the
frame's progress: a callback that raises stops the frame between bands).

Tiles start on multiples of :data:`ALIGN` pixels in both directions, so every 2x2 quad and every
SIMD block of pixels a rasteriser shades together lies in one tile: a tiled draw writes what the
whole draw writes, bit for bit (derivatives and group votes included).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager

import moderngl

from ..progress import Progress

ALIGN = 16  # tile edges on multiples of this many pixels (llvmpipe's 16x16 blocks, a GPU's quads)
FIRST_PIXELS = ALIGN * ALIGN  # a draw's first tile: one block (it also pays the shader's first use)
AIM = 0.4  # a tile aims at this share of the budget (room for costlier pixels further on)
GROWTH = 2.0  # the next tile is at most this many times larger than the last


class DrawBudget:
    """The per-draw budget of the frame being rendered (None: every draw whole) and what its
    tiles measured: ``tiles`` drawn and the ``longest_ms`` one since :meth:`reset_stats`."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.max_draw_ms: float | None = None
        self.tick: Callable[[], None] | None = None  # after each tile (progress, cancel)
        #: the frame's ``progress(done, total, label)`` for CPU work inside a pass (a light grid's
        #: build), None outside a frame or without a callback
        self.progress: Progress | None = None
        self.tiles = 0
        self.longest_ms = 0.0

    def reset_stats(self) -> None:
        self.tiles = 0
        self.longest_ms = 0.0

    @contextmanager
    def frame(self, max_draw_ms: float | None, tick: Callable[[], None] | None = None,
              progress: Progress | None = None):
        """Within it, tiled draws keep under ``max_draw_ms`` each and call ``tick`` after each
        tile, and the passes' CPU work reports to ``progress``; outside it every draw is whole
        again."""
        if max_draw_ms is not None and not max_draw_ms > 0:
            raise ValueError(f"max_draw_ms must be positive, not {max_draw_ms!r}")
        saved = self.max_draw_ms, self.tick, self.progress
        self.max_draw_ms, self.tick, self.progress = max_draw_ms, tick, progress
        try:
            yield self
        finally:
            self.max_draw_ms, self.tick, self.progress = saved

    def fullscreen(self, vao, target) -> None:
        """The buffer-less full-screen triangle of ``vao`` into ``target`` (a
        :class:`~.targets.Target`), in tiles under the budget."""
        target.use(self.ctx)
        self.draw(vao, target.size)

    def draw(self, vao, size) -> None:
        """The full-screen triangle of ``vao`` into the bound framebuffer of ``size`` (w, h),
        whose scissor is off: once, or with a budget once per tile under a scissor (left off
        afterwards)."""
        if self.max_draw_ms is None:
            vao.render(moderngl.TRIANGLES, vertices=3)
            return
        ctx = self.ctx
        ctx.finish()  # (the work queued before is not the first tile's)
        try:
            for rect in self._tiles(int(size[0]), int(size[1])):
                ctx.scissor = rect
                t0 = time.perf_counter()
                vao.render(moderngl.TRIANGLES, vertices=3)
                ctx.finish()
                self._done_tile(rect, (time.perf_counter() - t0) * 1e3)
        finally:
            ctx.scissor = None

    def slices(self, total: int, align: int):
        """``(first, count)`` of each slice of a compute queue of ``total`` items, sized as the
        tiles are (``count`` a multiple of ``align`` but for the last): the caller dispatches
        each slice when it is yielded, and the slice is finished and timed before the next."""
        ctx = self.ctx
        ctx.finish()
        self._last = None
        self._rate = 0.0
        items = FIRST_PIXELS
        first = 0
        while first < total:
            n = min(total - first, max(align, int(items) // align * align))
            t0 = time.perf_counter()
            yield first, n
            ctx.finish()
            self._done_tile((0, 0, n, 1), (time.perf_counter() - t0) * 1e3)
            items = self._next_pixels(n)
            first += n

    def _tiles(self, w: int, h: int):
        """(x, y, width, height) of each tile, bottom-up row strips of whole width or, where
        even :data:`ALIGN` rows take too long, strips of tiles; sized from :attr:`_last`."""
        self._last = None
        self._rate = 0.0  # ms per pixel of the draw's tiles after the first, the older halved
        pixels = FIRST_PIXELS
        y = 0
        while y < h:
            if pixels >= w * ALIGN or w <= ALIGN:
                rows = min(h - y, max(ALIGN, int(pixels // w) // ALIGN * ALIGN))
                yield 0, y, w, rows
                pixels = self._next_pixels(w * rows)
            else:
                rows, x = min(ALIGN, h - y), 0
                while x < w:
                    cols = min(w - x, max(ALIGN, int(pixels // ALIGN) // ALIGN * ALIGN))
                    yield x, y, cols, rows
                    pixels = self._next_pixels(cols * ALIGN)
                    x += cols
            y += rows

    def _done_tile(self, rect, ms: float) -> None:
        self.tiles += 1
        self.longest_ms = max(self.longest_ms, ms)
        if self._last is not None:
            self._rate = max(0.5 * self._rate, ms / (rect[2] * rect[3]))
        self._last = (rect[2] * rect[3], ms)
        if self.tick is not None:
            self.tick()

    def _next_pixels(self, pixels: int) -> float:
        """The next tile's pixels: :data:`AIM` of the budget at the time per pixel of the last
        tile, or half the highest of those before it where that is more (the first tile's alone
        only for the second: it holds the shader's first use); at most :data:`GROWTH` times the
        last tile's."""
        n, ms = self._last
        rate = self._rate or ms / n
        return min(GROWTH * pixels, AIM * self.max_draw_ms / max(rate, 1e-9))
