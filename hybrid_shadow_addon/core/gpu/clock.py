"""Timing spans of GPU work that choices are made from (reuse or trace a light again, build a
light grid or not), without stalling the frame where the device allows.

:meth:`GpuClock.span` times the work issued inside it and hands the milliseconds to a callback:

- at once, between two ``ctx.finish()`` (two waits), by default and on a software rasteriser,
  whose timer queries do not measure its work (Mesa's llvmpipe answers a compute dispatch with
  0 ns and a fragment draw with a figure unrelated to it);
- or, in :attr:`GpuClock.deferred` frames (the viewport's: :attr:`.pipeline.Pipeline.timing`
  ``"frame"``) on a GPU with timer queries, through a ``GL_TIME_ELAPSED`` query whose result is
  read by :meth:`collect` at the start of the next frame, after that frame's image read has
  waited for the GPU: no wait of its own. Timer queries do not nest: an outer span's query
  stops while an inner span runs, and its time is the sum of its pieces and its inner spans'.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager

from .context import software_context


class _Span:
    """One deferred span: its queries (pieces between its inner spans) and inner spans."""

    def __init__(self, done):
        self.done = done
        self.pieces: list = []
        self.inner: list = []
        self.ms = 0.0


class GpuClock:
    def __init__(self, ctx):
        self.ctx = ctx
        #: whether this context's timer queries measure its work
        self.queries = not software_context(ctx)
        #: this frame's spans are read at the next frame's start (set per frame by the pipeline)
        self.deferred = False
        self._open: list = []  # the deferred spans open, innermost last
        self._pending: list = []  # the deferred spans ended since the last collect, in order
        self._pool: list = []

    @contextmanager
    def span(self, done: Callable[[float], None]):
        """Time the GPU work issued inside; ``done(ms)`` is called with its time (at once, or
        by the next :meth:`collect`)."""
        if not (self.deferred and self.queries):
            self.ctx.finish()
            t0 = time.perf_counter()
            yield
            self.ctx.finish()
            done((time.perf_counter() - t0) * 1e3)
            return
        outer = self._open[-1] if self._open else None
        if outer is not None:
            outer.pieces[-1].__exit__(None, None, None)
            outer.inner.append(None)  # (its place, filled once it ends)
        span = _Span(done)
        self._open.append(span)
        self._piece(span)
        try:
            yield
        finally:
            span.pieces[-1].__exit__(None, None, None)
            self._open.pop()
            if outer is not None:
                outer.inner[-1] = span
                self._piece(outer)
        self._pending.append(span)

    def _piece(self, span: _Span) -> None:
        query = self._pool.pop() if self._pool else self.ctx.query(time=True)
        query.__enter__()
        span.pieces.append(query)

    def collect(self) -> None:
        """Hand the times of the spans ended before to their callbacks, in the order the spans
        ended, inner ones first (a frame's start: the last frame's image read waited for their
        work)."""
        pending, self._pending = self._pending, []
        for span in pending:
            span.ms = sum(q.elapsed for q in span.pieces) / 1e6 + sum(s.ms for s in span.inner if s is not None)
            self._pool.extend(span.pieces)
            span.done(span.ms)

    def release(self) -> None:
        """Drop the spans not collected and the queries (moderngl's queries have no release:
        they go with the context)."""
        self._pending = []
        self._open = []
        self._pool = []
