"""The engine's rendered viewport: what ``view_update`` and ``view_draw`` do on an engine instance.

Rendering happens off the draw callback and out of Blender's process, in a renderer process
(:class:`~..core.runtime.remote.RemoteWorker`: its own OpenGL context and bake; waiting for it never
holds Python's lock, and its frames arrive as half floats, flipped and wrapped in a
``gpu.types.Buffer`` on the receiving thread, so the draw callback only uploads them). The
viewports of one scene, view layer and local view share one (:data:`_registry`: a
:class:`~..core.runtime.viewport_share.SharedViewport` with the worker and one
:class:`~.viewport.ViewportSync`, released with its last engine); each engine is a view of its own
there (camera, size, render targets, interlacing and soft-shadow history). The main thread does
everything that touches bpy (export, ``depsgraph.updates``: applied once for all the engines that
receive them) and hands the worker copies of the scene. ``view_draw`` only queues a render when the
view, the settings or the scene changed, and shows the newest finished frame; a timer
(:func:`_poll`) tags a redraw when one arrives (headless, without timers, ``view_draw`` tags
redraws itself while work is pending). ``HYBRID_SHADOWS_VIEWPORT_SYNC=1`` (or
``worker.SYNCHRONOUS``) renders inline instead, one frame per redraw, for debugging.

State on the engine instance (:func:`init`): ``_vp_user`` (its token in the registry and its
view in the worker), ``_display`` (:class:`~.viewport.ViewportDisplay`), ``_vp_state`` (view and
settings of the last request), ``_vp_generation`` (the shared scene's changes it rendered),
``_vp_key`` (the key of its shared state), ``_vp_sent`` (the last request's number),
``_vp_refining`` (frames still to come) and ``_vp_error`` (the error shown last).
"""
from __future__ import annotations

import dataclasses
import functools
import itertools
import os
import traceback
import weakref

import bpy

from ..core.errors import HybridShadowError
from ..core.gpu.debug_views import DebugView
from ..core.runtime import worker as worker_mod
from ..core.runtime.remote import RemoteWorker
from ..core.runtime.viewport_share import SharedRegistry, SharedViewport
from ..core.runtime.worker import RenderRequest, RenderWorker
from . import gl
from .export.curves import TUBES
from .final_render import settings_label
from .viewport import ViewportDisplay, ViewportSync, crop_window, prepare_display, render_region, viewport_camera

#: the shared state of the viewports of each (scene, view layer, local view)
_registry = SharedRegistry()
_users = itertools.count(1)
_engines: dict = {}  # user -> weakref to its engine instance (for the redraw timer)
_evaluations = [0]  # depsgraph evaluations so far (the updates of one are applied once)
POLL_S = 1.0 / 60.0


def init(engine) -> None:
    """Give a new engine instance the viewport state (nothing created yet)."""
    engine._vp_user = next(_users)
    engine._vp_key = None  # (scene, view layer, local view) of its shared state
    engine._display = None
    engine._vp_state = None  # (view key, settings, ...) of the last request
    engine._vp_generation = -1
    engine._vp_sent = 0
    engine._vp_refining = False
    engine._vp_error = None
    try:
        _engines[engine._vp_user] = weakref.ref(engine)
    except TypeError:  # not weak-referenceable: view_draw tags its own redraws
        pass


def free(engine) -> None:
    """Leave the shared state (the last engine of a scene stops its worker and context)."""
    user = getattr(engine, "_vp_user", None)
    if user is None:
        return
    _engines.pop(user, None)
    _registry.release(user)


def release_all() -> None:
    """Stop every viewport worker (the add-on is unregistered)."""
    _registry.release_all()
    _engines.clear()


def shared(engine) -> SharedViewport | None:
    """The engine's shared state (worker and sync), None before its first update or draw."""
    return _registry.get(engine._vp_user)


def make_worker():
    """The viewport's worker: a renderer process (:class:`~..core.runtime.remote.RemoteWorker`;
    frames arrive ready for the display), or with ``HYBRID_SHADOWS_RENDERER=thread`` (or the
    inline debugging mode) a thread of this process, whose GL calls hold Python's lock."""
    if worker_mod.SYNCHRONOUS or os.environ.get("HYBRID_SHADOWS_RENDERER", "").strip() == "thread":
        return RenderWorker(create=gl.create_pipeline, scope=gl.gl_scope, release=gl.release_pipeline)
    return RemoteWorker(prepare=prepare_display)


def _make_shared(local) -> SharedViewport:
    worker = make_worker()
    sync = ViewportSync(worker)  # the worker stands in for the pipeline: same calls, queued
    sync.only = None if local is None else frozenset(local)
    return SharedViewport(worker, sync)


def _acquire(engine, depsgraph, local, export: bool) -> SharedViewport:
    """The shared state of the engine's scene, view layer and local view (``local``: its object
    names, None outside one); ``export``: make the first export now if nobody did."""
    key = (depsgraph.scene.as_pointer(), depsgraph.view_layer.name, None if local is None else frozenset(local))
    before = _registry.get(engine._vp_user)
    state = _registry.acquire(engine._vp_user, key, functools.partial(_make_shared, local))
    if state is not before:  # first use, another local view, a new file: render again
        engine._vp_key, engine._vp_state = key, None
    if export and state.sync.scene is None:
        state.sync.full_export(depsgraph)
        state.changed()
    _start_polling()
    return state


def _local_of(engine, context):
    """The local-view objects of the engine's 3D view; without a 3D view in ``context``, those
    of the engine's current shared state."""
    if getattr(context, "space_data", None) is not None:
        return local_view_objects(context)
    key = engine._vp_key
    return None if key is None or key[2] is None else sorted(key[2])


def update_key(depsgraph) -> tuple:
    """What identifies one depsgraph update for every engine receiving it: the evaluation
    (counted by :func:`_count_evaluation`) and what changed."""
    changes = tuple((u.id.original.as_pointer(), bool(u.is_updated_transform), bool(u.is_updated_geometry),
                     bool(u.is_updated_shading)) for u in depsgraph.updates)
    return _evaluations[0], changes


def view_update(engine, context, depsgraph) -> None:
    """Apply ``depsgraph.updates`` to the shared viewport scene (once for all the engines that
    receive them); any change renders every view again."""
    try:
        state = _acquire(engine, depsgraph, _local_of(engine, context), export=False)
        state.update(engine._vp_user, update_key(depsgraph), depsgraph)
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
    """Queue a render when needed (:func:`view_render`, at the preview pixel size), then draw
    the newest image over the region unless it failed."""
    region, rv3d = context.region, context.region_data
    scene = depsgraph.scene
    rect = render_region(context, region.width, region.height) or (0, 0, region.width, region.height)
    try:
        _acquire(engine, depsgraph, local_view_objects(context), export=True)
        px = preview_pixel_size(context)
        window = crop_window(rv3d.window_matrix, rect, region.width, region.height)
        view_render(engine, scene, rv3d, max(1, -(-rect[2] // px)), max(1, -(-rect[3] // px)), window=window)
    except Exception as exc:
        report_error(engine, exc)
    if engine._display is not None and engine._vp_error is None:
        engine._display.draw(scene, rect[2], rect[3], engine=engine, origin=rect[:2])


def report_error(engine, exc) -> None:
    """Report a viewport error once (the same message again stays quiet) and show it in the
    stats line; a traceback on the console for anything but a user-facing error (also for one
    raised where the frame was rendered: the renderer process or the worker's thread)."""
    known = isinstance(exc, (HybridShadowError, ValueError))
    msg = str(exc) if known else f"{type(exc).__name__}: {exc}"
    if not known:
        traceback.print_exception(type(exc), exc, exc.__traceback__)
    if msg != engine._vp_error:
        engine.report({"ERROR"}, f"Hybrid Shadows: {msg}")
    engine._vp_error = msg
    engine.update_stats("", f"Hybrid Shadows error: {msg}")


def view_render(engine, scene, rv3d, width, height, window=None) -> None:
    """Queue a render of the engine's view when the view, the settings or the scene changed
    (the worker renders the navigation quality first, then full viewport quality: four frames
    with interlacing, more while soft shadows accumulate; the automatic navigation quality is
    the viewport quality on a software rasteriser), then show the newest finished frame.
    Redraws are tagged until the last one is shown. ``window``: the projection (default the
    view's; a render region's crop of it)."""
    state = shared(engine)
    window = rv3d.window_matrix if window is None else window
    if state is None or state.sync.scene is None:
        return
    worker = state.worker
    props = scene.hybrid_shadows
    full = props.to_settings(viewport=True)
    fast = props.to_settings(viewport=True, navigating=True)
    view_key = (tuple(map(tuple, rv3d.view_matrix)), tuple(map(tuple, window)), width, height)
    light = getattr(props.debug_light, "name", None)
    film = bool(scene.render.film_transparent)
    key = (view_key, full, props.debug_view, light, film, props.use_reuse_visibility)
    if key != engine._vp_state or state.generation != engine._vp_generation:
        engine._vp_state, engine._vp_generation = key, state.generation
        if "raytrace" in (fast.mode, full.mode):
            state.sync.ensure_baked()
        core = dataclasses.replace(state.scene_snapshot(), resolution=(width, height),
                                   camera=viewport_camera(rv3d.view_matrix, window, width, height))
        post = None if props.debug_view == "NONE" else DebugView(props.debug_view, light)
        engine._vp_sent = worker.render(RenderRequest(view=engine._vp_user, scene=core, fast=fast, full=full,
                                                      width=width, height=height, film_transparent=film, post=post,
                                                      fast_auto=props.navigation_quality == "AUTO",
                                                      reuse=props.use_reuse_visibility))
        engine._vp_refining = True
    worker.pump()  # (inline mode only: one frame now)
    show_result(engine, worker)
    timer_tags = _polling() and not worker.synchronous and engine._vp_user in _engines
    if (engine._vp_refining or worker.busy(engine._vp_user)) and not timer_tags:
        engine.tag_redraw()  # (inline, frames are only rendered here: the timer cannot help)


def show_result(engine, worker) -> bool:
    """Take the newest frame of the engine's view from the worker into the display texture,
    with its stats line, and report its errors. Returns whether a frame came."""
    result, errors = worker.poll(engine._vp_user)
    for exc in errors:
        report_error(engine, exc)
    if errors and result is None:
        engine._vp_refining = worker.busy(engine._vp_user)
    if result is None:
        return False
    if engine._display is None:
        engine._display = ViewportDisplay()
    engine._display.upload(result.image)
    if not errors:
        engine._vp_error = None
    if result.seq == engine._vp_sent:
        engine._vp_refining = result.refine_left > 0
    acc = result.stats.get("accumulated_samples")
    left = f", refining ({result.refine_left} left)" if result.refine_left > 0 else ""
    if acc is not None:
        left += f", {acc}/{result.settings.samples} soft samples"
    seen = result.stats.get("see_through_samples")
    if seen is not None:
        left += f", {seen}/{result.stats['see_through_target']} see-through samples"
    mem = result.stats.get("gpu_memory_mb")
    mem = "" if mem is None else f" | GPU {mem:.0f} MB"
    engine.update_stats("", f"Hybrid Shadows | {settings_label(result)}{light_limit_note(engine, result)} | "
                            f"{result.timings.get('total_ms', 0):.0f} ms{left}{mem}{report_note(engine)}")
    return True


def unshadowed_note(casting: int, shadowed: int, limit) -> str:
    """The stats line's note when the viewport's light limit leaves ``casting - shadowed``
    shadow-casting lights unshadowed ("" when none is)."""
    left = casting - shadowed
    if left <= 0:
        return ""
    return (f", {left} light{'s' if left != 1 else ''} unshadowed (viewport limit {limit}: "
            f"Render > Shadows > Limits, 0 shadows all)")


def light_limit_note(engine, result) -> str:
    """:func:`unshadowed_note` of a viewport frame: the shadow-casting lights of the engine's
    scene against those the frame shadowed."""
    settings = result.settings
    if getattr(settings, "mode", "none") == "none" or getattr(settings, "max_shadowed_lights", None) is None:
        return ""
    scene = getattr(getattr(shared(engine), "sync", None), "scene", None)
    lights = getattr(scene, "lights", None) or ()
    casting = sum(1 for light in lights if light.use_shadow)
    return unshadowed_note(casting, int(result.stats.get("shadowed_lights", casting)),
                           settings.max_shadowed_lights)


def report_note(engine) -> str:
    """The stats line's note of the export report of the engine's scene ("" when empty); its
    lines go to the Info report once each time they change."""
    state = shared(engine)
    scene = getattr(getattr(state, "sync", None), "scene", None)
    lines = tuple(getattr(scene, "report", ()) or ())
    if lines != getattr(engine, "_vp_report", ()):
        engine._vp_report = lines
        for line in lines:
            engine.report({"WARNING"}, f"Hybrid Shadows: {line}")
    if not lines:
        return ""
    return f" | {len(lines)} approximation{'s' if len(lines) != 1 else ''} (see Info: {lines[0]}" + \
        (", ..." if len(lines) > 1 else "") + ")"


# -- redraws and depsgraph evaluations ------------------------------------------------------------
def _polling() -> bool:
    return bpy.app.timers.is_registered(_poll)


def _start_polling() -> None:
    """Poll the workers from a timer while viewports render (not in background mode: no
    event loop runs timers there)."""
    if not bpy.app.background and not _polling():
        bpy.app.timers.register(_poll, first_interval=POLL_S, persistent=True)


def _poll():
    """Timer: tag a redraw of each engine whose worker has a new frame or error for it; stops
    when no viewport renders."""
    if not len(_registry):
        return None
    for user, ref in list(_engines.items()):
        state = _registry.get(user)
        engine = ref()
        if state is None or engine is None:
            continue
        try:
            if state.worker.has_news(user):
                engine.tag_redraw()
        except ReferenceError:  # the engine's Blender data is gone
            _engines.pop(user, None)
    return POLL_S


@bpy.app.handlers.persistent
def _count_evaluation(*_args) -> None:
    _evaluations[0] += 1


@bpy.app.handlers.persistent
def _release_on_load(*_args) -> None:
    """Another file is loaded: its scenes may reuse the old ones' addresses (the registry's
    keys), so no shared state may outlive the file; engines left over find nothing to release.
    The export's cached tube models go with it."""
    release_all()
    TUBES.clear()


_HANDLERS = (("depsgraph_update_post", _count_evaluation), ("load_pre", _release_on_load))


def register() -> None:
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn not in handlers:
            handlers.append(fn)


def unregister() -> None:
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn in handlers:
            handlers.remove(fn)
    if _polling():
        bpy.app.timers.unregister(_poll)
    release_all()
