"""A terminal progress bar for ``compare`` and ``bench``: a
:data:`~hybrid_shadow_addon.core.progress.Progress` callback, ``progress(done, total, label)``."""
from __future__ import annotations

import sys
import time


class TerminalProgress:
    """``[#######.......]  12/40  30%  label  ETA 0:42`` redrawn in place on a terminal (stderr);
    on a pipe, one line per step at most every ``interval`` seconds (and the last one)."""

    def __init__(self, title: str = "", stream=None, width: int = 28, interval: float = 2.0):
        self.title = title
        self.stream = stream or sys.stderr
        self.width = width
        self.interval = interval
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self._last = 0.0
        self._drawn = False

    def __call__(self, done: int, total: int, label: str = "") -> None:
        total = max(int(total), 1)
        done = min(max(int(done), 0), total)
        now = time.perf_counter()
        if not self.tty and done < total and now - self._last < self.interval:
            return
        self._last = now
        frac = done / total
        fill = int(round(self.width * frac))
        elapsed = now - self.t0
        eta = f"ETA {_clock(elapsed / frac - elapsed)}" if 0 < frac < 1 else f"{_clock(elapsed)}"
        line = (f"{self.title + ' ' if self.title else ''}[{'#' * fill}{'.' * (self.width - fill)}] "
                f"{done:>{len(str(total))}}/{total} {100 * frac:3.0f}%  {eta}  {label}")
        if self.tty:
            cols = 120
            self.stream.write("\r" + line[:cols].ljust(cols if self._drawn else 0))
            self._drawn = True
            if done >= total:
                self.stream.write("\n")
                self._drawn = False
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


def _clock(seconds: float) -> str:
    s = int(max(seconds, 0))
    return f"{s // 60}:{s % 60:02d}"
