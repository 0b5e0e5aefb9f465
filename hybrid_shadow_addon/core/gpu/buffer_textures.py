"""Buffer textures (``GL_TEXTURE_BUFFER``, core since GL 3.1): the scene's record textures as
one linear array each, read in GLSL by ``texelFetch(samplerBuffer, i)``.

moderngl has no buffer textures, so the few GL calls they need are made here through ctypes, on
the context the caller made current. A record fetch from a buffer texture skips the 2D array's
(x, y, layer) split and its mip, row and layer offsets: on llvmpipe a dependent fetch costs 1.5
ns instead of 1.9-2.2, and hard shadows take about a sixth less time (BENCHMARKS.md, "Buffer
textures, lights that reach nothing").

:func:`gl_functions` returns ``None`` where the entry points cannot be found (an unknown
platform); :class:`~.scene_textures.SceneTextures` then keeps 2D array textures, which the
shaders read the same records from (``HS_FETCH`` in ``shaders/common/scene_data.glsl``).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

import moderngl

from ..errors import GPUError

GL_TEXTURE_BUFFER = 0x8C2A
GL_TEXTURE0 = 0x84C0
GL_MAX_TEXTURE_BUFFER_SIZE = 0x8C2B
GL_NO_ERROR = 0

#: (moderngl dtype, components) -> sized internal format of a buffer texture
INTERNAL_FORMATS = {
    ("u4", 1): 0x8236,  # GL_R32UI
    ("u4", 2): 0x823C,  # GL_RG32UI
    ("u4", 3): 0x8D71,  # GL_RGB32UI
    ("u4", 4): 0x8D70,  # GL_RGBA32UI
    ("f4", 1): 0x822E,  # GL_R32F
    ("f4", 2): 0x8230,  # GL_RG32F
    ("f4", 3): 0x8815,  # GL_RGB32F
    ("f4", 4): 0x8814,  # GL_RGBA32F
}

_u, _i = ctypes.c_uint, ctypes.c_int
_SIGNATURES = {
    "glGenTextures": (None, _i, ctypes.POINTER(_u)),
    "glDeleteTextures": (None, _i, ctypes.POINTER(_u)),
    "glBindTexture": (None, _u, _u),
    "glActiveTexture": (None, _u),
    "glTexBuffer": (None, _u, _u, _u),
    "glGetIntegerv": (None, _u, ctypes.POINTER(_i)),
    "glGetError": (_u,),
    "glProgramUniform1i": (None, _u, _i, _i),
}
_loaded: dict | None = None
_tried = False


def _resolver():
    """A function name -> address lookup for this platform's GL, or None."""
    if sys.platform.startswith("linux"):
        for name in ("libEGL.so.1", "libEGL.so"):
            try:
                egl = ctypes.CDLL(name)
            except OSError:
                continue
            egl.eglGetProcAddress.restype = ctypes.c_void_p
            egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
            return lambda fn: egl.eglGetProcAddress(fn.encode())
        return None
    if sys.platform == "darwin":
        path = ctypes.util.find_library("OpenGL") or "/System/Library/Frameworks/OpenGL.framework/OpenGL"
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            return None

        def exported(fn):
            return ctypes.cast(getattr(lib, fn), ctypes.c_void_p).value if hasattr(lib, fn) else None
        return exported
    if sys.platform == "win32":
        try:
            lib = ctypes.WinDLL("opengl32")
        except OSError:
            return None
        lib.wglGetProcAddress.restype = ctypes.c_void_p
        lib.wglGetProcAddress.argtypes = [ctypes.c_char_p]

        def find(fn):  # GL 1.1 functions are exports of opengl32, later ones come from the driver
            if hasattr(lib, fn):
                return ctypes.cast(getattr(lib, fn), ctypes.c_void_p).value
            addr = lib.wglGetProcAddress(fn.encode())
            # (some drivers answer 1, 2, 3 or -1 instead of NULL for a function they lack)
            return None if addr in (None, 1, 2, 3, 2 ** 64 - 1, -1) else addr
        return find
    return None


def gl_functions() -> dict | None:
    """The GL entry points buffer textures need, or None where they cannot all be found."""
    global _loaded, _tried
    if _tried:
        return _loaded
    _tried = True
    try:
        find = _resolver()
        if find is None:
            return None
        fns = {}
        for name, (res, *args) in _SIGNATURES.items():
            addr = find(name)
            if not addr:
                return None
            fns[name] = ctypes.CFUNCTYPE(res, *args)(addr)
        _loaded = fns
    except (OSError, AttributeError, TypeError):
        _loaded = None
    return _loaded


def max_texels(ctx: moderngl.Context) -> int:
    """GL_MAX_TEXTURE_BUFFER_SIZE of the current context (0 without the entry points)."""
    gl = gl_functions()
    if gl is None:
        return 0
    v = ctypes.c_int(0)
    gl["glGetIntegerv"](GL_MAX_TEXTURE_BUFFER_SIZE, ctypes.byref(v))
    return max(0, int(v.value))


class BufferTexture:
    """One buffer texture: a moderngl buffer holding the texels, viewed by a GL texture object.

    ``write(data, offset)`` updates texels in place (byte offset); ``use(prog, sampler, unit)``
    binds it to ``unit`` and points the program's sampler there (moderngl's uniform objects do
    not know buffer samplers)."""

    def __init__(self, ctx: moderngl.Context, data: bytes, dtype: str, components: int):
        gl = gl_functions()
        fmt = INTERNAL_FORMATS.get((dtype, components))
        if gl is None or fmt is None:
            raise GPUError(f"buffer textures are not available for {dtype} x {components}")
        self.gl = gl
        for _ in range(16):  # errors left by earlier calls are not this texture's
            if gl["glGetError"]() == GL_NO_ERROR:
                break
        self.buffer = ctx.buffer(data)
        tid = ctypes.c_uint(0)
        gl["glGenTextures"](1, ctypes.byref(tid))
        self.glo = int(tid.value)
        gl["glActiveTexture"](GL_TEXTURE0)
        gl["glBindTexture"](GL_TEXTURE_BUFFER, self.glo)
        gl["glTexBuffer"](GL_TEXTURE_BUFFER, fmt, self.buffer.glo)
        gl["glBindTexture"](GL_TEXTURE_BUFFER, 0)
        err = gl["glGetError"]()
        if self.glo == 0 or err != GL_NO_ERROR:
            self.release()
            raise GPUError(f"could not create a buffer texture (GL error 0x{err:04X})")

    def write(self, data: bytes, offset: int = 0) -> None:
        self.buffer.write(data, offset=offset)

    def use(self, prog: moderngl.Program, sampler: str, unit: int) -> None:
        gl = self.gl
        gl["glActiveTexture"](GL_TEXTURE0 + unit)
        gl["glBindTexture"](GL_TEXTURE_BUFFER, self.glo)
        gl["glProgramUniform1i"](prog.glo, prog[sampler].location, unit)

    def release(self) -> None:
        if self.glo:
            self.gl["glDeleteTextures"](1, ctypes.byref(ctypes.c_uint(self.glo)))
            self.glo = 0
        if self.buffer is not None:
            self.buffer.release()
            self.buffer = None
