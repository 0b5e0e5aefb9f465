"""The OpenGL context: one standalone moderngl context (or one handed in), GL >= 4.1 core.

On Linux the context comes from EGL (Mesa's llvmpipe on machines without a GPU). Before asking
for one we check that the libraries can be loaded, because a missing libEGL/libGL/DRI driver
otherwise surfaces as an obscure ``eglInitialize failed`` (and, inside Blender, can abort the
process). Every failure becomes a :class:`~hybrid_shadow_addon.core.errors.GPUError` with one
line that names the fix.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import sys

import moderngl

from ..errors import GPUError
from ..limits import gib, host_memory_bytes
from .host_counts import track as track_host_counts
from .lights import LIGHT_TEXELS
from .memory import track as track_memory

MIN_GL_VERSION = 410
DEBIAN_FIX = "sudo apt-get install libegl1 libgl1-mesa-dri libgl1"

# where Mesa puts its DRI/gallium drivers on common distributions
_DRI_DIRS = (
    "/usr/lib/x86_64-linux-gnu/dri", "/usr/lib/aarch64-linux-gnu/dri", "/usr/lib/i386-linux-gnu/dri",
    "/usr/lib/arm-linux-gnueabihf/dri", "/usr/lib64/dri", "/usr/lib/dri", "/usr/local/lib/dri",
    "/usr/local/lib64/dri", "/usr/lib/x86_64-linux-gnu/gallium-pipe",
)
_EGL_VENDOR_DIRS = ("/usr/share/glvnd/egl_vendor.d", "/etc/glvnd/egl_vendor.d")


def _load_library(name: str) -> bool:
    """True when the shared library ``name`` (e.g. ``"EGL"``, soname ``libEGL.so.1``) loads."""
    candidates = [f"lib{name}.so.1", f"lib{name}.so"]
    found = ctypes.util.find_library(name)
    if found:
        candidates.insert(0, found)
    for cand in candidates:
        try:
            ctypes.CDLL(cand)
            return True
        except OSError:
            continue
    return False


def _has_dri_driver() -> bool:
    """True when Mesa's DRI driver (or another EGL vendor, e.g. NVIDIA's) is installed."""
    dirs = [d for d in os.environ.get("LIBGL_DRIVERS_PATH", "").split(os.pathsep) if d]
    dirs += list(_DRI_DIRS) + glob.glob("/usr/lib/*/dri")
    for d in dirs:
        if glob.glob(os.path.join(d, "*_dri.so")) or glob.glob(os.path.join(d, "libgallium*.so")):
            return True
    # a non-Mesa EGL vendor (glvnd) does not need Mesa's DRI drivers
    for d in _EGL_VENDOR_DIRS:
        for f in glob.glob(os.path.join(d, "*.json")):
            if "mesa" not in os.path.basename(f).lower():
                return True
    return False


def check_linux_libraries() -> None:
    """Raise GPUError (one line, naming the Debian packages) when EGL/GL/DRI are missing."""
    missing = []
    if not _load_library("EGL"):
        missing.append("libEGL.so.1")
    if not _load_library("GL"):
        missing.append("libGL.so.1")
    if not _has_dri_driver():
        missing.append("Mesa's DRI driver")
    if missing:
        raise GPUError(f"OpenGL is unavailable ({', '.join(missing)} not found); install it with: {DEBIAN_FIX}")


def create_context(share: moderngl.Context | None = None) -> moderngl.Context:
    """The handed-in context, else a new standalone one (EGL on Linux). Requires GL >= 4.1."""
    if share is not None:
        ctx = share
    else:
        linux = sys.platform.startswith("linux")
        if linux:
            check_linux_libraries()
        try:
            if linux:
                ctx = moderngl.create_standalone_context(require=MIN_GL_VERSION, backend="egl")
            else:
                ctx = moderngl.create_standalone_context(require=MIN_GL_VERSION)
        except Exception as exc:  # glcontext raises plain Exceptions with EGL/WGL/CGL codes
            msg = " ".join(str(exc).split()) or type(exc).__name__
            fix = f"; install it with: {DEBIAN_FIX}" if linux else "; update the graphics driver"
            raise GPUError(f"could not create an OpenGL {MIN_GL_VERSION // 100}.{MIN_GL_VERSION % 100 // 10} "
                           f"context ({msg}){fix}") from None
    if ctx.version_code < MIN_GL_VERSION:
        raise GPUError(f"OpenGL {ctx.version_code // 100}.{ctx.version_code % 100 // 10} found, "
                       f"4.1 core or newer is needed ({ctx.info.get('GL_RENDERER', '?')})")
    track_memory(ctx)
    track_host_counts(ctx)
    return ctx


def make_current(ctx: moderngl.Context) -> None:
    """Make ``ctx`` the calling thread's current context. GL sends every call to the context the
    thread made current last, whichever moderngl object it is made through, and creating a
    standalone context makes it current: a pipeline used after another one was created on the
    same thread would draw into the newer context's objects. Every entry point that touches GL
    (:class:`Pipeline`'s, :func:`read_texture`) calls this first; switching to the context that
    is already current costs next to nothing."""
    ctx.__enter__()


def gpu_limits(ctx: moderngl.Context) -> dict:
    """The limits the passes check against, plus the renderer's name."""
    info = ctx.info
    vp = info.get("GL_MAX_VIEWPORT_DIMS", (0, 0))
    return {
        "renderer": str(info.get("GL_RENDERER", "")),
        "vendor": str(info.get("GL_VENDOR", "")),
        "version": str(info.get("GL_VERSION", "")),
        "gl_version_code": int(ctx.version_code),
        "max_texture_size": int(info.get("GL_MAX_TEXTURE_SIZE", 0)),
        "max_array_texture_layers": int(info.get("GL_MAX_ARRAY_TEXTURE_LAYERS", 0)),
        "max_3d_texture_size": int(info.get("GL_MAX_3D_TEXTURE_SIZE", 0)),
        "max_cube_map_texture_size": int(info.get("GL_MAX_CUBE_MAP_TEXTURE_SIZE", 0)),
        "max_renderbuffer_size": int(info.get("GL_MAX_RENDERBUFFER_SIZE", 0)),
        "max_viewport_dims": (int(vp[0]), int(vp[1])),
        "max_color_attachments": int(info.get("GL_MAX_COLOR_ATTACHMENTS", 0)),
        "max_texture_image_units": int(info.get("GL_MAX_TEXTURE_IMAGE_UNITS", 0)),
    }


#: names in ``GL_RENDERER`` of rasterisers that run on the CPU (Mesa's llvmpipe, softpipe and
#: swrast, SwiftShader, Apple's software renderer)
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "swiftshader", "software renderer")


def software_renderer(renderer: str) -> bool:
    """Whether ``renderer`` (a ``GL_RENDERER`` string) rasterises on the CPU. There the ray-traced
    ``medium`` and ``low`` cost more than ``high`` (``BENCHMARKS.md``, "Where the refinement's
    rays go"), which the viewport's automatic navigation quality follows."""
    name = str(renderer).lower()
    return any(k in name for k in SOFTWARE_RENDERERS)


def software_context(ctx) -> bool:
    """Whether ``ctx`` (a moderngl context, or anything with its ``info``) rasterises on the CPU
    (:func:`software_renderer` of its ``GL_RENDERER``)."""
    return software_renderer((getattr(ctx, "info", None) or {}).get("GL_RENDERER", ""))


#: bytes per pixel of the widest render target a frame makes (RGBA32F: the G-buffer's position,
#: normals and material, the lit image)
TARGET_BYTES_PER_PIXEL = 16

# GL enums of the proxy texture queries (GL 1.1 / 3.0 core): a proxy "allocation" asks the driver
# whether a texture of that size and format can be made, and allocates nothing
_PROXY_2D, _PROXY_2D_ARRAY, _TEXTURE_WIDTH = 0x8064, 0x8C1B, 0x1000
#: (moderngl dtype, components) -> (internal format, format, type) of a proxy query
_PROXY_FORMATS = {
    ("f4", 1): (0x822E, 0x1903, 0x1406), ("f4", 2): (0x8230, 0x8227, 0x1406),  # R32F, RG32F
    ("f4", 3): (0x8815, 0x1907, 0x1406), ("f4", 4): (0x8814, 0x1908, 0x1406),  # RGB32F, RGBA32F
    ("u4", 1): (0x8236, 0x8D94, 0x1405), ("u4", 2): (0x823C, 0x8228, 0x1405),  # R32UI, RG32UI
    ("u4", 3): (0x8D71, 0x8D98, 0x1405), ("u4", 4): (0x8D70, 0x8D99, 0x1405),  # RGB32UI, RGBA32UI
    ("f1", 4): (0x8058, 0x1908, 0x1401),  # RGBA8
}
_proxy_fns: list = []


def _proxy_functions():
    """``(glTexImage2D, glTexImage3D, glGetTexLevelParameteriv)`` through ctypes, or None."""
    if not _proxy_fns:
        from .buffer_textures import _resolver

        fns = None
        try:
            find = _resolver()
            addrs = [find(n) for n in ("glTexImage2D", "glTexImage3D", "glGetTexLevelParameteriv")] if find else []
            if addrs and all(addrs):
                u, i, p = ctypes.c_uint, ctypes.c_int, ctypes.c_void_p
                fns = (ctypes.CFUNCTYPE(None, u, i, i, i, i, i, u, u, p)(addrs[0]),
                       ctypes.CFUNCTYPE(None, u, i, i, i, i, i, i, u, u, p)(addrs[1]),
                       ctypes.CFUNCTYPE(None, u, i, u, ctypes.POINTER(i))(addrs[2]))
        except (OSError, AttributeError, TypeError):
            fns = None
        _proxy_fns.append(fns)
    return _proxy_fns[0]


def texture_fits(ctx: moderngl.Context, width: int, height: int, components: int = 4, dtype: str = "f4",
                 layers: int = 0) -> bool | None:
    """Whether the driver would make a ``width`` x ``height`` texture (a 2D array of ``layers``
    when ``layers`` > 0) of that format, by a proxy query (nothing is allocated; ``ctx`` must be
    current); None where it cannot be asked. GL states only a size per side, but a software
    rasteriser also refuses a texture of more bytes than it allows (Mesa's llvmpipe: 1.5 GiB,
    e.g. 16384 x 6140 RGBA32F) with a ``GL_OUT_OF_MEMORY`` that moderngl does not raise: the
    texture stays empty and a framebuffer over it is incomplete. The proxy says so beforehand."""
    fns = _proxy_functions()
    fmt = _PROXY_FORMATS.get((dtype, int(components)))
    if fns is None or fmt is None:
        return None
    tex2d, tex3d, level = fns
    if layers > 0:
        tex3d(_PROXY_2D_ARRAY, 0, fmt[0], int(width), int(height), int(layers), 0, fmt[1], fmt[2], None)
        target = _PROXY_2D_ARRAY
    else:
        tex2d(_PROXY_2D, 0, fmt[0], int(width), int(height), 0, fmt[1], fmt[2], None)
        target = _PROXY_2D
    out = ctypes.c_int(0)
    level(target, 0, _TEXTURE_WIDTH, ctypes.byref(out))
    return out.value != 0


def largest_fit(most: int, fits) -> int:
    """The largest ``n`` in ``0 .. most`` for which ``fits(n)`` is not False (a binary search:
    ``fits`` a :func:`texture_fits` query that holds up to some size)."""
    lo, hi = 0, int(most)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if fits(mid) is not False else (lo, mid - 1)
    return lo


def largest_rows(ctx: moderngl.Context, width: int, components: int = 4, dtype: str = "f4", layers: int = 0,
                 cap: int | None = None) -> int:
    """The most rows (up to ``cap``, else ``GL_MAX_TEXTURE_SIZE``) of a ``width``-wide texture of
    that format the driver makes (:func:`texture_fits`)."""
    return largest_fit(cap or gpu_limits(ctx)["max_texture_size"],
                       lambda rows: texture_fits(ctx, width, rows, components, dtype, layers))


def check_render_size(ctx: moderngl.Context, width: int, height: int, what: str = "render") -> None:
    """GPUError when a ``width`` x ``height`` target exceeds the GPU's limits: a side beyond the
    largest texture, renderbuffer or viewport, or more pixels than the driver makes an RGBA32F
    texture of (``TARGET_BYTES_PER_PIXEL``, :func:`texture_fits`)."""
    lim = gpu_limits(ctx)
    cap = min(lim["max_texture_size"], lim["max_renderbuffer_size"], *lim["max_viewport_dims"])
    if width < 1 or height < 1 or width > cap or height > cap:
        raise GPUError(f"{what} size {width}x{height} is outside this GPU's limits (1..{cap} per side)")
    if texture_fits(ctx, width, height, 4, "f4") is False:
        rows = largest_rows(ctx, width, cap=height)
        raise GPUError(f"{what} size {width}x{height} needs {gib(width * height * TARGET_BYTES_PER_PIXEL)} per "
                       f"RGBA32F target; this GPU makes at most {width}x{rows} "
                       f"({gib(width * rows * TARGET_BYTES_PER_PIXEL)}, {width * rows:,} pixels)")


#: bytes per pixel a frame holds whatever its lights: the G-buffer's seven targets and its depth
#: (96), the lit image (16) and its read-back (16)
FRAME_BYTES_PER_PIXEL = 128
#: bytes per pixel each shadowed light adds: its R32F mask, kept at full resolution until the
#: lighting pass has read every mask (a soft light's sums and ranges add more, left out here)
MASK_BYTES_PER_PIXEL = 4


def check_frame_memory(ctx: moderngl.Context, width: int, height: int, shadowed_lights: int) -> None:
    """GPUError when a ``width`` x ``height`` frame with ``shadowed_lights`` masks needs more
    memory than there is, before any of it is made: on a software rasteriser (its textures are
    this process's memory, :func:`host_memory_bytes`), where running out kills the process or
    leaves targets silently empty. The need counted is a lower bound (``FRAME_BYTES_PER_PIXEL``
    + ``MASK_BYTES_PER_PIXEL`` per light); a GPU pages its own memory and is not checked."""
    if not software_context(ctx):
        return
    have = host_memory_bytes()
    need = int(width) * int(height) * (FRAME_BYTES_PER_PIXEL + MASK_BYTES_PER_PIXEL * int(shadowed_lights))
    if have and need > have:
        raise GPUError(f"a {width}x{height} frame with {shadowed_lights} shadowed lights needs at least {gib(need)} "
                       f"of render targets; this machine has {gib(have)} (shadow fewer lights or render smaller)")


#: texels per light in the lighting pass's light table (``shaders/common/lights.glsl``)
LIGHT_TABLE_TEXELS = LIGHT_TEXELS


def max_lights(ctx: moderngl.Context) -> int:
    """Lights the lighting pass can hold: one row of ``LIGHT_TABLE_TEXELS`` texels per light in a
    texture at most ``GL_MAX_TEXTURE_SIZE`` wide (3276 on a 16384 GPU)."""
    return gpu_limits(ctx)["max_texture_size"] // LIGHT_TABLE_TEXELS


def check_light_count(ctx: moderngl.Context, count: int) -> None:
    """GPUError when a scene has more lights than the lighting pass can hold."""
    limit = max_lights(ctx)
    if count > limit:
        raise GPUError(f"the scene has {count} lights; this GPU can light at most {limit} "
                       f"(hide some lights from rendering)")
