"""GL work in a renderer process, so that waiting for the driver never holds the caller's Python.

moderngl keeps Python's lock while the driver works: GL on any thread of Blender's process
holds the interface for the length of every call. Here a child process
(:mod:`.renderer_process`) owns the OpenGL context and the caller only queues messages. A child
that dies (a driver fault, a failed context, a kill) or hangs is an error on the next poll; the
next message starts a new one.

- :class:`RemoteWorker`: the viewport's :class:`~.worker.RenderWorker` interface, with a
  ``prepare(image)`` hook that turns each arriving frame (rows bottom-up, half floats) into what
  the display takes, on the receiver thread.
- :class:`FinalRenderer`: one final frame at a time; ``should_stop`` is polled every 20 ms and a
  cancel the child does not acknowledge within :data:`CANCEL_S` ends the child.
"""
from __future__ import annotations

import collections
import dataclasses
import itertools
import sys
import threading
import time
import types

import numpy as np

from ..errors import Cancelled
from .channel import RendererError, rebuild_error
from .messages import (
    SCENE_COMMANDS,
    Bake,
    Call,
    Cancel,
    DropView,
    FinalFrame,
    JobDone,
    Message,
    MoveInstances,
    Progress,
    RenderView,
    ResetHistory,
    ResetLight,
    SendError,
    ServerState,
    UpdateModel,
    ViewFrame,
    ViewScene,
)
from .renderer_process import CLOSE_S, RendererProcess, ended, env_seconds
from .worker import ViewResults, snapshot

#: how long a cancelled final render may take to stop before its process is ended
CANCEL_S = 0.12
class RemoteWorker(ViewResults):
    """:class:`~.worker.RenderWorker`'s interface over a renderer process (module docstring).
    The scene of render requests crosses once per change: each request carries only its camera,
    resolution and settings."""

    synchronous = False

    def __init__(self, prepare=None, name: str = "hybrid-shadows-viewport"):
        self._prepare = prepare
        self._init_results()
        self._acked = 0
        self._busy: dict = {}  # view -> the child's last word on its work
        self._busy_any = False
        self._closing = False
        self._scene_key = None
        self._scene_refs = None  # (the objects the key's ids name stay alive)
        self._tokens = itertools.count(1)
        self._token = 0
        self._seq = itertools.count(1)
        self.log: list = []
        self.coalesced = 0
        self._proc = RendererProcess(self._on_message, self._on_exit, name)

    # -- commands ---------------------------------------------------------------------------------
    def set_scene(self, scene, structure=None) -> None:
        """A new bake; it stands for the unsent bakes, moves and model edits before it (a move
        queued later is never merged with one of an earlier scene, whose rows may differ)."""
        post(self._proc, Bake(snapshot(scene), structure))

    def move_instances(self, scene, indices) -> None:
        """Instances moved; moves not sent yet become one (their instances, the newest scene)."""
        post(self._proc, MoveInstances(snapshot(scene), np.array(indices, np.int64)))

    def update_model(self, scene, model_id: int) -> None:
        """A model edited; an unsent edit of the same model is replaced (the newest scene has both)."""
        post(self._proc, UpdateModel(snapshot(scene), int(model_id)))

    def reset_history(self) -> None:
        post(self._proc, ResetHistory())

    def reset_light(self, index: int) -> None:
        post(self._proc, ResetLight(int(index)))

    def drop_view(self, view) -> None:
        with self._cond:
            self._results.pop(view, None)
            self._seen.pop(view, None)
            self._busy.pop(view, None)
        post(self._proc, DropView(view))

    def render(self, request) -> int:
        """Queue ``request`` in place of an unsent one of its view; returns its number."""
        with self._cond:
            if self._closing:
                return 0
            seq = next(self._seq)
            self._seen.setdefault(request.view, self._error_n)
        scene = request.scene
        refs = (scene.instances, scene.models, scene.lights, scene.materials, scene.images)
        key = tuple(map(id, refs)) + (scene.name, tuple(np.asarray(scene.world_color).tolist()))
        if key != self._scene_key:
            self._scene_key, self._scene_refs, self._token = key, refs, next(self._tokens)
            token = self._token
            # an unsent older scene is replaced: renders waiting for it take the newer one, queued
            # behind it (the sender may have taken that older scene already)
            post(self._proc, ViewScene(token, dataclasses.replace(scene, camera=None)),
                 rewrite=lambda m: dataclasses.replace(m, token=token) if isinstance(m, RenderView) else m)
        view_of = types.SimpleNamespace(camera=scene.camera, resolution=scene.resolution)
        msg = RenderView(dataclasses.replace(request, scene=view_of, seq=seq), self._token, seq)
        _, dropped = post(self._proc, msg)
        self.coalesced += dropped
        return seq

    # -- results: ViewResults.poll, has_news -------------------------------------------------------
    def busy(self, view=None) -> bool:
        """Whether messages are unapplied or the child reported work for ``view`` (any: None)."""
        with self._cond:
            if self._acked < self._proc.posted:
                return True
            return self._busy_any if view is None else bool(self._busy.get(view) or self._busy_any)

    def wait_idle(self, timeout: float = 60.0) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._closing or (self._acked >= self._proc.posted
                                                                 and not self._busy_any), timeout)

    def pump(self) -> None:
        """Nothing to do here (the child renders on its own)."""

    @property
    def alive(self) -> bool:
        return not self._closing

    @property
    def thread_alive(self) -> bool:
        """Whether it can still render: the sender runs, or the child does."""
        return self._proc.sender_alive or self._proc.running

    @property
    def pid(self):
        return self._proc.pid

    def close(self, timeout: float = 5.0) -> None:
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._proc.close(min(timeout, CLOSE_S))

    # -- receiver thread --------------------------------------------------------------------------
    def _on_message(self, msg: Message) -> None:
        if isinstance(msg, ViewFrame):
            view, result, infos = msg.view, msg.result, msg.errors
            if result is not None and self._prepare is not None:
                result.image = self._prepare(result.image)  # (outside the lock: it may take a while)
            with self._cond:
                for info in infos:
                    self._add_error(view, rebuild_error(info))
                if result is not None:
                    self._results[view] = result
                    self.log.append((view, result.seq, result.step, result.settings.quality, result.refine_left))
                    del self.log[:-1000]
                self._cond.notify_all()
        elif isinstance(msg, ServerState):
            with self._cond:
                self._acked = max(self._acked, msg.acked)
                self._busy = dict(msg.busy)
                self._busy_any = bool(msg.busy_any)
                self._cond.notify_all()
        elif isinstance(msg, SendError):
            with self._cond:
                self._acked = max(self._acked, msg.seq)
                self._add_error(None, RendererError(f"could not send '{type(msg.message).__name__}' to the renderer "
                                                    f"process: {msg.error[0]}: {msg.error[1]}"))
                self._cond.notify_all()

    def _on_exit(self, code, silent_s=None) -> None:
        # what was queued for that child's scene cannot be applied to a new one: the next frame
        # sends its scene again
        self._proc.discard(lambda m: isinstance(m, _DROPPED_ON_EXIT))
        with self._cond:
            self._add_error(None, RendererError(f"{ended(code, silent_s)}; the next frame starts a new one"))
            self._acked = self._proc.posted
            self._busy, self._busy_any = {}, False
            self._scene_key = self._scene_refs = None  # (the new child has no scene yet)
            self._cond.notify_all()


#: messages that act on the scene a child holds (dropped, unsent, when it ends; a bake is
#: kept: it brings the new child its scene)
_DROPPED_ON_EXIT = tuple(c for c in SCENE_COMMANDS if c is not Bake) + (RenderView,)


def post(proc, msg: Message, rewrite=None) -> tuple:
    """Queue ``msg`` on ``proc`` in place of the unsent messages it supersedes (merged into it
    where it merges); ``rewrite``: :meth:`.renderer_process.RendererProcess.post`'s."""
    return proc.post(msg, replace=msg.supersedes, merge=lambda dropped, m: m.merged(dropped), rewrite=rewrite)


def stage_deadline_s() -> float:
    """How long a final frame may go without progress (a bake's steps, a pass, a tile) before its
    renderer is taken for stuck: a backstop for a renderer that beats but does not advance.
    ``HYBRID_SHADOWS_STAGE_DEADLINE_S`` overrides the 3600 s."""
    return env_seconds("HYBRID_SHADOWS_STAGE_DEADLINE_S", 3600.0)


class FinalRenderer:
    """Final frames in a renderer process of their own (module docstring)."""

    def __init__(self, name: str = "hybrid-shadows-final"):
        self._cond = threading.Condition()
        self._events: collections.deque = collections.deque()
        self._jobs = itertools.count(1)
        self._exited = None
        self._killed = False
        self._proc = RendererProcess(self._on_message, self._on_exit, name)

    @property
    def pid(self):
        return self._proc.pid

    @property
    def starts(self) -> int:
        return self._proc.starts

    def call_steps(self, function, kwargs: dict):
        """Generator: run the generator function ``function`` (a module-level function of this
        package) in the process; yields each label it yields, or None after about 20 ms without
        one (so a modal operator's step returns); returns its return value. Closing it cancels
        the call."""
        job = self._begin()
        post(self._proc, Call(job, function, kwargs))
        finished = False
        try:
            while True:
                events, exited = self._wait()
                labels = []
                for ev in events:
                    if ev.job != job:
                        continue
                    if isinstance(ev, Progress):
                        labels.append(ev.label)
                        continue
                    finished = True
                    if ev.error is not None:
                        raise rebuild_error(ev.error)
                    for label in labels:
                        yield label
                    return ev.value
                if exited is not None:
                    finished = True
                    raise RendererError(ended(*exited))
                for label in labels or [None]:
                    yield label
        finally:
            if not finished:
                self._cancel(job)

    def _begin(self) -> int:
        """A new job's number, the events of earlier ones dropped (and the exit of a renderer
        ended by a cancel recorded first: the next message starts a new one)."""
        with self._cond:
            if self._killed:
                self._cond.wait_for(lambda: self._exited is not None, 5.0)
                self._killed = False
            self._events.clear()
            self._exited = None
        return next(self._jobs)

    def _wait(self):
        """The events that came within about 20 ms, and how the child ended (``(exit code,
        seconds silent or None)``; None: running)."""
        with self._cond:
            self._cond.wait_for(lambda: self._events or self._exited is not None, 0.02)
            events = list(self._events)
            self._events.clear()
            return events, self._exited

    def render(self, scene, settings, width: int, height: int, *, should_stop=None, on_progress=None,
               **options):
        """A :class:`~.render_server.FinalFrameData` of ``scene``. ``options``: ``film_transparent``,
        ``persistent_key`` (None: bake afresh and give the bake back after), ``reuse`` (with a
        ``persistent_key``: hard masks reused from the last frame, its history kept), ``want``
        (G-buffer targets to read), ``masks``, ``max_draw_ms``. ``should_stop()`` polled every 20 ms: True
        cancels (raises :class:`Cancelled`); ``on_progress(done, total, label)`` follows the child.
        A renderer that ends (or stays silent past :func:`.renderer_process.deadline_s`, or makes no progress for
        :func:`stage_deadline_s`) is started again and the frame rendered once more; a second
        failure raises :class:`RendererError` naming the stage (the last progress label) where it
        happened."""
        stage, limit = "the start", stage_deadline_s()
        for attempt in (1, 2):
            job = self._begin()
            post(self._proc, FinalFrame(job, scene, settings, int(width), int(height), options))
            exited, stuck, last = None, None, time.monotonic()
            while exited is None:
                events, exited = self._wait()
                for ev in events:
                    if ev.job != job:
                        continue
                    if isinstance(ev, Progress):
                        stage, last = ev.label or stage, time.monotonic()
                        if on_progress is not None:
                            on_progress(ev.done, ev.total, ev.label)
                        continue
                    if ev.error is not None:
                        raise rebuild_error(ev.error)
                    return ev.value
                if exited is None and should_stop is not None and should_stop():
                    self._cancel(job)
                    raise Cancelled()
                if exited is None and time.monotonic() - last > limit:
                    stuck = time.monotonic() - last
                    self._proc.kill()
                    with self._cond:
                        self._cond.wait_for(lambda: self._exited is not None, 10.0)
                        exited = self._exited or (None, None)
            how = (f"the renderer process made no progress for {stuck:.1f} s and was ended" if stuck is not None
                   else ended(*exited))
            if attempt == 2:
                raise RendererError(f"{how} in '{stage}', twice: the frame was not rendered")
            print(f"Hybrid Shadows: {how} in '{stage}'; rendering the frame again", file=sys.stderr, flush=True)

    def _cancel(self, job) -> None:
        """Stop ``job``: the child drops it between two steps, or is ended after :data:`CANCEL_S`."""
        cancel = Cancel(job)
        if self._proc.unsent(cancel.supersedes):
            post(self._proc, cancel)
            return
        post(self._proc, cancel)
        with self._cond:
            done = self._cond.wait_for(lambda: self._exited is not None or any(
                isinstance(e, JobDone) and e.job == job for e in self._events), CANCEL_S)
        if not done:
            self._proc.kill()
            self._killed = True  # (the next job waits for its exit to be recorded)

    def close(self) -> None:
        self._proc.close()

    def _on_message(self, msg: Message) -> None:
        if isinstance(msg, SendError):  # (a job that cannot cross fails with what pickling said)
            if not isinstance(msg.message, (FinalFrame, Call)):
                return
            info = msg.error
            msg = JobDone(msg.message.job, None, ("RendererError", f"the frame could not be sent to the renderer "
                                                  f"process ({info[0]}: {info[1]})", info[2]))
        if isinstance(msg, (Progress, JobDone)):
            with self._cond:
                self._events.append(msg)
                self._cond.notify_all()

    def _on_exit(self, code, silent_s=None) -> None:
        with self._cond:
            self._exited = (code, silent_s)
            self._cond.notify_all()
