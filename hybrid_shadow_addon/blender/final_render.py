"""Final renders of the engine (F12, ``bpy.ops.render.render``, ``blender -b file.blend -f N``)
and the render passes they fill.

Passes (:func:`pass_layout`): Combined, Depth (view depth, 1e10 on the background, like Cycles),
Normal (world-space shading normal), Albedo (base colour) and one ``Shadow <light>`` pass per
shadow-casting light (1 lit, 0 shadowed; 1 where there is no geometry, and 1 everywhere for a
light beyond ``max_shadowed_lights``: it is drawn unshadowed). Blender's pass rects are bottom-up;
the pipeline's arrays are top-down.

Persistent data (``scene.render.use_persistent_data``; Render ▸ Shadows ▸ Limits): the
exported scene and its bake stay with the shared pipeline between frames, and the next frame
only updates the bake (:func:`~..core.scene_sync.sync_scene`), so an animation render
(``blender -b file.blend -a``) bakes once. Off: every frame bakes afresh. A pipeline script
sees each frame's stats (the bake's kind, timings, GPU memory) through :data:`frame_handlers`.
"""
from __future__ import annotations

import traceback

import numpy as np

from ..core.errors import Cancelled, HybridShadowError
from . import export
from .export.camera import render_resolution
from .gl import final_renderer

#: functions called with each final frame's stats (a dict: ``bake``, the bake's kind ``full``,
#: ``incremental`` or ``none``; ``bake_ms``; ``gpu_memory_before_mb``, ``gpu_peak_mb``,
#: ``gpu_memory_after_mb``; the passes' timings), before its result is written: what a
#: pipeline script appends to log or check its frames
frame_handlers: list = []

SHADOW_PASS_PREFIX = "Shadow "
BACKGROUND_DEPTH = 1.0e10


# ------------------------------------------------------------------------------------------------
# Passes
# ------------------------------------------------------------------------------------------------
PASS_NAME_BYTES = 63  # Blender's pass names: 64 bytes with the terminating NUL


def _cut_utf8(text: str, limit: int) -> str:
    """``text`` cut to at most ``limit`` UTF-8 bytes, never inside a character."""
    return text.encode("utf-8")[:limit].decode("utf-8", "ignore")


def shadow_pass_name(light_name: str) -> str:
    """``Shadow <light>``, cut to Blender's 63-byte pass names (UTF-8, whole characters)."""
    return _cut_utf8(SHADOW_PASS_PREFIX + light_name, PASS_NAME_BYTES)


def shadow_pass_names(light_names) -> dict:
    """``{light name: pass name}``, unique: a name that its cut would make equal to an earlier
    one gets ``.001``, ``.002``, ... (within the byte limit)."""
    out, used = {}, set()
    for name in light_names:
        pname = shadow_pass_name(name)
        k = 0
        while pname in used:
            k += 1
            suffix = f".{k:03d}"
            pname = _cut_utf8(SHADOW_PASS_PREFIX + name, PASS_NAME_BYTES - len(suffix)) + suffix
        used.add(pname)
        out[name] = pname
    return out


def shadow_pass_lights(scene, view_layer=None) -> list:
    """Names of the lights that get a shadow pass: the render-visible lights with ``use_shadow``
    of ``view_layer`` (its own objects: excluded collections leave theirs out; default: the
    scene's), in object order (instanced lights get none)."""
    objects = view_layer.objects if view_layer is not None else scene.objects
    return [ob.name for ob in objects
            if ob.type == "LIGHT" and ob.data.use_shadow and not ob.hide_render
            and not any(c.hide_render for c in ob.users_collection)]


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
        out += [(p, 1, "X", "VALUE") for p in shadow_pass_names(shadow_pass_lights(scene, view_layer)).values()]
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


def border_region(scene, width: int, height: int) -> tuple:
    """``(x0, y0, w, h)`` of the pixels a render fills, bottom-up: the whole frame, or with
    ``use_border`` Blender's render border (its edges truncated to whole pixels, as Blender
    does; the render result then holds only that region, whether cropped or not)."""
    r = scene.render
    if not r.use_border:
        return 0, 0, width, height
    x0, x1 = int(r.border_min_x * width), int(r.border_max_x * width)
    y0, y1 = int(r.border_min_y * height), int(r.border_max_y * height)
    return x0, y0, max(x1 - x0, 0), max(y1 - y0, 0)


def _bottom_up(a: np.ndarray, region=None) -> np.ndarray:
    """Rows flipped to Blender's bottom-up order, cut to ``region`` (:func:`border_region`)."""
    a = a[::-1]
    if region is not None:
        x0, y0, w, h = region
        a = a[y0:y0 + h, x0:x0 + w]
    return np.ascontiguousarray(a, np.float32)


def _stats(engine, text: str) -> None:
    """The render's stats line. Blender 5 no longer prints it in background renders
    (``blender -b``): there it goes to stdout as well, so batch logs keep the progress."""
    engine.update_stats("", text)
    if _print_stats():
        print(text, flush=True)


def _print_stats() -> bool:
    import bpy

    return bool(bpy.app.background) and bpy.app.version >= (5, 0, 0)


class _Progress:
    """The final-render process's progress: its steps mapped onto ``start..end`` of the progress
    bar, their labels in the stats line."""

    def __init__(self, engine, start: float, end: float):
        self.engine = engine
        self.start, self.end = start, end

    def __call__(self, done: int, total: int, label: str = "") -> None:
        _stats(self.engine, f"Hybrid Shadows | {label}")
        self.engine.update_progress(self.start + (self.end - self.start) * min(1.0, done / max(1, total)))


# ------------------------------------------------------------------------------------------------
# The render
# ------------------------------------------------------------------------------------------------
def _fail(engine, message: str) -> None:
    engine.report({"ERROR"}, message)
    if hasattr(engine, "error_set"):
        engine.error_set(message)


def render(engine, depsgraph) -> None:
    """``RenderEngine.render``: export, then bake, render and read back in the final-render
    process (:func:`~.gl.final_renderer`: this thread waits without holding Python's lock), then
    write the passes. Esc (``test_break``, polled every 20 ms) stops it within 0.2 s, writing
    nothing; errors are reported on the render."""
    scene = depsgraph.scene
    view_layer = depsgraph.view_layer
    width, height = render_resolution(scene)
    try:
        settings = scene.hybrid_shadows.to_settings()
        _stats(engine, "Hybrid Shadows | Exporting scene")
        engine.update_progress(0.0)
        core = export.export_depsgraph(depsgraph, resolution=(width, height),
                                       should_stop=engine.test_break).validate()
        for line in core.report:  # what is approximated: the Info report
            engine.report({"WARNING"}, f"Hybrid Shadows: {line}")
        if engine.test_break():
            return
        engine.update_progress(0.1)
        frame = final_renderer().render(
            core, settings, width, height, should_stop=engine.test_break, on_progress=_Progress(engine, 0.1, 0.8),
            film_transparent=bool(scene.render.film_transparent), persistent_key=persistent_key(scene, view_layer),
            reuse=bool(scene.hybrid_shadows.use_reuse_animation),
            want=wanted_buffers(scene, view_layer), masks=bool(shadow_pass_lights(scene, view_layer)),
            max_draw_ms=MAX_DRAW_MS)
        for handler in list(frame_handlers):
            handler(dict(frame.stats))
        write_result(engine, core, frame, scene, view_layer, width, height)
    except Cancelled:  # before HybridShadowError, its base class: a cancel is no error
        return
    except HybridShadowError as exc:
        _fail(engine, f"Hybrid Shadows: {exc}")
    except Exception as exc:  # a bug: readable message, traceback on the console
        traceback.print_exc()
        _fail(engine, f"Hybrid Shadows internal error: {type(exc).__name__}: {exc}")


#: the longest single draw of a final render (ms on this machine's software rasteriser): tiles
#: keep each under a GPU driver's watchdog and let Esc stop between them
MAX_DRAW_MS = 100.0


def persistent_key(scene, view_layer):
    """With persistent data, what identifies the scene the final-render process keeps baked
    between frames (the file, scene and view layer); None without it (bake afresh, give it back
    after)."""
    if not scene.render.use_persistent_data:
        return None
    import bpy

    return (bpy.data.filepath, scene.name_full, view_layer.name)


def wanted_buffers(scene, view_layer) -> tuple:
    """The G-buffer targets the view layer's passes need."""
    names = {"Depth": "depth", "Normal": "shading_normal", "Albedo": "albedo"}
    return tuple(names[n] for n, *_ in pass_layout(scene, view_layer) if n in names)


def write_result(engine, core, frame, scene, view_layer, width, height) -> None:
    """Write a rendered ``frame`` into the passes of a new render result of ``view_layer`` (only
    the render border's pixels when a border is set)."""
    layout = {name: channels for name, channels, _, _ in pass_layout(scene, view_layer)}
    region = border_region(scene, width, height)
    if region[2] == 0 or region[3] == 0:
        return  # an empty border: nothing to write
    result = engine.begin_result(0, 0, region[2], region[3], layer=view_layer.name)
    cancelled = False
    try:
        passes = result.layers[0].passes
        _stats(engine, "Hybrid Shadows | Writing passes")
        passes["Combined"].rect.foreach_set(_bottom_up(frame.image, region).ravel())
        gb = frame.gbuffer
        valid = gb.coverage()
        if "Depth" in layout and passes.get("Depth") is not None:
            d = gb.read("depth")
            d = d[..., 0] if d.ndim == 3 else d
            passes["Depth"].rect.foreach_set(_bottom_up(np.where(valid, d, BACKGROUND_DEPTH), region).ravel())
        if "Normal" in layout and passes.get("Normal") is not None:
            nrm = gb.read("shading_normal")[..., :3] * valid[..., None]
            passes["Normal"].rect.foreach_set(_bottom_up(nrm, region).ravel())
        if "Albedo" in layout and passes.get("Albedo") is not None:
            alb = gb.read("albedo")[..., :3] * valid[..., None]
            passes["Albedo"].rect.foreach_set(_bottom_up(alb, region).ravel())
        by_name = {core.lights[i].name: i for i in frame.lights}
        shadow_names = [n for n in layout if n.startswith(SHADOW_PASS_PREFIX)]
        lights = {p: n for n, p in shadow_pass_names(shadow_pass_lights(scene, view_layer)).items()}
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
                ones = np.ones(region[2] * region[3], np.float32) if ones is None else ones
                rp.rect.foreach_set(ones)
                continue
            m = np.nan_to_num(frame.mask_array(li), nan=1.0)
            rp.rect.foreach_set(_bottom_up(m, region).ravel())
        t = frame.timings
        bake = frame.stats.get("bake")
        peak = frame.stats.get("gpu_peak_mb")
        _stats(engine, f"Hybrid Shadows | {settings_label(frame)} | {t.get('total_ms', 0):.0f} ms"
                                + (f" | bake: {bake}" if bake else "") + (f" | GPU peak {peak:.0f} MB" if peak else ""))
        engine.update_progress(1.0)
    finally:
        engine.end_result(result, cancel=cancelled)
