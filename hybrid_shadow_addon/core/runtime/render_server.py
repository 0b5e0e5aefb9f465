"""The renderer process's side (:mod:`.remote` starts it): it owns the OpenGL context.

:func:`serve` reads messages ``(seq, message)`` (:mod:`.messages`) on one thread (a
:class:`~.messages.Cancel` takes effect at once) and runs them in order on the main thread, each
through :attr:`Server.handlers`:

- the viewport's scene commands and frames (``Bake``, ``MoveInstances``, ``UpdateModel``,
  ``ResetHistory``, ``ResetLight``, ``ViewScene``, ``RenderView``, ``DropView``) go to a
  synchronous :class:`~.worker.RenderWorker`, pumped one render step at a time while messages
  keep arriving; each finished frame goes back as a ``ViewFrame`` with its image already in the
  display's layout (:func:`encode_image`);
- ``FinalFrame`` renders one final frame (:class:`FinalJobs`): bake or persistent-data update,
  render, every array the render passes need back in one ``JobDone`` reply, then the frame's
  targets are released (and, without persistent data, the bake); ``Call`` runs a generator
  function of the package (Compare's measurements), its labels sent as ``Progress``;
- after each round a ``ServerState`` tells the caller which messages were applied and which
  views still have work.
"""
from __future__ import annotations

import collections
import dataclasses
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from ..errors import Cancelled
from ..gpu import memory
from .channel import RendererError, error_info, read_message, write_message
from .messages import (
    Alive,
    Bake,
    Call,
    Cancel,
    Close,
    DropView,
    FinalFrame,
    JobDone,
    MoveInstances,
    Progress,
    RenderView,
    ResetHistory,
    ResetLight,
    ServerState,
    UpdateModel,
    ViewFrame,
    ViewScene,
)

MB = float(1 << 20)
#: the renderer's scheduling priority below the caller's (POSIX): on a software rasteriser its
#: threads take every core, and the interface's threads must still be woken on time
NICE = 15
#: seconds between the heartbeats the process sends its caller
HEARTBEAT_S = 0.5


def encode_image(image: np.ndarray) -> np.ndarray:
    """A frame (float32 (H, W, 4), row 0 = top) as it crosses to the display: rows bottom-up
    (GL's order), half floats (what the display shows; half the bytes of float32)."""
    return np.clip(image[::-1], -65504.0, 65504.0).astype(np.float16)


@dataclass
class GBufferData:
    """A final frame's G-buffer as read back: what ``GBuffer.read`` and ``coverage`` give,
    without GL objects."""

    buffers: dict = field(default_factory=dict)  # target name -> array (row 0 = top)
    coverage_mask: np.ndarray = None

    def coverage(self) -> np.ndarray:
        return self.coverage_mask

    def read(self, name: str) -> np.ndarray:
        return self.buffers[name]


@dataclass
class FinalFrameData:
    """A final frame's arrays (row 0 = top), read back in the renderer process: what ``Frame``
    and its masks give, without GL objects; its G-buffer is :attr:`gbuffer`."""

    image: np.ndarray
    lights: list
    timings: dict
    stats: dict
    gbuffer: GBufferData
    masks: dict = field(default_factory=dict)  # light index -> float32 (H, W), NaN off geometry

    @property
    def buffers(self) -> dict:
        return self.gbuffer.buffers

    def mask_array(self, light_index: int) -> np.ndarray:
        return self.masks[light_index].copy()


def frame_data(frame, want=("depth", "shading_normal", "albedo"), masks: bool = True) -> FinalFrameData:
    """Read a rendered ``Frame``'s image, coverage, the G-buffer targets ``want`` and (``masks``)
    every light's mask into a :class:`FinalFrameData`."""
    gb = frame.gbuffer
    return FinalFrameData(image=frame.image, lights=list(frame.lights), timings=dict(frame.timings),
                          stats=dict(frame.stats),
                          gbuffer=GBufferData({name: gb.read(name) for name in want}, gb.coverage()),
                          masks={li: frame.mask_array(li) for li in frame.lights} if masks else {})


class FinalJobs:
    """Final frames in this process: one pipeline (programs stay compiled between frames) and,
    with persistent data, the last scene its bake holds."""

    def __init__(self, send, cancel: threading.Event):
        self.send = send
        self.cancel = cancel
        self.pipe = None
        self.state: dict = {}

    def run(self, msg: FinalFrame) -> None:
        """Render and reply a :class:`~.messages.JobDone` (its value a :class:`FinalFrameData`)."""
        job, scene, settings, options = msg.job, msg.scene, msg.settings, msg.options
        from ..gpu.pipeline import Pipeline

        def progress(done, total, label=""):
            if self.cancel.is_set():
                raise Cancelled()
            self.send(Progress(job, done, total, label))

        try:
            if self.pipe is None:
                self.pipe = Pipeline()
            pipe = self.pipe
            # (an animation with persistent data may reuse hard masks from frame to frame: every
            # light, whatever it costs, so the frames are the same on any machine)
            keep = bool(options.get("reuse")) and options.get("persistent_key") is not None
            pipe.reuse, pipe.reuse_choice = keep, "always"
            ledger = memory.track(pipe.ctx)
            before = ledger.bytes
            ledger.reset_peak()
            progress(0, 1, "Baking")
            t0 = time.perf_counter()
            kind, updates = self._bake(pipe, scene, settings, options.get("persistent_key"))
            bake_ms = (time.perf_counter() - t0) * 1e3
            kwargs = {"max_draw_ms": options["max_draw_ms"]} if options.get("max_draw_ms") else {}
            frame = pipe.render(scene, settings, msg.width, msg.height,
                                film_transparent=options.get("film_transparent", False), progress=progress, **kwargs)
            data = frame_data(frame, options.get("want", ()), options.get("masks", True))
            data.stats.update(bake=kind, bake_ms=bake_ms, bake_updates=updates,
                              gpu_memory_before_mb=round(before / MB, 1),
                              gpu_peak_mb=round(ledger.peak / MB, 1))
            self._free(pipe, keep_bake=options.get("persistent_key") is not None, keep_history=keep)
            memory.collect(pipe.ctx)
            memory.trim_heap()
            driver = memory.driver_memory(pipe.ctx)
            data.stats.update(gpu_memory_after_mb=round(ledger.bytes / MB, 1), gpu_dropped=len(ledger.dropped),
                              process_rss_mb=memory.process_rss_mb(),
                              gpu_driver_used_mb=None if driver is None else driver.get("used_mb"))
            self.send(JobDone(job, data, None))
            del data, frame
            memory.trim_heap()
        except BaseException as exc:  # noqa: BLE001 - the caller gets every failure
            if self.pipe is not None:
                try:
                    self._free(self.pipe, keep_bake=False)
                except Exception:
                    pass
            self.state.clear()
            self.send(JobDone(job, None, error_info(exc)))
            if not isinstance(exc, Exception):
                raise

    def _bake(self, pipe, scene, settings, key) -> tuple:
        """``(kind, updates)``: how the bake was made ready for ``scene`` (``scene_sync``'s
        kinds) and, for an update, ``{"instances", "models", "reason"}``."""
        from ..scene_sync import FULL, NONE, sync_scene

        raytrace = settings.mode == "raytrace"
        if key is None:
            self.state.clear()
            if not raytrace:
                return NONE, {"instances": 0, "models": 0, "reason": "no ray tracing"}
            pipe.set_scene(scene, settings.structure)
            return FULL, {"instances": 0, "models": 0, "reason": "no persistent data"}
        prev = self.state.get("scene") if self.state.get("key") == key else None
        self.state.clear()  # (until the update below succeeded)
        sync = sync_scene(pipe, prev, scene, bake=raytrace, structure=settings.structure)
        self.state.update(key=key, scene=scene)
        return sync.kind, {"instances": len(sync.moved), "models": len(sync.models), "reason": sync.reason}

    @staticmethod
    def _free(pipe, keep_bake: bool, keep_history: bool = False) -> None:
        """Give back the frame's targets (every pass's but, ``keep_history``, the ray-traced
        pass's), and the bake unless it is kept."""
        pipe.release_targets(keep_history)
        if not keep_bake:
            pipe.drop_bake()

    def close(self) -> None:
        if self.pipe is not None:
            try:
                self.pipe.release()
                self.pipe.ctx.release()
            except Exception:
                pass
            self.pipe = None


class Server:
    """The message loop of the renderer process (see the module docstring)."""

    def __init__(self, out, send_lock=None):
        self.out = out
        self.send_lock = send_lock or threading.Lock()
        self.cond = threading.Condition()
        self.inbox: collections.deque = collections.deque()
        self.cancel = threading.Event()
        self.acked = 0
        self.worker = None
        self.views: set = set()  # views with render requests
        self.scenes: dict = {}  # token -> scene (without a camera) of render requests
        self.seqs: dict = {}  # the worker's request numbers -> the caller's
        self.final = FinalJobs(self.send, self.cancel)
        #: what each message does (its class -> handler); a message of no class here is a bug
        self.handlers = {
            Cancel: lambda msg: None,  # (it stopped what was running; nothing queued is cancelled)
            FinalFrame: lambda msg: self._job(self.final.run, msg),
            Call: lambda msg: self._job(self.call, msg),
            Bake: lambda msg: self._viewport().set_scene(msg.scene, msg.structure),
            MoveInstances: lambda msg: self._viewport().move_instances(msg.scene, msg.indices),
            UpdateModel: lambda msg: self._viewport().update_model(msg.scene, msg.model_id),
            ResetHistory: lambda msg: self._viewport().reset_history(),
            ResetLight: lambda msg: self._viewport().reset_light(msg.index),
            ViewScene: self._view_scene,
            RenderView: self._render_view,
            DropView: self._drop_view,
        }

    def send(self, obj) -> None:
        with self.send_lock:
            write_message(self.out, obj)

    def read_loop(self, rfile) -> None:
        try:
            while True:
                seq, msg = read_message(rfile)
                if isinstance(msg, Cancel):
                    self.cancel.set()
                with self.cond:
                    self.inbox.append((seq, msg))
                    self.cond.notify_all()
        except BaseException as exc:  # noqa: BLE001 - the caller gone, or a message unreadable: end
            if not isinstance(exc, (EOFError, OSError)):
                traceback.print_exc()
            with self.cond:
                self.inbox.append((0, Close()))
                self.cond.notify_all()

    def _has_work(self) -> bool:
        return self.worker is not None and self.worker.busy()

    def run(self) -> None:
        while True:
            with self.cond:
                while not self.inbox and not self._has_work():
                    self.cond.wait()
                msgs = list(self.inbox)
                self.inbox.clear()
            for seq, msg in msgs:
                if isinstance(msg, Close):
                    return
                self.handlers[type(msg)](msg)
                self.acked = max(self.acked, seq)
            if self.worker is not None:
                self.worker.pump()
                self._send_results()
            self.send(ServerState(self.acked, {v: self.worker.busy(v) for v in self.views} if self.worker else {},
                                  self._has_work()))

    def _job(self, run, msg) -> None:
        """A final frame or a call: a cancel meant for an earlier job is forgotten first."""
        self.cancel.clear()
        run(msg)
        self.cancel.clear()

    def call(self, msg: Call) -> None:
        """Run the generator function ``msg.function`` to its end: each label it yields goes back
        as a :class:`~.messages.Progress`, its return value as the :class:`~.messages.JobDone`."""
        job = msg.job
        try:
            steps = msg.function(**msg.kwargs)
            k = 0
            while True:
                if self.cancel.is_set():
                    steps.close()
                    raise Cancelled()
                try:
                    label = next(steps)
                except StopIteration as stop:
                    self.send(JobDone(job, stop.value, None))
                    return
                k += 1
                self.send(Progress(job, k, 0, label))
        except BaseException as exc:  # noqa: BLE001 - the caller gets every failure
            self.send(JobDone(job, None, error_info(exc)))
            if not isinstance(exc, Exception):
                raise

    def _viewport(self):
        if self.worker is None:
            from .worker import RenderWorker

            self.worker = RenderWorker(synchronous=True)
        return self.worker

    def _view_scene(self, msg: ViewScene) -> None:
        self._viewport()
        self.scenes[msg.token] = msg.scene
        for old in sorted(self.scenes)[:-4]:
            del self.scenes[old]

    def _render_view(self, msg: RenderView) -> None:
        w = self._viewport()
        request = msg.request
        base = self.scenes.get(msg.token)
        if base is None:  # (its scene went to a renderer that ended: the caller sends it again)
            self.send(ViewFrame(request.view, None, [error_info(RendererError(
                "a frame came without its scene (the renderer process was restarted); the next frame sends it"))]))
            return
        request.scene = dataclasses.replace(base, camera=request.scene.camera, resolution=request.scene.resolution)
        self.seqs[w.render(request)] = msg.seq
        self.views.add(request.view)
        for old in sorted(self.seqs)[:-64]:
            del self.seqs[old]

    def _drop_view(self, msg: DropView) -> None:
        self._viewport().drop_view(msg.view)
        self.views.discard(msg.view)

    def _send_results(self) -> None:
        for view in list(self.views):
            result, errors = self.worker.poll(view)
            if result is None and not errors:
                continue
            if result is not None:
                result.seq = self.seqs.get(result.seq, 0)
                result.image = encode_image(result.image)
                ctx = self.worker.context
                result.stats["gpu_memory_mb"] = round(memory.in_use(ctx) / MB, 1) if ctx is not None else 0.0
            self.send(ViewFrame(view, result, [error_info(e) for e in errors]))

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
        self.final.close()


def _claim_stdout():
    """The channel to the caller: the process's original stdout; what anything else prints
    (Python or the driver) goes to stderr from now on."""
    sys.stdout.flush()
    fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return os.fdopen(fd, "wb")


def _heartbeat(out, lock) -> None:
    """Tell the caller every :data:`HEARTBEAT_S` that this process lives (it ends a renderer
    that stays silent past its deadline: ``renderer_process.deadline_s``); ends with the channel."""
    while True:
        time.sleep(HEARTBEAT_S)
        try:
            with lock:
                write_message(out, Alive())
        except (OSError, ValueError):
            return


def serve(rfile) -> None:
    """The renderer process's main function: messages from ``rfile`` (its stdin)."""
    out, lock = _claim_stdout(), threading.Lock()
    threading.Thread(target=_heartbeat, args=(out, lock), name="hybrid-shadows-heartbeat", daemon=True).start()
    # the modules messages name, imported in the package's own order before any message is
    # read (unpickling a Settings first would enter the bake's imports halfway)
    from ..gpu import pipeline  # noqa: F401
    from . import worker  # noqa: F401

    if hasattr(os, "nice"):  # where the rasteriser runs on the CPU, the interface comes first
        try:
            os.nice(NICE)
        except OSError:
            pass
    server = Server(out, lock)
    reader = threading.Thread(target=server.read_loop, args=(rfile,), name="hybrid-shadows-reader", daemon=True)
    reader.start()
    try:
        server.run()
    finally:
        server.close()
