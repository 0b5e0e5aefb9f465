"""The one progress-callback signature of the project: ``progress(done, total, label)``.

``done`` of ``total`` steps are finished and ``label`` names the step about to run (or the one
just finished, for the last call). A callback may raise :class:`~.errors.Cancelled` (or any
error) to stop the work: the pipeline, ``compare`` and ``bench`` let it propagate. Long CPU
stages (bakes, light grids) report from their loops through :func:`reporting` and
:func:`checkpoint`, so that a raise stops them between two checkpoints.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import contextmanager

from .errors import Cancelled

Progress = Callable[[int, int, str], None]


def null_progress(done: int, total: int, label: str = "") -> None:
    """A progress callback that does nothing."""


def call(progress: Progress | None, done: int, total: int, label: str = "") -> None:
    """``progress(done, total, label)`` when a callback is given."""
    if progress is not None:
        progress(done, total, label)




# -- long CPU stages ---------------------------------------------------------------------------
#: a stage's checkpoints call its callback at most this often (seconds)
CHECK_INTERVAL = 0.02

_local = threading.local()


class _Reporter:
    """A long stage's callback: :meth:`stage` calls it at once, :meth:`tick` at most every
    ``interval`` seconds, with ``done`` moved on by a share of the current stage."""

    def __init__(self, progress: Progress, total: float, interval: float):
        self.progress = progress
        self.total = total
        self.interval = interval
        self.done = 0.0
        self.label = ""
        self.last = time.perf_counter()

    def stage(self, done: float, label: str) -> None:
        self.done, self.label = done, label
        self._call(0.0)

    def tick(self, share: float) -> None:
        if time.perf_counter() - self.last >= self.interval:
            self._call(share)

    def _call(self, share: float) -> None:
        self.last = time.perf_counter()
        self.progress(self.done + min(max(share, 0.0), 0.99), self.total, self.label)


@contextmanager
def reporting(progress: Progress | None, total: float = 1, interval: float = CHECK_INTERVAL):
    """Within it, :func:`stage` and :func:`checkpoint` on this thread reach ``progress`` (None:
    they do nothing), so that deep loops report (and a callback that raises stops them) without
    a callback passed down to each. Other threads' checkpoints are not reported."""
    stack = _local.__dict__.setdefault("stack", [])
    stack.append(None if progress is None else _Reporter(progress, total, interval))
    try:
        yield
    finally:
        stack.pop()


def _current() -> _Reporter | None:
    stack = getattr(_local, "stack", None)
    return stack[-1] if stack else None


def stage(done: float, label: str) -> None:
    """The current :func:`reporting` stage is now ``done`` of its total, named ``label``."""
    r = _current()
    if r is not None:
        r.stage(done, label)


def checkpoint(share: float = 0.0) -> None:
    """A point in a long loop where the work may be stopped: the current stage's callback is
    called if :data:`CHECK_INTERVAL` has passed since its last call (``share``: how far the loop
    is through the stage, 0..1). Raises what the callback raises."""
    r = _current()
    if r is not None:
        r.tick(share)


__all__ = ["Cancelled", "Progress", "call", "checkpoint", "null_progress", "reporting", "stage"]
