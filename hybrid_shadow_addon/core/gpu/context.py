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
from .host_counts import track as track_host_counts
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


def check_render_size(ctx: moderngl.Context, width: int, height: int, what: str = "render") -> None:
    """GPUError when a ``width`` x ``height`` target exceeds the GPU's limits."""
    lim = gpu_limits(ctx)
    cap = min(lim["max_texture_size"], lim["max_renderbuffer_size"], *lim["max_viewport_dims"])
    if width < 1 or height < 1 or width > cap or height > cap:
        raise GPUError(f"{what} size {width}x{height} is outside this GPU's limits (1..{cap} per side)")


#: texels per light in the lighting pass's light table (``shaders/common/lights.glsl``)
LIGHT_TABLE_TEXELS = 4


def max_lights(ctx: moderngl.Context) -> int:
    """Lights the lighting pass can hold: one row of ``LIGHT_TABLE_TEXELS`` texels per light in a
    texture at most ``GL_MAX_TEXTURE_SIZE`` wide (4096 on a 16384 GPU)."""
    return gpu_limits(ctx)["max_texture_size"] // LIGHT_TABLE_TEXELS


def check_light_count(ctx: moderngl.Context, count: int) -> None:
    """GPUError when a scene has more lights than the lighting pass can hold."""
    limit = max_lights(ctx)
    if count > limit:
        raise GPUError(f"the scene has {count} lights; this GPU can light at most {limit} "
                       f"(hide some lights from rendering)")
