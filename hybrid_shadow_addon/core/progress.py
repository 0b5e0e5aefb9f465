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
    is through the stage, 0..1). Raises what the callback raises; on a :func:`run_reporting`
    worker whose wait was given up, :class:`Cancelled`."""
    stop = getattr(_local, "stop", None)
    if stop is not None and stop.is_set():
        raise Cancelled("stopped")
    r = _current()
    if r is not None:
        r.tick(share)


def run_reporting(fn, *args, progress: Progress | None = None, label: str = "", expected_s: float = 1.0,
                  interval: float = CHECK_INTERVAL):
    """``fn(*args)`` for work made of a few long numpy calls (a light grid's build): run on a
    worker thread while this one calls ``progress(share, 1, label)`` every ``interval`` seconds
    (``share``: the time waited over ``expected_s``, below 1). What ``progress`` raises ends the
    wait at once and stops the worker at its next :func:`checkpoint` (its result is dropped).
    Without ``progress``: ``fn(*args)`` here."""
    if progress is None:
        return fn(*args)
    stop = threading.Event()
    box: dict = {}

    def work():
        _local.stop = stop
        try:
            box["out"] = fn(*args)
        except BaseException as e:  # (re-raised by the caller)
            box["error"] = e

    worker = threading.Thread(target=work, name="hybrid-shadows-stage", daemon=True)
    t0 = time.perf_counter()
    worker.start()
    try:
        progress(0.0, 1, label)
        while True:
            worker.join(interval)
            if not worker.is_alive():
                break
            progress(min(0.99, (time.perf_counter() - t0) / max(expected_s, 1e-6)), 1, label)
    except BaseException:
        stop.set()
        raise
    if "error" in box:
        raise box["error"]
    return box["out"]


__all__ = ["Cancelled", "Progress", "call", "checkpoint", "null_progress", "reporting", "run_reporting", "stage"]
