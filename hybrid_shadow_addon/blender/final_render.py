"""Final renders of the engine (F12, ``bpy.ops.render.render``, ``blender -b file.blend -f N``)
and the render passes they fill.

Passes (:func:`pass_layout`): Combined, Depth (view depth, 1e10 on the background, like Cycles),
Normal (world-space shading normal), Albedo (base colour) and one ``Shadow <light>`` pass per
shadow-casting light (1 lit, 0 shadowed; 1 where there is no geometry, and 1 everywhere for a
light beyond ``max_shadowed_lights``: it is drawn unshadowed). Blender's pass rects are bottom-up;
the pipeline's arrays are top-down.
"""
from __future__ import annotations

import traceback

import numpy as np

from ..core.errors import Cancelled, HybridShadowError
from . import export
from .gl import final_scope

SHADOW_PASS_PREFIX = "Shadow "
BACKGROUND_DEPTH = 1.0e10


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


def register_passes(engine, scene, view_layer) -> None:
    """``RenderEngine.update_render_passes``: register every pass of :func:`pass_layout`."""
    for name, channels, chan_id, kind in pass_layout(scene, view_layer):
        engine.register_pass(scene, view_layer, name, channels, chan_id, kind)


def settings_label(frame) -> str:
    """The shadow mode, quality and shadowed-light count of a rendered frame, for the stats line."""
    s = frame.stats
    mode = {"raytrace": "Ray traced", "shadowmap": "Shadow map", "none": "No shadows"}.get(s.get("mode"), "?")
    q = f" {s.get('quality')}" if s.get("mode") == "raytrace" else ""
    return f"{mode}{q}, {s.get('shadowed_lights', 0)} shadowed lights"


def _bottom_up(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a[::-1], np.float32)


class _Progress:
    """``Pipeline.render``'s ``progress``: checks ``test_break`` before each pass and light (raising
    :class:`Cancelled`), and maps the pipeline's steps onto ``start..end`` of the progress bar."""

    def __init__(self, engine, start: float, end: float):
        self.engine = engine
        self.start, self.end = start, end

    def __call__(self, done: int, total: int, label: str = "") -> None:
        if self.engine.test_break():
            raise Cancelled()
        self.engine.update_stats("", f"Hybrid Shadows | {label}")
        self.engine.update_progress(self.start + (self.end - self.start) * min(1.0, done / max(1, total)))


# ------------------------------------------------------------------------------------------------
# The render
# ------------------------------------------------------------------------------------------------
def _fail(engine, message: str) -> None:
    engine.report({"ERROR"}, message)
    if hasattr(engine, "error_set"):
        engine.error_set(message)


def render(engine, depsgraph) -> None:
    """``RenderEngine.render``: export, bake (ray tracing), render, write the passes. A cancel
    (``test_break``) ends it quietly; errors are reported on the render."""
    scene = depsgraph.scene
    view_layer = depsgraph.view_layer
    width, height = export.render_resolution(scene)
    try:
        settings = scene.hybrid_shadows.to_settings()
        engine.update_stats("", "Hybrid Shadows | Exporting scene")
        engine.update_progress(0.0)
        core = export.export_depsgraph(depsgraph, resolution=(width, height)).validate()
        if engine.test_break():
            return
        with final_scope() as pipe:
            if settings.mode == "raytrace":
                engine.update_stats("", f"Hybrid Shadows | Baking {len(core.instances)} objects")
                engine.update_progress(0.1)
                pipe.set_scene(core)
            if engine.test_break():
                return
            frame = pipe.render(core, settings, width, height,
                                film_transparent=bool(scene.render.film_transparent),
                                progress=_Progress(engine, 0.2, 0.8))
            write_result(engine, core, frame, scene, view_layer, width, height)
    except Cancelled:  # before HybridShadowError, its base class: a cancel is no error
        return
    except HybridShadowError as exc:
        _fail(engine, f"Hybrid Shadows: {exc}")
    except Exception as exc:  # a bug: readable message, traceback on the console
        traceback.print_exc()
        _fail(engine, f"Hybrid Shadows internal error: {type(exc).__name__}: {exc}")


def write_result(engine, core, frame, scene, view_layer, width, height) -> None:
    """Write a rendered ``frame`` into the passes of a new render result of ``view_layer``."""
    layout = {name: channels for name, channels, _, _ in pass_layout(scene, view_layer)}
    result = engine.begin_result(0, 0, width, height, layer=view_layer.name)
    cancelled = False
    try:
        passes = result.layers[0].passes
        engine.update_stats("", "Hybrid Shadows | Writing passes")
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
            if engine.test_break():
                cancelled = True
                return
            rp = passes.get(pname)
            if rp is None:
                continue
            engine.update_progress(0.8 + 0.2 * k / max(1, len(shadow_names)))
            li = by_name.get(lights.get(pname))
            if li is None:  # not shadowed in this frame (max_shadowed_lights): unshadowed
                ones = np.ones(width * height, np.float32) if ones is None else ones
                rp.rect.foreach_set(ones)
                continue
            m = np.nan_to_num(frame.mask_array(li), nan=1.0)
            rp.rect.foreach_set(_bottom_up(m).ravel())
        t = frame.timings
        engine.update_stats("", f"Hybrid Shadows | {settings_label(frame)} | {t.get('total_ms', 0):.0f} ms")
        engine.update_progress(1.0)
    finally:
        engine.end_result(result, cancel=cancelled)
