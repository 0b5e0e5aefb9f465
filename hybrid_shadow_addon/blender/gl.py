"""The add-on's standalone OpenGL contexts and their hygiene on Blender's threads.

A pipeline owns a standalone context. It is never left current on Blender's threads: every use
goes through :func:`gl_scope`, which makes it current and restores whatever context the thread
had before (Blender's own in the viewport). The viewport's render workers
(:mod:`..core.runtime.worker`) create, use and release theirs with the same three functions, on
their own thread (or inline, in the synchronous debugging mode).
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import sys
import threading


class _EGLCurrent:
    """Save and restore the calling thread's current EGL context (Blender's, in the viewport),
    around the creation of our standalone context, which makes itself current."""

    _lib = None

    @classmethod
    def lib(cls):
        if cls._lib is None and sys.platform.startswith("linux"):
            try:
                lib = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
                for name in ("eglGetCurrentDisplay", "eglGetCurrentContext"):
                    getattr(lib, name).restype = ctypes.c_void_p
                lib.eglGetCurrentSurface.restype = ctypes.c_void_p
                lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
                lib.eglMakeCurrent.restype = ctypes.c_uint
                lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
                cls._lib = lib
            except OSError:
                cls._lib = False
        return cls._lib or None

    def __enter__(self):
        lib = self.lib()
        self.saved = None
        if lib is not None:
            self.saved = (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(0x3059),
                          lib.eglGetCurrentSurface(0x305A), lib.eglGetCurrentContext())
        return self

    def __exit__(self, *exc):
        lib = self.lib()
        if lib is None or self.saved is None:
            return False
        dpy, draw, read, ctx = self.saved
        if ctx:
            lib.eglMakeCurrent(dpy, draw, read, ctx)
        else:
            ours = lib.eglGetCurrentDisplay()
            if ours:
                lib.eglMakeCurrent(ours, None, None, None)
        return False


def create_pipeline():
    """A new :class:`Pipeline` with its own context, leaving the thread's context as it was."""
    from ..core.gpu.pipeline import Pipeline

    with _EGLCurrent():
        return Pipeline()


@contextlib.contextmanager
def gl_scope(pipeline):
    """Make ``pipeline``'s context current meanwhile; restore the previous one after.
    (moderngl's ``with ctx`` alone leaves *no* context current on exit, which breaks Blender's
    drawing afterwards.)"""
    with _EGLCurrent(), pipeline.ctx:
        yield pipeline


def release_pipeline(pipeline) -> None:
    """Release ``pipeline``'s GPU objects and its context (None: nothing to do)."""
    if pipeline is None:
        return
    try:
        with gl_scope(pipeline):
            pipeline.release()
        with _EGLCurrent():
            pipeline.ctx.release()
    except Exception:  # at exit the context may already be gone
        pass


# one renderer process for final renders, shared by the engine instances of this process
# (programs stay compiled from one F12 to the next; with persistent data the bake too); ended
# when the add-on is disabled
_final = {"renderer": None}
_final_lock = threading.Lock()


def final_renderer():
    """The shared final-render :class:`~..core.runtime.remote.FinalRenderer` (started on first use)."""
    from ..core.runtime.remote import FinalRenderer

    with _final_lock:
        if _final["renderer"] is None:
            _final["renderer"] = FinalRenderer()
        return _final["renderer"]


def release_shared() -> None:
    """End the shared final-render process (and what it kept)."""
    with _final_lock:
        renderer, _final["renderer"] = _final["renderer"], None
    if renderer is not None:
        renderer.close()
