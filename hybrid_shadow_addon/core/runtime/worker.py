"""The rendered viewport's render worker (bpy-free).

- :class:`RenderWorker`: a daemon thread owning one standalone OpenGL context and one
  :class:`~..gpu.pipeline.Pipeline` (made in the thread, so its context is only ever current there).
  The main thread hands it commands through a queue: bake, move instances, update a model,
  reset history (the :class:`~..gpu.pipeline.Pipeline` methods the viewport sync calls, so the worker
  stands in for a pipeline there) and render a view. Each takes a :func:`snapshot` of the scene
  (copy-on-write, no array copied), so the main thread may go on editing its own. Commands run in order;
  render requests for the
  same view coalesce (only the newest pending one runs). A render request carries the fast and
  the full settings: the worker renders the fast pass, then the full-quality frames (four with
  interlacing, more while soft shadows or see-through surfaces accumulate) as long as nothing
  newer arrives, one frame per step. Each view renders through its own
  :meth:`Pipeline.view` (own targets and history, the worker's bake). Errors are kept for the
  caller's :meth:`RenderWorker.poll`. ``synchronous=True`` (or :data:`SYNCHRONOUS`) runs the
  same steps inline, one render step per :meth:`RenderWorker.pump`, for debugging.

What the viewports of one scene share (one worker, one scene sync) is in :mod:`.viewport_share`.
"""
from __future__ import annotations

import atexit
import collections
import contextlib
import dataclasses
import itertools
import os
import threading
import weakref
from dataclasses import dataclass, field

import numpy as np

from ..gpu.context import software_renderer

#: run the workers' steps inline on the caller's thread (debugging only): the environment
#: variable ``HYBRID_SHADOWS_VIEWPORT_SYNC=1``, or set this before workers are made
SYNCHRONOUS = os.environ.get("HYBRID_SHADOWS_VIEWPORT_SYNC", "").strip() not in ("", "0")

#: commands that change the bake or the scene's lighting: refinement in progress is stale
_SCENE_COMMANDS = ("bake", "move", "model", "reset", "reset_light")


def snapshot(scene):
    """A copy of a core Scene that later edits of ``scene`` do not reach, without copying its
    arrays: its own lists (the sync replaces models and lights in them, never edits one: GPU
    buffers cached per model stay), and the instance matrices shared copy-on-write: they
    become read-only in ``scene`` too, so whoever moves instances afterwards first takes its
    own copy (:func:`writable_matrices`; an edit in place raises instead of reaching the
    worker)."""
    inst = scene.instances
    for a in (inst.matrices, inst.inverse):
        a.flags.writeable = False
    own = dataclasses.replace(inst, names=list(inst.names))
    return dataclasses.replace(scene, instances=own, models=list(scene.models), lights=list(scene.lights),
                               materials=list(scene.materials), images=list(scene.images),
                               world_color=np.array(scene.world_color, np.float32))


def writable_matrices(instances) -> None:
    """Copy ``instances``' matrices (and inverses) if a :func:`snapshot` shares them, before
    ``Instances.set_matrices`` edits them in place."""
    if not instances.matrices.flags.writeable:
        instances.matrices = instances.matrices.copy()
    if not instances.inverse.flags.writeable:
        instances.inverse = instances.inverse.copy()


def fast_settings(request, renderer: str):
    """The settings of a request's fast pass on ``renderer`` (its ``GL_RENDERER``). With
    ``request.fast_auto`` (the viewport's automatic navigation quality) the fast pass takes the
    full pass's quality on a software rasteriser, where a lower quality costs more, not less, and
    where the view reuses visibility (full-resolution masks are what it reuses; its other
    differences stay: fewer soft samples, no probe pass); elsewhere ``request.fast``."""
    fast = request.fast
    keep = software_renderer(renderer) or getattr(request, "reuse", False)
    if getattr(request, "fast_auto", False) and keep and fast.quality != request.full.quality:
        fast = fast.replace(quality=request.full.quality)
    return fast


def refine_frames(fast, full) -> int:
    """Full-quality frames after the fast pass of a change: four with interlacing (one per ray
    phase), one when the fast pass differs from full quality, else none."""
    return (4 if full.interlace else 1) if (fast != full or full.interlace) else 0


@dataclass
class RenderRequest:
    """One view to render. ``scene``: a snapshot with the view's camera; ``post(frame, scene,
    pipeline) -> image`` (optional) runs in the worker after each frame (debug views)."""

    view: object
    scene: object
    fast: object  # Settings of the first frame
    full: object  # Settings of the refinement frames
    width: int
    height: int
    film_transparent: bool = False
    post: object = None
    seq: int = 0
    fast_auto: bool = False  # the fast pass's quality follows the renderer (fast_settings)
    reuse: bool = False  # the view's Pipeline.reuse: visibility kept across camera moves and edits


@dataclass
class ViewResult:
    """A finished frame of a view. ``step`` 0 is the fast pass; ``refine_left``: frames still to
    come for the same request (none if a newer request or a scene change supersedes it)."""

    view: object
    seq: int
    step: int
    image: np.ndarray
    settings: object
    refine_left: int
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


class _Job:
    """A render request and its refinement. ``epoch``: the worker's when it was queued (a scene
    command queued after it makes its refinement stale: its snapshot predates the command)."""

    def __init__(self, request, epoch: int):
        self.request = request
        self.epoch = epoch
        self.step = 0
        self.refine = 0
        self.settle = False  # the next frame traces the hard masks whole (the view came to rest)


def _default_create():
    from ..gpu.pipeline import Pipeline

    return Pipeline()


@contextlib.contextmanager
def _default_scope(pipeline):
    with pipeline.ctx:
        yield pipeline


def _default_release(pipeline) -> None:
    with pipeline.ctx:
        pipeline.release()
    pipeline.ctx.release()


_live: weakref.WeakSet[RenderWorker] = weakref.WeakSet()


class ViewResults:
    """The finished frames and errors of a worker's views, taken by the caller: the newest frame
    of each view (``_results``) and the errors of each view or of every view (``_errors``, each
    given once per view). Guarded by ``_cond``."""

    def _init_results(self) -> None:
        self._cond = threading.Condition()
        self._results: dict = {}  # view -> newest ViewResult not taken yet
        self._errors: list = []  # (n, view or None for every view, exception)
        self._error_n = 0
        self._seen: dict = {}  # view -> n of the last error it took

    def _add_error(self, view, exc) -> None:
        """Record ``exc`` for ``view`` (None: every view); call with ``_cond`` held."""
        self._error_n += 1
        self._errors.append((self._error_n, view, exc))
        del self._errors[:-64]

    def poll(self, view):
        """``(result, errors)``: the newest finished frame of ``view`` not taken yet (or None) and
        the errors raised for it (or for every view) since the last poll, each given once."""
        with self._cond:
            result = self._results.pop(view, None)
            seen = self._seen.get(view, 0)
            errors = [e for n, v, e in self._errors if n > seen and (v is None or v == view)]
            self._seen[view] = self._error_n
            return result, errors

    def has_news(self, view) -> bool:
        """Whether :meth:`poll` would give ``view`` a frame or an error."""
        with self._cond:
            seen = self._seen.get(view, 0)
            return view in self._results or any(n > seen and (v is None or v == view) for n, v, _ in self._errors)


class RenderWorker(ViewResults):
    """See the module docstring. ``create()`` makes the pipeline (with its context),
    ``scope(pipeline)`` makes its context current meanwhile, ``release(pipeline)`` frees it."""

    def __init__(self, create=None, scope=None, release=None, synchronous: bool | None = None,
                 name: str = "hybrid-shadows-viewport"):
        self._create = create or _default_create
        self._scope = scope or _default_scope
        self._release = release or _default_release
        self.synchronous = SYNCHRONOUS if synchronous is None else bool(synchronous)
        self._init_results()
        self._queue: collections.deque = collections.deque()
        self._active = None  # the item being executed
        self._epoch = 0  # bumped by every scene command: refinement started before is stale
        self._seq = itertools.count(1)
        self._closing = False
        self._pipe = None
        self._views: dict = {}  # view -> Pipeline.view() (worker side only)
        self.log: list = []  # (view, seq, step, quality, refine_left) per rendered frame
        self.coalesced = 0  # render requests replaced by a newer one before they ran
        self._thread = None
        if not self.synchronous:
            self._thread = threading.Thread(target=self._run, name=name, daemon=True)
            self._thread.start()
        _live.add(self)

    # -- commands (caller's thread) ---------------------------------------------------------------
    def set_scene(self, scene, structure: str | None = None) -> None:
        """Bake ``scene`` (as :meth:`Pipeline.set_scene`). It stands for the bakes, moves and
        model edits still queued (a move queued later never merges with one of an earlier scene,
        whose rows may differ)."""
        with self._cond:
            self._remove(lambda it: it[0] in ("bake", "move", "model"))
        self._command(("bake", snapshot(scene), structure))

    def move_instances(self, scene, indices) -> None:
        """Instances moved; moves still queued become one (their instances, the newest scene):
        a drag applies one update per step the worker takes, not one per depsgraph update."""
        idx = np.array(indices, np.int64)
        with self._cond:
            queued = [it for it in self._queue if it[0] == "move"]
            if queued:
                self._remove(lambda it: it[0] == "move")
                idx = np.unique(np.concatenate([it[2] for it in queued] + [idx]))
        self._command(("move", snapshot(scene), idx))

    def update_model(self, scene, model_id: int) -> None:
        """A model edited; a queued edit of the same model is replaced (the newest scene has both)."""
        mid = int(model_id)
        with self._cond:
            self._remove(lambda it: it[0] == "model" and it[2] == mid)
        self._command(("model", snapshot(scene), mid))

    def reset_history(self) -> None:
        """What every mask depends on changed: every view starts its history again."""
        self._command(("reset",))

    def reset_light(self, index: int) -> None:
        """Light ``index``'s shadow changed: every view forgets that light's history."""
        self._command(("reset_light", int(index)))

    def drop_view(self, view) -> None:
        """Forget ``view``: its pending renders, results and pipeline."""
        with self._cond:
            self._remove(lambda it: it[0] in ("render", "continue") and it[1] == view)
            self._results.pop(view, None)
            self._seen.pop(view, None)
        self._command(("drop", view))

    def render(self, request: RenderRequest) -> int:
        """Queue ``request`` in place of any pending one of its view; returns its sequence number."""
        with self._cond:
            if self._closing:
                return 0
            request.seq = next(self._seq)
            self._seen.setdefault(request.view, self._error_n)  # (errors from before it came: not its own)
            if self._remove(lambda it: it[0] == "render" and it[1] == request.view):
                self.coalesced += 1
            self._remove(lambda it: it[0] == "continue" and it[1] == request.view)
            self._queue.append(("render", request.view, _Job(request, self._epoch)))
            self._cond.notify_all()
        return request.seq

    def _command(self, item) -> None:
        with self._cond:
            if self._closing:
                return
            if item[0] in _SCENE_COMMANDS:
                self._epoch += 1
                self._remove(lambda it: it[0] == "continue")
            self._queue.append(item)
            self._cond.notify_all()

    def _remove(self, pred) -> int:
        keep = [it for it in self._queue if not pred(it)]
        n = len(self._queue) - len(keep)
        if n:
            self._queue.clear()
            self._queue.extend(keep)
        return n

    # -- results (caller's thread): ViewResults.poll, has_news --------------------------------------
    def busy(self, view=None) -> bool:
        """Whether work that concerns ``view`` (any, when None) is queued or running: its renders
        and refinement, and every scene command."""
        with self._cond:
            items = list(self._queue) + ([self._active] if self._active is not None else [])
        return any(view is None or it[0] in _SCENE_COMMANDS or (it[0] in ("render", "continue") and it[1] == view)
                   for it in items)

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until nothing is queued or running (inline: run it all); False on timeout."""
        if self.synchronous:
            while self.busy():
                self.pump()
            return True
        with self._cond:
            return self._cond.wait_for(lambda: (not self._queue and self._active is None) or self._closing, timeout)

    def pump(self) -> None:
        """Inline mode: run the queued commands and at most one render step (the draw callback
        calls it; one frame per redraw). Does nothing with a thread."""
        if not self.synchronous:
            return
        while True:
            with self._cond:
                if not self._queue or self._closing:
                    return
                item = self._queue.popleft()
                self._active = item
            try:
                rendered = self._execute(item)
            finally:
                with self._cond:
                    self._active = None
            if rendered:
                return

    @property
    def alive(self) -> bool:
        return not self._closing

    def close(self, timeout: float = 5.0) -> None:
        """Drop the queued work, stop the thread (joined for at most ``timeout`` s: a frame
        under way finishes first) and release the context. Safe to call twice."""
        with self._cond:
            first = not self._closing
            self._closing = True
            self._queue.clear()
            self._cond.notify_all()
        if self._thread is not None:
            if self._thread is not threading.current_thread():
                self._thread.join(timeout)
        elif first:
            self._release_gl()
        _live.discard(self)

    @property
    def thread_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- worker side ------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    while not self._queue and not self._closing:
                        self._cond.wait()
                    if self._closing:
                        return
                    item = self._queue.popleft()
                    self._active = item
                try:
                    self._execute(item)
                finally:
                    with self._cond:
                        self._active = None
                        self._cond.notify_all()
        finally:
            self._release_gl()

    @property
    def context(self):
        """The OpenGL context of this worker's pipeline (None before its first command)."""
        pipe = self._pipe
        return None if pipe is None else pipe.ctx

    def _pipeline(self):
        if self._pipe is None:
            self._pipe = self._create()
        return self._pipe

    def _execute(self, item) -> bool:
        """Run one item; True when it rendered a frame. Exceptions become errors for poll."""
        kind = item[0]
        view = item[1] if kind in ("render", "continue", "drop") else None
        try:
            if kind == "drop":
                vp = self._views.pop(view, None)
                if vp is not None and self._pipe is not None:
                    with self._scope(self._pipe):
                        vp.release()
                return False
            pipe = self._pipeline()
            with self._scope(pipe):
                if kind in ("render", "continue"):
                    self._render_step(pipe, item[2])
                    return True
                self._scene_command(pipe, item)
            return False
        except BaseException as exc:  # noqa: BLE001 - every failure reaches the caller
            if kind in _SCENE_COMMANDS and self._pipe is not None:
                self._pipe.baked = None  # half-updated: the next ray-traced frame bakes afresh
            with self._cond:
                self._add_error(view, exc)
            if not isinstance(exc, Exception):
                raise
            return kind in ("render", "continue")

    def _scene_command(self, pipe, item) -> None:
        kind = item[0]
        if kind == "bake":
            pipe.set_scene(item[1], item[2])
        elif kind in ("move", "model"):
            if pipe.baked is None:
                return  # no bake (or a failed one): the next ray-traced frame bakes this scene
            if kind == "move":
                pipe.move_instances(item[1], item[2])
            else:
                pipe.update_model(item[1], item[2])
        if kind == "reset":  # (bake changes reach the views through Pipeline.view, edits as what they touch)
            for vp in self._views.values():
                vp.reset_history()
        elif kind == "reset_light":
            for vp in self._views.values():
                vp.reset_light(item[1])

    @staticmethod
    def _renderer(pipe) -> str:
        """The pipeline's ``GL_RENDERER`` ('' when it has no context to ask)."""
        info = getattr(getattr(pipe, "ctx", None), "info", None) or {}
        return str(info.get("GL_RENDERER", ""))

    def _render_step(self, pipe, job: _Job) -> None:
        req = job.request
        vp = self._views.get(req.view)
        if vp is None:
            vp = self._views[req.view] = pipe.view()
            vp.timing = "frame"  # (no wait but the image's: per-pass times and ray counts unread)
        vp.reuse = bool(req.reuse)
        if job.step == 0:  # (a camera move keeps the history: the view reprojects what stays exact)
            settings = fast_settings(req, self._renderer(pipe))
            job.refine = refine_frames(settings, req.full)
        else:
            settings = req.full
            job.refine -= 1
            if job.settle:  # (once: the frames after it reuse that exact one)
                vp.retrace_once()
                job.settle = False
        frame = vp.render(req.scene, settings, req.width, req.height, film_transparent=req.film_transparent)
        if job.step == 0 and frame.stats.get("reuse_ways", {}).get("reused"):  # exact again once the view rests
            job.refine, job.settle = max(job.refine, 1), True
        image = frame.image if req.post is None else req.post(frame, req.scene, vp)
        acc = frame.stats.get("accumulated_samples")
        if acc is not None and settings.accumulate and acc < settings.samples:
            job.refine = max(job.refine, 1)  # soft lights still converging: one more frame
        seen = frame.stats.get("see_through_samples")
        if seen is not None and settings.accumulate and seen < frame.stats["see_through_target"]:
            job.refine = max(job.refine, 1)  # see-through surfaces still converging: one more frame
        result = ViewResult(view=req.view, seq=req.seq, step=job.step, image=image, settings=settings,
                            refine_left=job.refine, stats=dict(frame.stats), timings=dict(frame.timings))
        job.step += 1
        with self._cond:
            self.log.append((req.view, req.seq, result.step, settings.quality, job.refine))
            del self.log[:-1000]
            self._results[req.view] = result
            newer = any(it[0] == "render" and it[1] == req.view for it in self._queue)
            if job.refine > 0 and not newer and job.epoch == self._epoch and not self._closing:
                self._queue.append(("continue", req.view, job))

    def _release_gl(self) -> None:
        pipe, self._pipe = self._pipe, None
        views, self._views = list(self._views.values()), {}
        if pipe is None:
            return
        try:
            with self._scope(pipe):
                for vp in views:
                    vp.release()
        except Exception:  # at exit the context may already be gone
            pass
        try:
            self._release(pipe)
        except Exception:
            pass


@atexit.register
def close_all() -> None:
    """Stop every worker still running (interpreter exit; also the add-on's unregister)."""
    for w in list(_live):
        w.close(timeout=2.0)
