"""The engine's rendered viewport: what ``view_update`` and ``view_draw`` do on an engine instance.

The state lives on the engine instance (:func:`init`): ``_vp_pipeline`` (its own pipeline),
``_sync`` (:class:`~.viewport.ViewportSync`), ``_display`` (:class:`~.viewport.ViewportDisplay`),
``_vp_state`` (view and settings of the last render), ``_refine`` (frames still to render at
full quality) and ``_vp_error`` (the error shown last). The pipeline is reached through the
engine's ``_viewport_pipeline()``.
"""
from __future__ import annotations

import traceback

from ..core.errors import HybridShadowError
from .final_render import settings_label
from .gl import create_pipeline, gl_scope, release_pipeline
from .viewport import ViewportDisplay, ViewportSync, debug_image, viewport_camera


def init(engine) -> None:
    """Give a new engine instance the viewport state (nothing created yet)."""
    engine._vp_pipeline = None
    engine._sync = None
    engine._display = None
    engine._vp_state = None  # (view key, settings key, ...) of the last viewport render
    engine._refine = 0  # viewport frames still to render at full quality
    engine._vp_error = None


def free(engine) -> None:
    """Release the engine instance's viewport pipeline."""
    release_pipeline(getattr(engine, "_vp_pipeline", None))


def viewport_pipeline(engine):
    """The engine instance's own pipeline, with its sync and display, created on first use."""
    if engine._vp_pipeline is None:
        engine._vp_pipeline = create_pipeline()
        engine._sync = ViewportSync(engine._vp_pipeline)
        engine._display = ViewportDisplay()
    return engine._vp_pipeline


def view_update(engine, context, depsgraph) -> None:
    """Apply ``depsgraph.updates`` to the viewport scene; any change renders again."""
    try:
        pipe = engine._viewport_pipeline()
        with gl_scope(pipe):
            plan = engine._sync.update(depsgraph)
        if not plan.nothing:
            engine._vp_state = None  # render again (fast pass first)
        engine._vp_error = None
    except Exception as exc:
        report_error(engine, exc)


def preview_pixel_size(context) -> int:
    """Render ▸ Performance ▸ Viewport ▸ Pixel Size: ``AUTO`` follows the interface's pixel size
    (2 on a high-DPI display), else 1, 2, 4 or 8 screen pixels per rendered pixel."""
    size = context.scene.render.preview_pixel_size
    if size == "AUTO":
        return max(1, int(round(context.preferences.system.pixel_size)))
    return max(1, int(size))


def local_view_objects(context):
    """Names of the objects of the 3D view's local view, or None outside one."""
    space = getattr(context, "space_data", None)
    if space is None or getattr(space, "local_view", None) is None:
        return None
    return [ob.name for ob in context.view_layer.objects if ob.local_view_get(space)]


def view_draw(engine, context, depsgraph) -> None:
    """Render when needed (:func:`view_render`, at the preview pixel size), then draw the last
    image over the region unless it failed."""
    region, rv3d = context.region, context.region_data
    scene = depsgraph.scene
    try:
        if engine._sync is not None and engine._sync.scene is not None:
            pipe = engine._viewport_pipeline()
            with gl_scope(pipe):
                if engine._sync.set_local_view(depsgraph, local_view_objects(context)):
                    engine._vp_state = None  # render again
        px = preview_pixel_size(context)
        view_render(engine, scene, rv3d, max(1, -(-region.width // px)), max(1, -(-region.height // px)))
    except Exception as exc:
        report_error(engine, exc)
    if engine._display is not None and engine._vp_error is None:
        engine._display.draw(scene, region.width, region.height, engine=engine)


def report_error(engine, exc) -> None:
    """Report a viewport error once (the same message again stays quiet) and show it in the
    stats line; a traceback on the console for anything but a user-facing error."""
    known = isinstance(exc, (HybridShadowError, ValueError))
    msg = str(exc) if known else f"{type(exc).__name__}: {exc}"
    if not known:
        traceback.print_exc()
    if msg != engine._vp_error:
        engine.report({"ERROR"}, f"Hybrid Shadows: {msg}")
    engine._vp_error = msg
    engine.update_stats("", f"Hybrid Shadows error: {msg}")


def view_render(engine, scene, rv3d, width, height) -> None:
    """Render into the display texture when something changed or refinement is pending:
    the navigation quality right after a change, then full viewport quality (four frames
    with interlacing: one per ray phase), tagging redraws until it is done."""
    pipe = engine._viewport_pipeline()
    sync = engine._sync
    if sync.scene is None:
        return
    props = scene.hybrid_shadows
    full = props.to_settings(viewport=True)
    fast = props.to_settings(viewport=True, navigating=True)
    view_key = (tuple(map(tuple, rv3d.view_matrix)), tuple(map(tuple, rv3d.window_matrix)), width, height)
    state = (view_key, full, props.debug_view, getattr(props.debug_light, "name", None),
             bool(scene.render.film_transparent))
    changed = state != engine._vp_state
    if not changed and engine._refine <= 0:
        return
    if changed:
        engine._vp_state = state
        settings = fast
        passes = 4 if full.interlace else 1
        engine._refine = passes if (fast != full or full.interlace) else 0
        pipe.reset_history()
    else:
        settings = full
        engine._refine -= 1
    core = sync.scene
    core.camera = viewport_camera(rv3d.view_matrix, rv3d.window_matrix, width, height)
    core.resolution = (width, height)
    with gl_scope(pipe):
        if settings.mode == "raytrace":
            sync.ensure_baked()
        frame = pipe.render(core, settings, width, height, film_transparent=bool(scene.render.film_transparent))
        if props.debug_view != "NONE":
            image = debug_image(props.debug_view, frame, core, pipe, getattr(props.debug_light, "name", None))
        else:
            image = frame.image
    engine._display.upload(image)
    engine._vp_error = None
    acc = frame.stats.get("accumulated_samples")
    if acc is not None and settings.accumulate and acc < settings.samples:
        engine._refine = max(engine._refine, 1)  # soft lights still converging: one more redraw
    left = f", refining ({engine._refine} left)" if engine._refine > 0 else ""
    if acc is not None:
        left += f", {acc}/{settings.samples} soft samples"
    engine.update_stats("", f"Hybrid Shadows | {settings_label(frame)} | "
                            f"{frame.timings.get('total_ms', 0):.0f} ms{left}")
    if engine._refine > 0:
        engine.tag_redraw()
