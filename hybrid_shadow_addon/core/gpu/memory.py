"""GPU memory in use, counted by the context that allocates it, and GL objects dropped without
being released.

Drivers report free video memory only through vendor extensions (and software rasterisers not at
all), so each context counts what it allocates itself: :func:`track` wraps the context's
constructors. A texture's or buffer's bytes are added when it is made and taken off when it is
released. moderngl frees an object's GL memory only on ``release()``: one that Python collects
unreleased is recorded as *dropped* (its kind and bytes in ``MemoryLedger.dropped``) and its bytes
stay counted until :func:`collect` hands it to the context's ``gc()`` (the context runs with
``gc_mode = "context_gc"``, so dropped objects queue there instead of leaking). Every pass
releases what it makes; tests assert that nothing is dropped.

``in_use(ctx)`` and ``peak(ctx)`` read the count; :func:`driver_memory` asks the driver where it
can tell.
"""
from __future__ import annotations

import ctypes
import sys
import weakref

from ..limits import process_memory_bytes

_DTYPE_BYTES = {"f1": 1, "u1": 1, "i1": 1, "f2": 2, "u2": 2, "i2": 2, "f4": 4, "u4": 4, "i4": 4}
#: constructors whose objects hold memory (counted in bytes)
_MAKERS = ("texture", "depth_texture", "texture_array", "texture3d", "texture_cube", "buffer", "renderbuffer",
           "depth_renderbuffer")
#: constructors of the other objects that must be released (counted as dropped, 0 bytes). Queries
#: are left out: moderngl gives them no ``release()``, so passes keep theirs in pools.
_OBJECT_MAKERS = ("program", "compute_shader", "vertex_array", "simple_vertex_array", "framebuffer",
                  "simple_framebuffer", "sampler", "scope")


class MemoryLedger:
    """Bytes held by one context's textures and buffers (``bytes``), the most held at once since
    :meth:`reset_peak` (``peak``), and the objects collected without ``release()``
    (``dropped``: ``(kind, bytes)`` each; their bytes stay in ``bytes`` until :func:`collect`)."""

    def __init__(self):
        self.bytes = 0
        self.peak = 0
        self.dropped: list[tuple[str, int]] = []
        self._uncollected = 0  # bytes of dropped objects not yet handed to ctx.gc()

    def reset_peak(self) -> None:
        self.peak = self.bytes

    def add(self, obj, nbytes: int) -> None:
        self.bytes += nbytes
        self.peak = max(self.peak, self.bytes)
        state = {"held": nbytes, "released": False}
        ref = weakref.ref(self)
        kind = type(obj).__name__

        def on_release(*_a, _state=state, _ledger=ref):
            ledger = _ledger()
            if ledger is not None and not _state["released"]:
                ledger.bytes -= _state["held"]
            _state["released"] = True

        def on_collect(_state=state, _ledger=ref, _kind=kind):
            ledger = _ledger()
            if ledger is not None and not _state["released"]:
                ledger.dropped.append((_kind, _state["held"]))
                ledger._uncollected += _state["held"]

        release = obj.release

        def released(*a, **k):
            on_release()
            return release(*a, **k)

        try:
            obj.release = released
            weakref.finalize(obj, on_collect)
        except (AttributeError, TypeError):  # an object that cannot carry the hook: counted as kept
            pass

    def collected(self) -> None:
        """The dropped objects were released by the context's ``gc()``."""
        self.bytes -= self._uncollected
        self._uncollected = 0


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
    """Count ``ctx``'s allocations and dropped objects from now on (once per context); returns
    its ledger. Sets ``ctx.gc_mode = "context_gc"`` (:func:`collect` frees what was dropped)."""
    ledger = getattr(ctx, "_hs_memory", None)
    if ledger is not None:
        return ledger
    ledger = MemoryLedger()
    for name in _MAKERS + _OBJECT_MAKERS:
        make = getattr(ctx, name, None)
        if make is None:
            continue
        sized = name in _MAKERS

        def counted(*a, _make=make, _sized=sized, **k):
            obj = _make(*a, **k)
            ledger.add(obj, _object_bytes(obj) if _sized else 0)
            return obj

        setattr(ctx, name, counted)
    try:
        ctx.gc_mode = "context_gc"
    except (AttributeError, ValueError):  # a moderngl without collection modes
        pass
    ctx._hs_memory = ledger
    return ledger


def collect(ctx) -> int:
    """Release the GL objects that were collected unreleased (``ctx`` must be current); the
    number released. (moderngl also queues the husks of released objects, which ``ctx.gc()``
    cannot release: they are skipped here.)"""
    queue = getattr(ctx, "objects", None)
    if queue is None or getattr(ctx, "gc_mode", None) != "context_gc":
        return 0
    n = 0
    while queue:
        obj = queue.popleft()
        release = getattr(obj, "release", None)
        if release is not None:
            release()
            n += 1
    ledger = getattr(ctx, "_hs_memory", None)
    if ledger is not None:
        ledger.collected()
    return n


def in_use(ctx) -> int:
    """Bytes ``ctx`` holds (0 for a context not tracked)."""
    ledger = getattr(ctx, "_hs_memory", None)
    return 0 if ledger is None else ledger.bytes


def peak(ctx) -> int:
    ledger = getattr(ctx, "_hs_memory", None)
    return 0 if ledger is None else ledger.peak


def dropped(ctx) -> list:
    """``(kind, bytes)`` of each object ``ctx`` had collected without ``release()``."""
    ledger = getattr(ctx, "_hs_memory", None)
    return [] if ledger is None else list(ledger.dropped)


#: GL enums of the vendor extensions that report video memory, in KiB
_NVX_TOTAL, _NVX_AVAILABLE = 0x9048, 0x9049  # GL_NVX_gpu_memory_info
_ATI_TEXTURE_FREE = 0x87FC  # GL_ATI_meminfo: TEXTURE_FREE_MEMORY_ATI (4 ints, [0] = total free)


def driver_memory(ctx) -> dict | None:
    """The driver's own figure of video memory, where it has one: ``{"used_mb", "total_mb"}``
    (``GL_NVX_gpu_memory_info``) or ``{"free_mb"}`` (``GL_ATI_meminfo``); None elsewhere
    (software rasterisers, Apple, Intel)."""
    try:
        ext = ctx.extensions
    except Exception:  # noqa: BLE001 - a context that cannot list them
        return None
    if "GL_NVX_gpu_memory_info" in ext:
        total, avail = _gl_int(ctx, _NVX_TOTAL), _gl_int(ctx, _NVX_AVAILABLE)
        if total is not None and avail is not None:
            return {"used_mb": (total - avail) / 1024.0, "total_mb": total / 1024.0}
    if "GL_ATI_meminfo" in ext:
        free = _gl_int(ctx, _ATI_TEXTURE_FREE)
        if free is not None:
            return {"free_mb": free / 1024.0}
    return None


def _gl_int(ctx, enum: int):
    """``glGetIntegerv(enum)``'s first value on ``ctx`` (current); None where it cannot be asked."""
    from .buffer_textures import gl_functions

    gl = gl_functions()
    if gl is None:
        return None
    out = (ctypes.c_int * 4)()  # (GL_ATI_meminfo's queries write four)
    gl["glGetIntegerv"](enum, out)
    return int(out[0])


def trim_heap() -> None:
    """Give the C heap's free pages back to the system (glibc's ``malloc_trim``): a frame's
    read-backs and scene arrays are freed in pieces that glibc otherwise keeps, so a renderer
    process would grow from frame to frame without holding more. A no-op elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    if not _LIBC:
        try:
            libc = ctypes.CDLL("libc.so.6")
            libc.malloc_trim  # noqa: B018 - musl has none
        except (OSError, AttributeError):
            libc = None
        _LIBC.append(libc)
    if _LIBC[0] is not None:
        _LIBC[0].malloc_trim(0)


_LIBC = []


def process_rss_mb(pid=None) -> float | None:
    """The resident memory in MiB of process ``pid`` (None: this one); None where the system
    does not tell (:func:`..limits.process_memory_bytes`)."""
    n = process_memory_bytes(pid)
    return n / 2**20 if n else None
