"""The one progress-callback signature of the project: ``progress(done, total, label)``.

``done`` of ``total`` steps are finished and ``label`` names the step about to run (or the one
just finished, for the last call). A callback may raise :class:`~.errors.Cancelled` (or any
error) to stop the work: the pipeline, ``compare`` and ``bench`` let it propagate.
"""
from __future__ import annotations

from collections.abc import Callable

from .errors import Cancelled

Progress = Callable[[int, int, str], None]


def null_progress(done: int, total: int, label: str = "") -> None:
    """A progress callback that does nothing."""


def call(progress: Progress | None, done: int, total: int, label: str = "") -> None:
    """``progress(done, total, label)`` when a callback is given."""
    if progress is not None:
        progress(done, total, label)


__all__ = ["Cancelled", "Progress", "call", "null_progress"]
