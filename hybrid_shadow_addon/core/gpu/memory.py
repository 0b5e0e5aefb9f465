"""GPU memory in use, counted by the context that allocates it.

Drivers report free video memory only through vendor extensions (and software rasterisers not at
all), so each context counts what it allocates itself: :func:`track` wraps the context's
texture and buffer constructors; every object's bytes are added when it is made and taken off
when it is released (or collected). ``in_use(ctx)`` and ``peak(ctx)`` read the count.
"""
from __future__ import annotations

import weakref

_DTYPE_BYTES = {"f1": 1, "u1": 1, "i1": 1, "f2": 2, "u2": 2, "i2": 2, "f4": 4, "u4": 4, "i4": 4}
_MAKERS = ("texture", "depth_texture", "texture_array", "texture3d", "texture_cube", "buffer", "renderbuffer",
           "depth_renderbuffer")


class MemoryLedger:
    """Bytes held by one context's textures and buffers (``bytes``) and the most held at once
    since :meth:`reset_peak` (``peak``)."""

    def __init__(self):
        self.bytes = 0
        self.peak = 0

    def reset_peak(self) -> None:
        self.peak = self.bytes

    def add(self, obj, nbytes: int) -> None:
        self.bytes += nbytes
        self.peak = max(self.peak, self.bytes)
        state = {"held": nbytes}
        ref = weakref.ref(self)

        def forget(*_a, _state=state, _ledger=ref):
            ledger = _ledger()
            if ledger is not None and _state["held"]:
                ledger.bytes -= _state["held"]
                _state["held"] = 0

        release = obj.release

        def released(*a, **k):
            forget()
            return release(*a, **k)

        try:
            obj.release = released
            weakref.finalize(obj, forget)
        except (AttributeError, TypeError):  # an object that cannot carry the hook: counted as kept
            pass


def _object_bytes(obj) -> int:
    size = getattr(obj, "size", 0)
    if isinstance(size, int):  # a buffer
        return int(size)
    dims = [int(d) for d in size] if size else []
    layers = getattr(obj, "layers", None)
    if layers:
        dims.append(int(layers))
    n = 1
    for d in dims:
        n *= max(d, 1)
    comps = int(getattr(obj, "components", 4) or 4)
    per = _DTYPE_BYTES.get(str(getattr(obj, "dtype", "f4")), 4)
    samples = max(1, int(getattr(obj, "samples", 0) or 0))
    faces = 6 if type(obj).__name__ == "TextureCube" else 1
    return n * comps * per * samples * faces


def track(ctx) -> MemoryLedger:
    """Count ``ctx``'s allocations from now on (once per context); returns its ledger."""
    ledger = getattr(ctx, "_hs_memory", None)
    if ledger is not None:
        return ledger
    ledger = MemoryLedger()
    for name in _MAKERS:
        make = getattr(ctx, name, None)
        if make is None:
            continue

        def counted(*a, _make=make, **k):
            obj = _make(*a, **k)
            ledger.add(obj, _object_bytes(obj))
            return obj

        setattr(ctx, name, counted)
    ctx._hs_memory = ledger
    return ledger


def in_use(ctx) -> int:
    """Bytes ``ctx`` holds (0 for a context not tracked)."""
    ledger = getattr(ctx, "_hs_memory", None)
    return 0 if ledger is None else ledger.bytes


def peak(ctx) -> int:
    ledger = getattr(ctx, "_hs_memory", None)
    return 0 if ledger is None else ledger.peak
