"""The ``HYBRID_SHADOWS`` render engine: final renders (F12, ``bpy.ops.render.render``,
``blender -b file.blend -f N``) and the rendered viewport.

Final renders fill Combined plus the registered passes (:func:`register_passes`): Depth (view
depth, 1e10 on the background, like Cycles), Normal (world-space shading normal), Albedo (base
colour) and one ``Shadow <light>`` pass per shadow-casting light (1 lit, 0 shadowed; 1 where there
is no geometry, and 1 everywhere for a light beyond ``max_shadowed_lights``: it is drawn
unshadowed). Blender's pass rects are bottom-up; the pipeline's arrays are top-down.

The pipeline owns a standalone OpenGL context. It is never left current on Blender's threads:
every use goes through :func:`gl_scope`, which makes it current and restores whatever context
the thread had before (Blender's own in the viewport).
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import sys
import threading
import traceback

import bpy
import numpy as np

from ..core.errors import HybridShadowError
from . import export
from .viewport import ViewportDisplay, ViewportSync, debug_image, viewport_camera

ENGINE_ID = "HYBRID_SHADOWS"
SHADOW_PASS_PREFIX = "Shadow "
BACKGROUND_DEPTH = 1.0e10


class Cancelled(Exception):
    """The user cancelled the render (``test_break``)."""


# ------------------------------------------------------------------------------------------------
# OpenGL context hygiene
# ------------------------------------------------------------------------------------------------
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
    drawing afterwards: measured with bpy 4.5 on EGL.)"""
    with _EGLCurrent(), pipeline.ctx:
        yield pipeline


def release_pipeline(pipeline) -> None:
    if pipeline is None:
        return
    try:
        with gl_scope(pipeline):
            pipeline.release()
        with _EGLCurrent():
            pipeline.ctx.release()
    except Exception:  # at exit the context may already be gone
        pass


# one pipeline for final renders, shared by the engine instances of this process (compiled
# programs survive from one F12 to the next); released when the add-on is disabled
_final = {"pipeline": None}
_final_lock = threading.Lock()


def final_pipeline():
    if _final["pipeline"] is None:
        _final["pipeline"] = create_pipeline()
    return _final["pipeline"]


def release_shared() -> None:
    with _final_lock:
        release_pipeline(_final["pipeline"])
        _final["pipeline"] = None


# ------------------------------------------------------------------------------------------------
# Passes
# ------------------------------------------------------------------------------------------------
def shadow_pass_name(light_name: str) -> str:
    """``Shadow <light>``, cut to Blender's 63-character pass names."""
    return (SHADOW_PASS_PREFIX + light_name)[:63]


def shadow_pass_lights(scene) -> list:
    """Names of the lights that get a shadow pass: the scene's render-visible lights with
    ``use_shadow``, in the scene's object order (instanced lights get none)."""
    return [ob.name for ob in scene.objects
            if ob.type == "LIGHT" and ob.data.use_shadow and not ob.hide_render]


def pass_layout(scene, view_layer) -> list:
    """``(name, channels, chan_id, type)`` of every pass this engine writes for a view layer."""
    out = [("Combined", 4, "RGBA", "COLOR")]
    if view_layer.use_pass_z:
        out.append(("Depth", 1, "Z", "VALUE"))
    if view_layer.use_pass_normal:
        out.append(("Normal", 3, "XYZ", "VECTOR"))
    hs = getattr(view_layer, "hybrid_shadows", None)
    if hs is not None and hs.use_pass_albedo:
        out.append(("Albedo", 3, "RGB", "COLOR"))
    if hs is not None and hs.use_pass_shadow:
        out += [(shadow_pass_name(n), 1, "X", "VALUE") for n in shadow_pass_lights(scene)]
    return out


def _bottom_up(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a[::-1], np.float32)


class _Progress:
    """``Pipeline.render``'s ``on_step``: checks ``test_break`` before each pass and light (raising
    :class:`Cancelled`), and maps the pipeline's steps onto ``start..end`` of the progress bar."""

    def __init__(self, engine, start: float, end: float):
        self.engine = engine
        self.start, self.end = start, end

    def __call__(self, label: str, done: int, total: int) -> None:
        if self.engine.test_break():
            raise Cancelled()
        self.engine.update_stats("", f"Hybrid Shadows | {label}")
        self.engine.update_progress(self.start + (self.end - self.start) * min(1.0, done / max(1, total)))


# ------------------------------------------------------------------------------------------------
# The engine
# ------------------------------------------------------------------------------------------------
class HybridShadowsEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "Hybrid Shadows"
    bl_use_preview = False  # material/light previews: Blender's own
    bl_use_eevee_viewport = True  # Material Preview shading uses EEVEE, as with Cycles
    bl_use_shading_nodes_custom = False  # standard shader nodes in the node editor

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._vp_pipeline = None
        self._sync = None
        self._display = None
        self._vp_state = None  # (view key, settings key, size) of the last viewport render
        self._refine = 0  # viewport frames still to render at full quality
        self._vp_error = None

    def __del__(self):
        release_pipeline(getattr(self, "_vp_pipeline", None))

    # -- errors -----------------------------------------------------------------------------------
    def _fail(self, message: str) -> None:
        self.report({"ERROR"}, message)
        if hasattr(self, "error_set"):
            self.error_set(message)

    # -- final render -----------------------------------------------------------------------------
    def update_render_passes(self, scene=None, renderlayer=None):
        for name, channels, chan_id, kind in pass_layout(scene, renderlayer):
            self.register_pass(scene, renderlayer, name, channels, chan_id, kind)

    def render(self, depsgraph):
        scene = depsgraph.scene
        view_layer = depsgraph.view_layer
        width, height = export.render_resolution(scene)
        try:
            settings = scene.hybrid_shadows.to_settings()
            self.update_stats("", "Hybrid Shadows | Exporting scene")
            self.update_progress(0.0)
            core = export.export_depsgraph(depsgraph, resolution=(width, height)).validate()
            if self.test_break():
                return
            with _final_lock:
                pipe = final_pipeline()
                with gl_scope(pipe):
                    if settings.mode == "raytrace":
                        self.update_stats("", f"Hybrid Shadows | Baking {len(core.instances)} objects")
                        self.update_progress(0.1)
                        pipe.set_scene(core)
                    if self.test_break():
                        return
                    frame = pipe.render(core, settings, width, height,
                                        film_transparent=bool(scene.render.film_transparent),
                                        on_step=_Progress(self, 0.2, 0.8))
                    self._write_result(core, frame, scene, view_layer, width, height)
        except Cancelled:
            return
        except HybridShadowError as exc:
            self._fail(f"Hybrid Shadows: {exc}")
        except Exception as exc:  # a bug: readable message, traceback on the console
            traceback.print_exc()
            self._fail(f"Hybrid Shadows internal error: {type(exc).__name__}: {exc}")

    def _write_result(self, core, frame, scene, view_layer, width, height) -> None:
        layout = {name: channels for name, channels, _, _ in pass_layout(scene, view_layer)}
        result = self.begin_result(0, 0, width, height, layer=view_layer.name)
        cancelled = False
        try:
            passes = result.layers[0].passes
            self.update_stats("", "Hybrid Shadows | Writing passes")
            passes["Combined"].rect.foreach_set(_bottom_up(frame.image).ravel())
            gb = frame.gbuffer
            valid = gb.coverage()
            if "Depth" in layout and passes.get("Depth") is not None:
                d = gb.read("depth")
                d = d[..., 0] if d.ndim == 3 else d
                passes["Depth"].rect.foreach_set(_bottom_up(np.where(valid, d, BACKGROUND_DEPTH)).ravel())
            if "Normal" in layout and passes.get("Normal") is not None:
                nrm = gb.read("shading_normal")[..., :3] * valid[..., None]
                passes["Normal"].rect.foreach_set(_bottom_up(nrm).ravel())
            if "Albedo" in layout and passes.get("Albedo") is not None:
                alb = gb.read("albedo")[..., :3] * valid[..., None]
                passes["Albedo"].rect.foreach_set(_bottom_up(alb).ravel())
            by_name = {core.lights[i].name: i for i in frame.lights}
            shadow_names = [n for n in layout if n.startswith(SHADOW_PASS_PREFIX)]
            lights = {shadow_pass_name(l.name): l.name for l in core.lights}
            ones = None
            for k, pname in enumerate(shadow_names):
                if self.test_break():
                    cancelled = True
                    return
                rp = passes.get(pname)
                if rp is None:
                    continue
                self.update_progress(0.8 + 0.2 * k / max(1, len(shadow_names)))
                li = by_name.get(lights.get(pname))
                if li is None:  # not shadowed in this frame (max_shadowed_lights): unshadowed
                    ones = np.ones(width * height, np.float32) if ones is None else ones
                    rp.rect.foreach_set(ones)
                    continue
                m = np.nan_to_num(frame.mask_array(li), nan=1.0)
                rp.rect.foreach_set(_bottom_up(m).ravel())
            t = frame.timings
            self.update_stats("", f"Hybrid Shadows | {settings_label(frame)} | {t.get('total_ms', 0):.0f} ms")
            self.update_progress(1.0)
        finally:
            self.end_result(result, cancel=cancelled)

    # -- viewport ---------------------------------------------------------------------------------
    def _viewport_pipeline(self):
        if self._vp_pipeline is None:
            self._vp_pipeline = create_pipeline()
            self._sync = ViewportSync(self._vp_pipeline)
            self._display = ViewportDisplay()
        return self._vp_pipeline

    def view_update(self, context, depsgraph):
        try:
            pipe = self._viewport_pipeline()
            with gl_scope(pipe):
                plan = self._sync.update(depsgraph)
            if not plan.nothing:
                self._vp_state = None  # render again (fast pass first)
            self._vp_error = None
        except Exception as exc:
            self._viewport_failed(exc)

    def _viewport_failed(self, exc) -> None:
        msg = str(exc) if isinstance(exc, (HybridShadowError, ValueError)) else f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, (HybridShadowError, ValueError)):
            traceback.print_exc()
        if msg != self._vp_error:
            self.report({"ERROR"}, f"Hybrid Shadows: {msg}")
        self._vp_error = msg
        self.update_stats("", f"Hybrid Shadows error: {msg}")

    def view_draw(self, context, depsgraph):
        region, rv3d = context.region, context.region_data
        scene = depsgraph.scene
        try:
            self._view_render(scene, rv3d, region.width, region.height)
        except Exception as exc:
            self._viewport_failed(exc)
        if self._display is not None and self._vp_error is None:
            self._display.draw(scene, region.width, region.height, engine=self)

    def _view_render(self, scene, rv3d, width, height) -> None:
        """Render into the display texture when something changed or refinement is pending:
        the navigation quality right after a change, then full viewport quality (four frames
        with interlacing: one per ray phase), tagging redraws until it is done."""
        pipe = self._viewport_pipeline()
        if self._sync.scene is None:
            return
        props = scene.hybrid_shadows
        full = props.to_settings(viewport=True)
        fast = props.to_settings(viewport=True, navigating=True)
        view_key = (tuple(map(tuple, rv3d.view_matrix)), tuple(map(tuple, rv3d.window_matrix)), width, height)
        state = (view_key, full, props.debug_view, getattr(props.debug_light, "name", None),
                 bool(scene.render.film_transparent))
        changed = state != self._vp_state
        if not changed and self._refine <= 0:
            return
        if changed:
            self._vp_state = state
            settings = fast
            passes = 4 if full.interlace else 1
            self._refine = passes if (fast != full or full.interlace) else 0
            pipe.reset_history()
        else:
            settings = full
            self._refine -= 1
        core = self._sync.scene
        core.camera = viewport_camera(rv3d.view_matrix, rv3d.window_matrix, width, height)
        core.resolution = (width, height)
        with gl_scope(pipe):
            if settings.mode == "raytrace":
                self._sync.ensure_baked()
            frame = pipe.render(core, settings, width, height, film_transparent=bool(scene.render.film_transparent))
            if props.debug_view != "NONE":
                image = debug_image(props.debug_view, frame, core, pipe, getattr(props.debug_light, "name", None))
            else:
                image = frame.image
        self._display.upload(image)
        self._vp_error = None
        left = f", refining ({self._refine} left)" if self._refine > 0 else ""
        self.update_stats("", f"Hybrid Shadows | {settings_label(frame)} | {frame.timings.get('total_ms', 0):.0f} ms{left}")
        if self._refine > 0:
            self.tag_redraw()


def settings_label(frame) -> str:
    s = frame.stats
    mode = {"raytrace": "Ray traced", "shadowmap": "Shadow map", "none": "No shadows"}.get(s.get("mode"), "?")
    q = f" {s.get('quality')}" if s.get("mode") == "raytrace" else ""
    return f"{mode}{q}, {s.get('shadowed_lights', 0)} shadowed lights"


CLASSES = (HybridShadowsEngine,)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister() -> None:
    release_shared()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
