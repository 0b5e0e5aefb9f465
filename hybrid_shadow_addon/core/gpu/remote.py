"""GL work in a renderer process, so that waiting for the driver never holds the caller's Python.

moderngl keeps Python's lock while the driver works: GL on any thread of Blender's process
holds the interface for the length of every call. Here a child process (the same Python,
``sys.executable``, importing only this core: :mod:`.render_server`) owns the OpenGL context;
the caller's threads only queue messages, which a sender thread pickles and writes to the
child's stdin, and a receiver thread reads the replies from its stdout. Both wait in system
calls that release the lock. A child that dies (a driver fault, a failed context, a kill) is an
error on the next poll; the next message starts a new one.

- :class:`RemoteWorker`: the viewport's :class:`~.worker.RenderWorker` interface, with a
  ``prepare(image)`` hook that turns each arriving frame (rows bottom-up, half floats) into what
  the display takes, on the receiver thread.
- :class:`FinalRenderer`: one final frame at a time; ``should_stop`` is polled every 20 ms and a
  cancel the child does not acknowledge within :data:`CANCEL_S` ends the child.
"""
from __future__ import annotations

import atexit
import collections
import dataclasses
import itertools
import json
import os
import subprocess
import sys
import threading
import time
import traceback
import types
import weakref
from pathlib import Path

import numpy as np

from ..errors import Cancelled
from .channel import RendererError, encode_message, error_info, read_message, rebuild_error, write_encoded
from .worker import ViewResults, snapshot

#: how long a cancelled final render may take to stop before its process is ended
CANCEL_S = 0.12
#: how long :meth:`RendererProcess.close` waits for the child to exit before ending it
CLOSE_S = 2.0


def deadline_s() -> float:
    """How long a renderer may stay silent before it is taken for hung and ended. The child
    sends a heartbeat every :data:`~.render_server.HEARTBEAT_S` from a thread that runs whenever
    it is not inside one driver call (moderngl keeps Python's lock through each), so this bounds
    the longest single GL call (a shader compile on a software rasteriser takes seconds), not a
    stage: a long bake keeps beating. ``HYBRID_SHADOWS_DEADLINE_S`` overrides the 120 s."""
    try:
        value = float(os.environ.get("HYBRID_SHADOWS_DEADLINE_S", "120"))
    except ValueError:
        value = 120.0
    return value if value > 0 else 120.0

# The child imports the package under the caller's own module name (in Blender an extension's
# is ``bl_ext.<repository>.<id>.hybrid_shadow_addon``), so that pickled classes name the same
# modules on both sides: the packages above it become plain namespace stubs, their code unrun.
_BOOT = """
import importlib, json, os, sys, types
f = sys.stdin.buffer
cfg = json.loads(f.readline())
sys.path[:0] = cfg["path"]
parts, d = cfg["root"].split("."), cfg["root_dir"]
for i in range(len(parts) - 1, 0, -1):
    d = os.path.dirname(d)
    name = ".".join(parts[:i])
    if name not in sys.modules:
        stub = types.ModuleType(name)
        stub.__path__ = [d]
        sys.modules[name] = stub
importlib.import_module(cfg["root"] + ".core.gpu.render_server").serve(f)
"""
_ROOT = __name__.rsplit(".core.gpu.", 1)[0]


def _package_dir() -> Path:
    return Path(__file__).resolve().parents[2]


class RendererProcess:
    """One renderer child and its channel. :meth:`post` queues a message body (any thread; the
    child starts on the first); ``on_message(msg)`` and ``on_exit(code, silent_s)`` run on the
    receiver thread (``silent_s``: how long the child had been silent when it was ended for it,
    else None). After an exit the next :meth:`post` starts a new child. A message that cannot be
    pickled comes back as ``("send_error", seq, error_info, body)``."""

    def __init__(self, on_message, on_exit, name: str = "hybrid-shadows-renderer"):
        self._on_message = on_message
        self._on_exit = on_exit
        self.name = name
        self._cond = threading.Condition()
        self._outbox: collections.deque = collections.deque()  # (seq, body)
        self._seq = itertools.count(1)
        self.posted = 0  # seq of the newest message posted
        self._proc = None
        self._closing = False
        self.starts = 0
        self.deadline = deadline_s()
        self._heard = {}  # child pid -> time.monotonic() of its last message
        self.hung = None  # (pid, seconds silent) of the last child ended for silence
        self._sender = threading.Thread(target=self._send_loop, name=f"{name}-send", daemon=True)
        self._sender.start()
        threading.Thread(target=self._watch_loop, name=f"{name}-watch", daemon=True).start()
        _live.add(self)

    # -- caller side ------------------------------------------------------------------------------
    def post(self, body, replace=None, merge=None, rewrite=None) -> tuple:
        """Queue ``body``. ``replace(body)``: unsent messages it matches are dropped first, and
        ``merge(dropped bodies, body)`` makes the body queued from them; ``rewrite(body)``:
        what each unsent message becomes; one it changes now depends on ``body`` and moves
        behind it. Returns ``(message seq, dropped count)``."""
        with self._cond:
            if self._closing:
                return 0, 0
            dropped = 0
            if replace is not None:
                keep = [m for m in self._outbox if not replace(m[1])]
                gone = [m[1] for m in self._outbox if replace(m[1])]
                dropped = len(gone)
                self._outbox = collections.deque(keep)
                if gone and merge is not None:
                    body = merge(gone, body)
            behind = []
            if rewrite is not None:
                keep = collections.deque()
                for m in self._outbox:
                    nb = rewrite(m[1])
                    (keep if nb is m[1] else behind).append((m[0], nb))
                self._outbox = keep
            seq = next(self._seq)
            self.posted = seq
            self._outbox.append((seq, body))
            self._outbox.extend(behind)
            self._cond.notify_all()
            return seq, dropped

    def unsent(self, pred) -> bool:
        with self._cond:
            return any(pred(m[1]) for m in self._outbox)

    @property
    def running(self) -> bool:
        p = self._proc
        return p is not None and p.poll() is None

    @property
    def pid(self):
        p = self._proc
        return None if p is None else p.pid

    @property
    def sender_alive(self) -> bool:
        return self._sender.is_alive()

    def kill(self) -> None:
        """End the child now (its work is lost; the next message starts a new one)."""
        p = self._proc
        if p is not None and p.poll() is None:
            p.kill()

    def discard(self, pred) -> int:
        """Drop the unsent messages whose body ``pred`` matches; how many."""
        with self._cond:
            keep = [m for m in self._outbox if not pred(m[1])]
            n = len(self._outbox) - len(keep)
            self._outbox = collections.deque(keep)
            return n

    def close(self, timeout: float = CLOSE_S) -> None:
        """Ask the child to exit, end it after ``timeout`` s, stop the sender. Safe twice."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._outbox.clear()
            self._cond.notify_all()
        p = self._proc
        if p is not None:
            try:
                p.stdin.close()  # the child's reader sees the end and the child exits
            except OSError:
                pass
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        with self._cond:  # (the sender starts no child once closing is set)
            p = self._proc
        if p is not None and p.poll() is None:
            p.kill()
            p.wait(5)
        _live.discard(self)

    # -- threads ----------------------------------------------------------------------------------
    def _spawn(self):
        pkg = _package_dir()
        cfg = {"path": [str(pkg.parent)] + [p for p in sys.path if p], "root": _ROOT, "root_dir": str(pkg)}
        flags = getattr(subprocess, "CREATE_NO_WINDOW", 0) if os.name == "nt" else 0
        proc = subprocess.Popen([sys.executable, "-I", "-c", _BOOT], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                creationflags=flags)
        proc.stdin.write((json.dumps(cfg) + "\n").encode())
        proc.stdin.flush()
        self.starts += 1
        self._heard[proc.pid] = time.monotonic()
        threading.Thread(target=self._receive_loop, args=(proc,), name=f"{self.name}-receive", daemon=True).start()
        return proc

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._outbox and not self._closing:
                    self._cond.wait()
                if self._closing:
                    return
                msg = self._outbox.popleft()
            try:
                pieces = encode_message(msg)
            except Exception as exc:  # noqa: BLE001 - a message that cannot cross (a bug): said, not lost
                self._on_message(("send_error", msg[0], error_info(exc), msg[1]))
                continue
            try:
                with self._cond:  # (close() sees every child started)
                    if self._closing:
                        return
                    if self._proc is None or self._proc.poll() is not None:
                        self._proc = self._spawn()
                    proc = self._proc
                write_encoded(proc.stdin, pieces)
            except (OSError, ValueError):  # the child is gone (or never started): the receiver reports it
                pass

    def _receive_loop(self, proc) -> None:
        try:
            while True:
                msg = read_message(proc.stdout)
                self._heard[proc.pid] = time.monotonic()
                if msg[0] != "alive":
                    self._on_message(msg)
        except (EOFError, OSError):
            pass
        except BaseException:  # noqa: BLE001 - a reply that cannot be read: end that child
            traceback.print_exc()
            proc.kill()
        code = proc.wait()
        self._heard.pop(proc.pid, None)
        hung = self.hung if self.hung is not None and self.hung[0] == proc.pid else None
        if not self._closing:
            self._on_exit(code, None if hung is None else hung[1])

    def _watch_loop(self) -> None:
        """End a child silent for longer than :attr:`deadline` (stopped, or stuck in the driver)."""
        while not self._closing:
            time.sleep(min(0.25, self.deadline / 4))
            p = self._proc
            if p is None or p.poll() is not None:
                continue
            silent = time.monotonic() - self._heard.get(p.pid, time.monotonic())
            if silent > self.deadline:
                self.hung = (p.pid, silent)
                p.kill()


_live: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def close_all() -> None:
    """End every renderer process (interpreter exit, the add-on's unregister)."""
    for p in list(_live):
        p.close(timeout=1.0)


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
        self._proc.post(("bake", snapshot(scene), structure), replace=lambda b: b[0] in ("bake", "move", "model"))

    def move_instances(self, scene, indices) -> None:
        """Instances moved; moves not sent yet become one (their instances, the newest scene)."""
        self._proc.post(("move", snapshot(scene), np.array(indices, np.int64)), replace=lambda b: b[0] == "move",
                        merge=_merge_moves)

    def update_model(self, scene, model_id: int) -> None:
        """A model edited; an unsent edit of the same model is replaced (the newest scene has both)."""
        mid = int(model_id)
        self._proc.post(("model", snapshot(scene), mid), replace=lambda b: b[0] == "model" and b[2] == mid)

    def reset_history(self) -> None:
        self._proc.post(("reset",))

    def reset_light(self, index: int) -> None:
        self._proc.post(("reset_light", int(index)))

    def drop_view(self, view) -> None:
        with self._cond:
            self._results.pop(view, None)
            self._seen.pop(view, None)
            self._busy.pop(view, None)
        self._proc.post(("drop", view), replace=lambda b: b[0] == "render" and b[1].view == view)

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
            self._proc.post(("scene", token, dataclasses.replace(scene, camera=None)),
                            replace=lambda b: b[0] == "scene",
                            rewrite=lambda b: (b[0], b[1], token, b[3]) if b[0] == "render" else b)
        view_of = types.SimpleNamespace(camera=scene.camera, resolution=scene.resolution)
        body = ("render", dataclasses.replace(request, scene=view_of, seq=seq), self._token, seq)
        _, dropped = self._proc.post(body, replace=lambda b: b[0] == "render" and b[1].view == request.view)
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
    def _on_message(self, msg) -> None:
        kind = msg[0]
        if kind == "result":
            _, view, result, infos = msg
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
        elif kind == "state":
            with self._cond:
                self._acked = max(self._acked, msg[1])
                self._busy = dict(msg[2])
                self._busy_any = bool(msg[3])
                self._cond.notify_all()
        elif kind == "send_error":
            with self._cond:
                self._acked = max(self._acked, msg[1])
                self._add_error(None, RendererError(f"could not send '{msg[3][0]}' to the renderer process: "
                                                    f"{msg[2][0]}: {msg[2][1]}"))
                self._cond.notify_all()

    def _on_exit(self, code, silent_s=None) -> None:
        # what was queued for that child's scene cannot be applied to a new one: the next frame
        # sends its scene again
        self._proc.discard(lambda b: b[0] in _SCENE_COMMANDS)
        with self._cond:
            self._add_error(None, RendererError(f"{ended(code, silent_s)}; the next frame starts a new one"))
            self._acked = self._proc.posted
            self._busy, self._busy_any = {}, False
            self._scene_key = self._scene_refs = None  # (the new child has no scene yet)
            self._cond.notify_all()


#: messages that act on the scene a child holds (dropped, unsent, when it ends)
_SCENE_COMMANDS = ("render", "move", "model", "reset", "reset_light")


def stage_deadline_s() -> float:
    """How long a final frame may go without progress (a bake's steps, a pass, a tile) before its
    renderer is taken for stuck: a backstop for a renderer that beats but does not advance.
    ``HYBRID_SHADOWS_STAGE_DEADLINE_S`` overrides the 3600 s."""
    try:
        value = float(os.environ.get("HYBRID_SHADOWS_STAGE_DEADLINE_S", "3600"))
    except ValueError:
        value = 3600.0
    return value if value > 0 else 3600.0


def ended(code, silent_s=None) -> str:
    """How a renderer process ended, in words."""
    if silent_s is not None:
        return f"the renderer process stopped answering for {silent_s:.0f} s and was ended"
    return f"the renderer process ended unexpectedly (exit code {code})"


def _merge_moves(dropped: list, body: tuple) -> tuple:
    """One move for unsent ones: every moved instance, the newest scene."""
    idx = np.unique(np.concatenate([b[2] for b in dropped] + [body[2]]))
    return body[0], body[1], idx


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

    def call_steps(self, target: str, kwargs: dict):
        """Generator: run the generator function ``target`` (``"module:function"`` of this
        package) in the process; yields each label it yields, or None after about 20 ms without
        one (so a modal operator's step returns); returns its return value. Closing it cancels
        the call."""
        job = self._begin()
        self._proc.post(("call", job, target, kwargs))
        finished = False
        try:
            while True:
                events, exited = self._wait()
                labels = []
                for ev in events:
                    if ev[1] != job:
                        continue
                    if ev[0] == "progress":
                        labels.append(ev[4])
                        continue
                    finished = True
                    if ev[3] is not None:
                        raise rebuild_error(ev[3])
                    for label in labels:
                        yield label
                    return ev[2]
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
        """A :class:`~.render_server.FrameData` of ``scene``. ``options``: ``film_transparent``,
        ``persistent_key`` (None: bake afresh and give the bake back after), ``reuse`` (with a
        ``persistent_key``: hard masks reused from the last frame, its history kept), ``want``
        (G-buffer targets to read), ``masks``, ``max_draw_ms``. ``should_stop()`` polled every 20 ms: True
        cancels (raises :class:`Cancelled`); ``on_progress(done, total, label)`` follows the child.
        A renderer that ends (or stays silent past :func:`deadline_s`, or makes no progress for
        :func:`stage_deadline_s`) is started again and the frame rendered once more; a second
        failure raises :class:`RendererError` naming the stage (the last progress label) where it
        happened."""
        stage, limit = "the start", stage_deadline_s()
        for attempt in (1, 2):
            job = self._begin()
            self._proc.post(("final", job, scene, settings, int(width), int(height), options))
            exited, stuck, last = None, None, time.monotonic()
            while exited is None:
                events, exited = self._wait()
                for ev in events:
                    if ev[1] != job:
                        continue
                    if ev[0] == "progress":
                        stage, last = ev[4] or stage, time.monotonic()
                        if on_progress is not None:
                            on_progress(*ev[2:])
                        continue
                    data, info = ev[2], ev[3]
                    if info is not None:
                        raise rebuild_error(info)
                    return data
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
        if self._proc.unsent(lambda b: b[0] in ("final", "call") and b[1] == job):
            self._proc.post(("cancel", job), replace=lambda b: b[0] in ("final", "call") and b[1] == job)
            return
        self._proc.post(("cancel", job))
        with self._cond:
            done = self._cond.wait_for(lambda: self._exited is not None or any(
                e[0] == "final" and e[1] == job for e in self._events), CANCEL_S)
        if not done:
            self._proc.kill()
            self._killed = True  # (the next job waits for its exit to be recorded)

    def close(self) -> None:
        self._proc.close()

    def _on_message(self, msg) -> None:
        if msg[0] == "send_error":  # (a job that cannot cross fails with what pickling said)
            body = msg[3]
            if body[0] not in ("final", "call"):
                return
            info = msg[2]
            msg = ("final", body[1], None, ("RendererError", f"the frame could not be sent to the renderer process "
                                            f"({info[0]}: {info[1]})", info[2]))
        if msg[0] in ("progress", "final"):
            with self._cond:
                self._events.append(msg)
                self._cond.notify_all()

    def _on_exit(self, code, silent_s=None) -> None:
        with self._cond:
            self._exited = (code, silent_s)
            self._cond.notify_all()
