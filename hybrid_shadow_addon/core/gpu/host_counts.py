"""What a frame asks of the GPU from the host, counted by the context: draws, compute
dispatches, waits and bytes read back (``Frame.stats``: ``draws``, ``dispatches``, ``waits``,
``bytes_read_back``).

As :mod:`.memory` counts allocations, :func:`track` wraps the context's makers so that each
object it makes counts its own calls: a vertex array's ``render``, a compute program's ``run``
and ``run_indirect``, a texture's, buffer's or framebuffer's ``read`` (a wait and its bytes),
an occlusion query's ``samples`` (a wait and 4 bytes, once per query and use), a timer query's
``elapsed`` (8 bytes and no wait: :mod:`.clock` reads it once the frame that issued it was waited
for) and the context's ``finish`` (a wait). A frame's counts are :meth:`HostCounts.since` a :meth:`HostCounts.mark`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

_READERS = ("texture", "depth_texture", "texture_array", "texture3d", "texture_cube", "buffer", "framebuffer",
            "simple_framebuffer")


@dataclass
class HostCounts:
    draws: int = 0
    dispatches: int = 0
    waits: int = 0
    bytes_read_back: int = 0

    def mark(self) -> HostCounts:
        """A copy of the counts now (the start of a frame)."""
        return HostCounts(**asdict(self))

    def since(self, start: HostCounts) -> dict:
        """The counts since ``start`` (a :meth:`mark`), as a dict."""
        now, then = asdict(self), asdict(start)
        return {k: now[k] - then[k] for k in now}

    def read(self, nbytes: int) -> None:
        self.waits += 1
        self.bytes_read_back += int(nbytes)


class _CountedQuery:
    """An occlusion query whose ``samples`` read counts as a wait and 4 bytes read back (a timer
    query's ``elapsed``: 8 bytes)."""

    def __init__(self, query, counts: HostCounts):
        self._query = query
        self._counts = counts

    def __enter__(self):
        self._query.__enter__()
        return self

    def __exit__(self, *exc):
        return self._query.__exit__(*exc)

    @property
    def samples(self) -> int:
        self._counts.read(4)
        return self._query.samples

    @property
    def elapsed(self) -> int:
        self._counts.bytes_read_back += 8
        return self._query.elapsed

    def release(self) -> None:
        self._query.release()


def _wrap(obj, name: str, wrapper) -> None:
    method = getattr(obj, name, None)
    if method is not None:
        try:
            setattr(obj, name, wrapper(method))
        except (AttributeError, TypeError):  # an object that cannot carry the hook: not counted
            pass


def track(ctx) -> HostCounts:
    """Count ``ctx``'s host calls from now on (once per context); returns its counts."""
    counts = getattr(ctx, "_hs_host_counts", None)
    if counts is not None:
        return counts
    counts = HostCounts()

    def counting(field):
        def wrapper(method):
            def counted(*a, **k):
                setattr(counts, field, getattr(counts, field) + 1)
                return method(*a, **k)
            return counted
        return wrapper

    def reading(method):
        def counted(*a, **k):
            data = method(*a, **k)
            counts.read(len(data) if isinstance(data, (bytes, bytearray)) else 0)
            return data
        return counted

    def maker(name, hook):
        make = getattr(ctx, name, None)
        if make is None:
            return

        def made(*a, _make=make, **k):
            obj = _make(*a, **k)
            return hook(obj)

        setattr(ctx, name, made)

    def vao_hook(vao):
        _wrap(vao, "render", counting("draws"))
        return vao

    def compute_hook(prog):
        _wrap(prog, "run", counting("dispatches"))
        _wrap(prog, "run_indirect", counting("dispatches"))
        return prog

    def reader_hook(obj):
        _wrap(obj, "read", reading)
        return obj

    maker("vertex_array", vao_hook)
    maker("compute_shader", compute_hook)
    for name in _READERS:
        maker(name, reader_hook)
    maker("query", lambda q: _CountedQuery(q, counts))
    _wrap(ctx, "finish", counting("waits"))
    ctx._hs_host_counts = counts
    return counts


def counts_of(ctx) -> HostCounts:
    """``ctx``'s counts (a fresh, unattached one for a context not tracked)."""
    return getattr(ctx, "_hs_host_counts", None) or HostCounts()
