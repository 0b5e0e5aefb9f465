"""The renderer process itself: one child (the same Python, ``sys.executable``, importing only
this core: :mod:`.render_server`) that owns the OpenGL context, and its channel.

The caller's threads only queue messages, which a sender thread pickles and writes to the
child's stdin, and a receiver thread reads the replies from its stdout; both wait in system
calls that release Python's lock. The child beats every :data:`~.render_server.HEARTBEAT_S`; a
child silent past :func:`deadline_s` is ended. A child that ends is reported to the owner
(:mod:`.remote`'s workers); the next message starts a new one.
"""
from __future__ import annotations

import atexit
import collections
import itertools
import json
import os
import subprocess
import sys
import threading
import time
import traceback
import weakref
from pathlib import Path

from .channel import encode_message, error_info, read_message, write_encoded
from .messages import Alive, SendError

#: how long :meth:`RendererProcess.close` waits for the child to exit before ending it
CLOSE_S = 2.0


def deadline_s() -> float:
    """How long a renderer may stay silent before it is taken for hung and ended. The child
    sends a heartbeat every :data:`~.render_server.HEARTBEAT_S` from a thread that runs whenever
    it is not inside one driver call (moderngl keeps Python's lock through each), so this bounds
    the longest single GL call (a shader compile on a software rasteriser takes seconds), not a
    stage: a long bake keeps beating. ``HYBRID_SHADOWS_DEADLINE_S`` overrides the 120 s."""
    return env_seconds("HYBRID_SHADOWS_DEADLINE_S", 120.0)


def env_seconds(name: str, default: float) -> float:
    """Seconds from environment variable ``name``; ``default`` where it is unset, not a number
    or not positive."""
    try:
        value = float(os.environ.get(name, default))
    except ValueError:
        return default
    return value if value > 0 else default


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
importlib.import_module(cfg["root"] + ".core.runtime.render_server").serve(f)
"""
_ROOT = __name__.rsplit(".core.runtime.", 1)[0]


def _package_dir() -> Path:
    return Path(__file__).resolve().parents[2]


class RendererProcess:
    """One renderer child and its channel. :meth:`post` queues a message body (any thread; the
    child starts on the first); ``on_message(msg)`` and ``on_exit(code, silent_s)`` run on the
    receiver thread (``silent_s``: how long the child had been silent when it was ended for it,
    else None). After an exit the next :meth:`post` starts a new child. A message that cannot be
    pickled comes back as a :class:`~.messages.SendError`."""

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
                self._on_message(SendError(msg[0], error_info(exc), msg[1]))
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
                if not isinstance(msg, Alive):
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


def ended(code, silent_s=None) -> str:
    """How a renderer process ended, in words."""
    if silent_s is not None:
        return f"the renderer process stopped answering for {silent_s:.0f} s and was ended"
    return f"the renderer process ended unexpectedly (exit code {code})"
