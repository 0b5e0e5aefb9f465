"""The compute stage's ray queues (``shaders/common/ray_queue.glsl``): rays traced where the
work is, not where the rasteriser's pixel grid puts it.

A mask is made in two dispatches. A generating kernel runs once per texel: ``raytrace.glsl``
with ``HS_QUEUE_GEN`` stores the answers known without a ray (background, facing away, out of
reach) and appends the other texels to the queue; ``queue_marked.glsl`` appends the pixels a
refinement or a reuse marked. The tracing kernel (``HS_QUEUE_TRACE``) is then dispatched
indirectly, with the group count the appends left on the GPU, one queued texel per invocation:
its lanes are all rays, so its time follows the rays traced, not the pixels around them. A
soft light's tracing kernel may give each queued texel several invocations (``lanes``, its
``HS_QUEUE_LANES``); the generating kernel then counts the groups by the texels a group takes.

Nothing is read back to size the work. Each queue's length is copied into a tally on the GPU;
:meth:`RayQueue.count` reads the frame's tallies once, when the stats ask. With a final
render's per-draw budget (:class:`~..tiles.DrawBudget`) the tracing kernel runs in slices of the
queue, each finished before the next, as the fragment stage's draws run in tiles.
"""
from __future__ import annotations

import struct

import moderngl
import numpy as np

#: invocations of a tracing group (``HS_QUEUE_GROUP``) and the side of a generating group
QUEUE_GROUP = 64
GEN_TILE = 8
_TALLY_SLOTS = 256  # queue lengths a frame keeps before the tally grows
_HEAD = struct.pack("4I", 0, 0, 1, 1)  # no texel queued, dispatch (0, 1, 1)
#: what a kernel's writes must be visible to before the next command: after the generating
#: kernel, the tracing kernel's storage and image accesses, the indirect dispatch's arguments and
#: the tally's copy; after the tracing kernel, whatever samples, draws into, copies or reads the
#: masks next (every kind of access)
_AFTER_GEN = (moderngl.SHADER_STORAGE_BARRIER_BIT | moderngl.COMMAND_BARRIER_BIT
              | moderngl.SHADER_IMAGE_ACCESS_BARRIER_BIT | moderngl.BUFFER_UPDATE_BARRIER_BIT)
_AFTER_TRACE = moderngl.ALL_BARRIER_BITS


class RayQueue:
    """One queue (its head, texels and the frame's tallies), reused by every mask of a
    context's ray-traced pass."""

    def __init__(self, gpu):
        self.ctx = gpu.ctx
        self.programs = gpu.programs
        self.budget = gpu.budget
        self._head = self.ctx.buffer(_HEAD)
        self._items = None
        self._tally = self.ctx.buffer(reserve=4 * _TALLY_SLOTS)
        self.counted: list = []  # (kind, key) of each tally slot of this frame
        self._counts = None  # the tallies read back, once a frame

    def begin_frame(self) -> None:
        self.counted = []
        self._counts = None

    # -- one mask ---------------------------------------------------------------------------------
    def trace(self, generate, trace, outputs, size, kind: str | None = None, key=None, lanes: int = 1,
              read: bool = False) -> None:
        """Queue and trace the texels of a ``size`` (w, h) grid: ``generate()`` binds and returns
        the generating program (one invocation per texel), ``trace()`` the tracing one (binding
        textures and uniforms only); both store into ``outputs`` (textures on image units 0, 1,
        ...; ``read``: loaded too, to add to). The tracing kernel runs ``lanes`` invocations per
        queued texel (its ``HS_QUEUE_LANES``, a divisor of QUEUE_GROUP). The queue's length is
        tallied as ``kind`` (None: not counted)."""
        if lanes < 1 or QUEUE_GROUP % lanes:
            raise ValueError(f"lanes per queued texel must divide {QUEUE_GROUP}, not {lanes}")
        w, h = (int(v) for v in size)
        self._reset(w * h)
        gen = generate()
        gen["u_queue_per_group"].value = QUEUE_GROUP // lanes
        self._bind(outputs, read)
        gen.run(-(-w // GEN_TILE), -(-h // GEN_TILE))
        self.ctx.memory_barrier(_AFTER_GEN)
        if kind is not None:
            self._tally_length(kind, key)
        self._dispatch(trace(), lanes)
        self.ctx.memory_barrier(_AFTER_TRACE)

    def trace_marked(self, marks, trace, outputs, kind: str | None, key=None, lanes: int = 1,
                     read: bool = False) -> None:
        """:meth:`trace` of the pixels ``marks`` (the refinement's depth texture: below 0.5, a
        ray) marks, queued by ``queue_marked.glsl``."""
        def generate():
            gen = self.programs.compute("queue_marked")
            marks.use(0)
            gen["u_marks"].value = 0
            return gen

        self.trace(generate, trace, outputs, marks.size, kind, key, lanes, read)

    # -- counts -----------------------------------------------------------------------------------
    def count(self, kind: str) -> int:
        """Texels queued this frame as ``kind`` (the frame's tallies are read once: a wait)."""
        if not self.counted:
            return 0
        if self._counts is None:
            n = len(self.counted)
            self._counts = np.frombuffer(self._tally.read(4 * n), np.uint32)
        return int(sum(int(c) for (k, _), c in zip(self.counted, self._counts) if k == kind))

    # -- internals --------------------------------------------------------------------------------
    def _reset(self, texels: int) -> None:
        need = 4 * max(texels, 1)
        if self._items is None or self._items.size < need:
            if self._items is not None:
                self._items.release()
            self._items = self.ctx.buffer(reserve=need)
        self._head.write(_HEAD)

    def _bind(self, outputs, read: bool) -> None:
        self._head.bind_to_storage_buffer(0)
        self._items.bind_to_storage_buffer(1)
        for unit, tex in enumerate(outputs):
            tex.bind_to_image(unit, read=read, write=True)

    def _tally_length(self, kind: str, key) -> None:
        slot = len(self.counted)
        if 4 * (slot + 1) > self._tally.size:
            grown = self.ctx.buffer(reserve=2 * self._tally.size)
            self.ctx.copy_buffer(grown, self._tally, self._tally.size)
            self._tally.release()
            self._tally = grown
        self.ctx.copy_buffer(self._tally, self._head, 4, 0, 4 * slot)
        self.counted.append((kind, key))

    def _dispatch(self, prog, lanes: int) -> None:
        """The tracing kernel over the whole queue: one indirect dispatch, or under a final
        render's budget slices of it (the length read back once: a final render waits anyway)."""
        budget = self.budget
        if "u_queue_first" in prog:
            prog["u_queue_first"].value = 0
        if budget.max_draw_ms is None:
            prog.run_indirect(self._head, offset=4)
            return
        total = int(np.frombuffer(self._head.read(4), np.uint32)[0])
        for first, n in budget.slices(total, QUEUE_GROUP):
            if "u_queue_first" in prog:
                prog["u_queue_first"].value = first
            prog.run(-(-n * lanes // QUEUE_GROUP))

    def release(self) -> None:
        for b in (self._head, self._items, self._tally):
            if b is not None:
                b.release()
        self._items = None
