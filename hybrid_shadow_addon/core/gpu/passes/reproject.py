"""Shadow visibility reused across camera moves and scene edits (``shaders/reproject.glsl``).

Visibility of a light from a surface point does not depend on the camera. Each frame keeps its
G-buffer (world positions, normals, instances: STORE) and camera; the next frame looks each
pixel's world position up in that image (HISTORY, once a frame) and keeps what was known there
where the surface is the same (same instance, normals and position within tolerances scaled to
the pixel footprint, no grazing view), and, for a hard light's mask, where the old codes of the
4x4 samples around the point (8x8 without the refinement's group rule), all on its object, hold
no shadow edge and those samples are no sparser than this frame's pixels (MARK: a hard light's
trace writes, besides its mask, a code per pixel: lit or shadowed, known without a ray, and the
spacing of the samples the value stands on). The other pixels (disoccluded, at an edge,
grazing, zoomed into) are marked for the trace under the refinement's depth test; the mark
counts the pixels it settles, so a reused light costs two full-screen passes, the mark and the
trace of the marked pixels. :class:`ReuseChoice` times both ways per light and reuses where that
is cheaper.

Edits invalidate only what they can touch: :meth:`MaskReprojection.invalidate` takes the old and
new bounds of edited objects; a pixel whose shadow segment (a soft light's cone: the segment to
its centre, the boxes widened by its extent) can meet one gives up its history.
"""
from __future__ import annotations

from contextlib import nullcontext

import moderngl
import numpy as np

from ...scene.lights import shadow_key
from ..targets import TargetCache, draw_fullscreen, set_uniforms
from .base import Pass

MAX_BOXES = 32  # HS_MAX_BOXES of shaders/reproject.glsl: more edited boxes forget everything


def light_key(light, settings) -> tuple:
    """What a light's mask depends on besides the scene and the surface point (a change of any
    of it starts that light over)."""
    return shadow_key(light) + (float(settings.max_distance), bool(settings.hard))


def light_pad(light, soft) -> tuple:
    """``(absolute, per metre)`` widening of edited boxes that covers a soft light's cone around
    the segment to its centre (0, 0 for a hard light)."""
    if soft is None:
        return 0.0, 0.0
    if light.type == "SUN":
        return 0.0, float(np.tan(min(float(light.angle), 3.0) / 2.0))
    return float(max(light.radius, light.size, light.size_y, 0.0)), 0.0


class ReuseChoice:
    """Per hard light, whether reusing its history pays here: on a renderer whose full-screen
    passes cost about as much as cheap rays (a software rasteriser tracing a light grid), marking
    the history costs more than the rays it saves; where rays are dear (the tree, big scenes),
    it pays. Both ways are timed (the GPU's work, waited for; one frame in :attr:`EVERY`; a
    way's first timing, which holds its shaders' compiles, is left out), and so are the passes
    that serve all reusing lights of a frame (the previous pixels, the stored G-buffer). The
    lights timed cheaper reusing (by :attr:`MARGIN`) reuse when together they save more than
    those passes cost; the other way is tried again every :attr:`PROBE` frames, as the view,
    the scene and the light grids change what each costs. ``auto`` False: always reuse (tests,
    benchmarks, animation renders)."""

    PROBE = 16
    EVERY = 4
    MARGIN = 0.85  # reuse must be timed this much cheaper: what the timings leave out (the work on the CPU)
    ALPHA = 0.5  # weight of the newest timing in each running mean

    def __init__(self):
        self.auto = True
        self._lights: dict = {}  # light index -> dict(key, ms={"reuse", "plain"}, since, probe, warm)
        self.shared = None  # ms a frame of the passes all reusing lights share
        self._shared_warm = False
        self._reusing = None  # this frame's lights that reuse (None: not decided yet)

    def reset(self) -> None:
        self._lights.clear()
        self._reusing = None

    def forget(self, index: int) -> None:
        self._lights.pop(index, None)
        self._reusing = None

    def begin_frame(self) -> None:
        self._reusing = None

    def way(self, index: int, key) -> str:
        """``reuse`` (use the history where it stands, else trace with codes so the next frame
        can) or ``plain`` (a plain full trace, no history kept) for light ``index`` this frame
        (called once a frame per light)."""
        if not self.auto:
            return "reuse"
        s = self._lights.get(index)
        if s is None or s["key"] != key:
            s = self._lights[index] = dict(key=key, ms={"reuse": None, "plain": None}, since=0, probe=None,
                                           warm=set())
            self._reusing = None
        s["since"] += 1
        ms = s["ms"]
        if s["probe"] is not None:
            return s["probe"]
        if ms["reuse"] is None:
            return "reuse"
        if ms["plain"] is None:
            return "plain"
        best = "reuse" if index in self.reusing() else "plain"
        if s["since"] >= self.PROBE:
            s["probe"] = "plain" if best == "reuse" else "reuse"
            return s["probe"]
        return best

    def reusing(self) -> set:
        """The lights timed cheaper reusing, if together they save more than the shared passes
        cost (else none)."""
        if self._reusing is None:
            timed = {i: s["ms"] for i, s in self._lights.items() if None not in s["ms"].values()}
            cheaper = {i for i, ms in timed.items() if ms["reuse"] <= self.MARGIN * ms["plain"]}
            saving = sum(timed[i]["plain"] - timed[i]["reuse"] for i in cheaper)
            self._reusing = cheaper if saving > (self.shared or 0.0) else set()
        return self._reusing

    def wants_time(self, index: int, way: str) -> bool:
        """Whether to time light ``index``'s ``way`` this frame."""
        s = self._lights.get(index)
        return s is not None and (s["ms"][way] is None or s["probe"] == way or s["since"] % self.EVERY == 0)

    def note(self, index: int, way: str, ms: float) -> None:
        """Light ``index`` took ``ms`` the ``way`` of :meth:`way` (``reuse``: with a usable
        history, the shared passes apart; a frame that primed the history is not noted)."""
        s = self._lights.get(index)
        if s is None:
            return
        if way not in s["warm"]:  # (a way's first timing holds its shaders' compiles)
            s["warm"].add(way)
            return
        old = s["ms"][way]
        s["ms"][way] = ms if old is None else old + self.ALPHA * (ms - old)
        if s["probe"] == way:
            s["probe"] = None
            s["since"] = 0

    def note_shared(self, ms: float) -> None:
        """A frame's shared passes took ``ms`` (the first timing, with the compiles, left out)."""
        if not self._shared_warm:
            self._shared_warm = True
            return
        self.shared = ms if self.shared is None else self.shared + self.ALPHA * (ms - self.shared)


class MaskReprojection(Pass):
    """One view's history for reuse: the last frame's packed G-buffer and camera, and each
    light's last mask (hard: mask and codes; soft: the accumulated sums) in ping-pong
    targets. ``rules``: :attr:`RULES` (see ``shaders/reproject.glsl``; ``sums_keep``: the share
    of a soft light's sums a move carries over; ``refresh``: one 4x2 block in that many traces
    again each moving frame, so a wrongly reused value does not last)."""

    RULES = dict(pos_tol=0.25, normal_cos=0.99, view_cos=0.2, spacing_ratio=1.5, same_instance=True,
                 sums_keep=1.0, refresh=8)

    def __init__(self, gpu, refiner, **rules):
        super().__init__(gpu)
        self.refiner = refiner
        self.rules = {**self.RULES, **rules}
        self.enabled = True
        self._targets = TargetCache(self.ctx, fill=1.0, what="reprojection target")
        self._prev = None  # (CameraUniforms, size, frame id) of the stored G-buffer
        self._frame = 0
        self._lights: dict = {}  # (light, kind) -> (ping-pong index, key, frame id of its targets)
        self._touched: dict = {}  # the same for this frame's lights
        self._boxes: list = []  # (min, max) bake-space boxes edited since the stored frame
        self.reused_lights = 0  # lights of the last frame that drew on their history
        self._history_drawn = False  # whether this frame's HISTORY map is drawn
        self._fbos: dict = {}  # ids of textures -> (textures, framebuffer)
        self.choice = ReuseChoice()
        self._shared_ms = None  # the timed HISTORY draw's ms (GpuClock: maybe a frame later)
        self._history_timed = False  # this frame's HISTORY draw is timed (then so is the store)
        # (light index, way, ms) timed (GpuClock: this frame's, or the last one's in a frame
        # that defers), noted at the end of the frame
        self._timed: list = []
        self.exact = False  # this frame's hard lights trace whole (Pipeline.retrace_once)
        self.plain_lights = 0  # lights of the last frame traced plainly by the choice
        # the trace of the retraced pixels alone timed (what reusing costs at least: benchmarks)
        self.time_retrace = False
        self.retrace_ms = 0.0  # that time, the last frame's lights together

    def reset_history(self) -> None:
        """Forget everything (``Pipeline.reset_history``)."""
        self._prev = None
        self._lights.clear()
        self._boxes = []
        self.choice.reset()

    def reset_light(self, index: int) -> None:
        """Forget one light's history."""
        for k in [k for k in self._lights if k[0] == index]:
            del self._lights[k]
        self.choice.forget(index)

    def codes(self, index: int) -> np.ndarray:
        """Hard light ``index``'s codes of the last frame (``reproject.glsl``): (H, W) float32,
        row 0 the top row (tests)."""
        cur = self._lights[(index, "hard")][0]
        t = self._targets.get((index, "hard", "code", cur), *self._prev[1], components=1).texture
        w, h = t.size
        return np.frombuffer(t.read(), np.float32).reshape(h, w)[::-1]

    def invalidate(self, boxes) -> None:
        """Objects whose old or new bounds are ``boxes`` ((n, 2, 3) bake space) changed: the
        next frame's pixels whose shadow segments can meet one trace again."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 2, 3)
        if len(self._boxes) + len(boxes) > MAX_BOXES:
            self.reset_history()
            return
        self._boxes.extend((b[0], b[1]) for b in boxes)

    # -- per frame --------------------------------------------------------------------------------
    def begin_frame(self) -> None:
        self.choice.begin_frame()
        self._history_timed = False
        self._touched = {}
        self._history_drawn = False
        self.reused_lights = 0
        self.plain_lights = 0
        self.retrace_ms = 0.0

    def history(self, index: int, kind: str, key, size):
        """``(previous, current)`` targets of light ``index``'s ``kind`` (``hard``: (mask,
        code) pairs, ``reproject.glsl``; ``soft``: sums), the previous None where it has no
        usable history."""
        h = self._lights.get((index, kind))
        usable = (self.enabled and h is not None and self._prev is not None and h[1] == key
                  and not (self.exact and kind == "hard")
                  and h[2] == self._prev[2] and self._prev[1] == tuple(size))
        cur = 0 if h is None else 1 - h[0]
        self._touched[(index, kind)] = (cur, key)
        comps = (1, 1) if kind == "hard" else (4,)
        names = ("mask", "code") if kind == "hard" else ("sums",)

        def pair(i):
            return tuple(self._targets.get((index, kind, name, i), *size, components=c)
                         for name, c in zip(names, comps))

        return (pair(1 - cur) if usable else None), pair(cur)

    def bind(self, prog, gbuffer, ray_uniforms: dict, pad=(0.0, 0.0)) -> int:
        """Bind the G-buffer, the stored one and the rules to ``prog``: the next free unit."""
        cam, _, _ = self._prev
        unit = gbuffer.bind(prog)
        geo, nrm = (self._targets.get(("gbuffer", name), *self._prev[1], components=4) for name in ("geo", "nrm"))
        geo.texture.use(unit)
        nrm.texture.use(unit + 1)
        r = self.rules
        set_uniforms(prog, {**ray_uniforms, "u_prev_geo": unit, "u_prev_nrm": unit + 1,
                            "u_prev_clip": cam.clip_from_rel.T.astype("f4").tobytes(),
                            "u_cam_delta": tuple(float(v) for v in gbuffer.camera.cam_pos - cam.cam_pos),
                            "u_pos_tol": float(r["pos_tol"]), "u_normal_cos": float(r["normal_cos"]),
                            "u_view_cos": float(r["view_cos"]), "u_same_instance": int(bool(r["same_instance"])),
                            "u_boxes": len(self._boxes),
                            "u_pad_abs": float(pad[0]), "u_pad_slope": float(pad[1])})
        boxes = np.zeros((MAX_BOXES, 2, 3), np.float32)
        for i, (lo, hi) in enumerate(self._boxes):
            boxes[i] = lo, hi
        for name, col in (("u_box_min", 0), ("u_box_max", 1)):
            if name in prog:
                prog[name].write(np.ascontiguousarray(boxes[:, col]).tobytes())
        return unit + 2

    def defines(self) -> dict:
        """``HS_BOXES`` where objects were edited since the stored frame (their boxes are tested)."""
        return {"HS_BOXES": 1} if self._boxes else {}

    def mark(self, key, gbuffer, defines: dict, ray_uniforms: dict, prev, now) -> None:
        """Hard light: write into ``now`` (mask, code) the history that stands and the
        background, counted (``kept``), and mark the other pixels for the trace
        (:meth:`Refiner.refine` with ``HS_CODE_OUT``, into the same targets)."""
        history = self.history_map(gbuffer, defines, ray_uniforms)
        cam = self._prev[0]
        still = (np.array_equal(cam.clip_from_rel, gbuffer.camera.clip_from_rel)
                 and np.array_equal(cam.cam_pos, gbuffer.camera.cam_pos))  # (history(): the same size)
        defs = {**defines, **self.defines()}
        defs.update(self.refiner.defines())
        if still:
            defs["HS_STILL"] = 1
        prog, vao = self.programs.fullscreen("reproject", defs)
        unit = self.bind(prog, gbuffer, ray_uniforms)
        prev[0].texture.use(unit)
        prev[1].texture.use(unit + 1)
        history.texture.use(unit + 2)
        refresh = max(1, int(self.rules["refresh"]))
        set_uniforms(prog, {"u_prev_mask": unit, "u_prev_code": unit + 1, "u_history": unit + 2,
                            "u_spacing_ratio": float(self.rules["spacing_ratio"]),
                            "u_refresh": refresh, "u_phase": self._frame % refresh})
        self.refiner.mark_kept(key, now[0], vao, "kept", extra=(now[1],))
        self.reused_lights += 1

    def history_map(self, gbuffer, defines: dict, ray_uniforms: dict, timed: bool = False):
        """This frame's previous pixel of each pixel (``reproject.glsl`` HISTORY), drawn for the
        first hard light that asks: it depends on no light (``timed``: the draw is timed, one of
        the frame's shared passes)."""
        target = self._targets.get("history", *gbuffer.size, components=4)
        if self._history_drawn:
            return target
        defs = {k: v for k, v in defines.items() if k == "HS_MAX_DISTANCE"}
        prog, vao = self.programs.fullscreen("reproject", {**defs, "HISTORY": 1})
        self.bind(prog, gbuffer, ray_uniforms)
        with self.gpu.clock.span(self._history_time) if timed else nullcontext():
            draw_fullscreen(self.ctx, vao, target)
        self._history_drawn = True
        self._history_timed = timed
        return target

    def _history_time(self, ms: float) -> None:
        self._shared_ms = ms

    def draw_fresh(self, vao, now, budget) -> None:
        """Draw the bound trace ``vao`` (``HS_CODE_OUT``) into ``now`` (mask, code) whole,
        through ``budget`` (a light without usable history)."""
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        self._mrt(now[0].texture, now[1].texture).use()
        size = now[0].texture.size
        self.ctx.viewport = (0, 0, *size)
        budget.draw(vao, size)

    def carry_sums(self, gbuffer, defines: dict, ray_uniforms: dict, pad, prev, out) -> None:
        """Soft light: ``out`` = the previous sums where the surface is the same, else 0."""
        prog, vao = self.programs.fullscreen("reproject", {**defines, **self.defines(), "SOFT": 1})
        unit = self.bind(prog, gbuffer, ray_uniforms, pad)
        prev.texture.use(unit)
        set_uniforms(prog, {"u_prev_sums": unit, "u_keep": float(self.rules["sums_keep"])})
        draw_fullscreen(self.ctx, vao, out)

    def timed(self, index: int, way: str, ms: float) -> None:
        """Light ``index`` took ``ms`` this frame the ``way`` :attr:`choice` gave."""
        self._timed.append((index, way, ms))

    def end_frame(self, gbuffer) -> None:
        """Keep this frame's G-buffer and camera, and the history of the lights it drew; note
        the frame's timings (the store with the previous pixels, where those were timed)."""
        with self.gpu.clock.span(self._store_time) if self._history_timed else nullcontext():
            self._store(gbuffer)
        for li, way, ms in self._timed:
            self.choice.note(li, way, ms)
        self._timed = []

    def _store_time(self, ms: float) -> None:
        self.choice.note_shared(self._shared_ms + ms)

    def _store(self, gbuffer) -> None:
        if not self._touched:
            return
        self._frame += 1
        size = gbuffer.size
        geo, nrm = (self._targets.get(("gbuffer", name), *size, components=4) for name in ("geo", "nrm"))
        fb = self._mrt(geo.texture, nrm.texture)
        prog, vao = self.programs.fullscreen("reproject", {"STORE": 1})
        gbuffer.bind(prog)
        fb.use()
        self.ctx.viewport = (0, 0, *size)
        vao.render(vertices=3)
        self._prev = (gbuffer.camera, tuple(size), self._frame)
        for k, (cur, key) in self._touched.items():
            self._lights[k] = (cur, key, self._frame)
        for k in [k for k in self._lights if self._lights[k][2] != self._frame]:
            del self._lights[k]
        self._boxes = []

    def _mrt(self, *textures):
        """A framebuffer of ``textures`` (kept; those of another size are given back)."""
        key = tuple(id(t) for t in textures)
        hit = self._fbos.get(key)
        if hit is not None and all(a is b for a, b in zip(hit[0], textures)):
            return hit[1]
        for k in [k for k, (texs, _) in self._fbos.items() if k == key or texs[0].size != textures[0].size]:
            self._fbos.pop(k)[1].release()
        fb = self.ctx.framebuffer(color_attachments=list(textures))
        self._fbos[key] = (textures, fb)
        return fb

    def release(self) -> None:
        for _, fb in self._fbos.values():
            fb.release()
        self._fbos.clear()
        self._targets.release()


def instance_boxes(scene, indices=None) -> np.ndarray:
    """(n, 2, 3) float64 world boxes (min, max) of instances ``indices`` (None: all)."""
    inst = scene.instances
    idx = np.arange(len(inst)) if indices is None else np.asarray(indices, np.int64).reshape(-1)
    if not len(idx):
        return np.zeros((0, 2, 3))
    mids = inst.model_ids[idx]
    bmin = np.array([m.bounds_min for m in scene.models], np.float64).reshape(-1, 3)[mids]
    bmax = np.array([m.bounds_max for m in scene.models], np.float64).reshape(-1, 3)[mids]
    mats = inst.matrices[idx]
    c = np.einsum("nij,nj->ni", mats[:, :3, :3], (bmin + bmax) * 0.5) + mats[:, :3, 3]
    h = np.einsum("nij,nj->ni", np.abs(mats[:, :3, :3]), (bmax - bmin) * 0.5)
    return np.stack([c - h, c + h], axis=1)


def merged_boxes(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The boxes an edit invalidates: ``old`` and ``new`` (each (n, 2, 3)), or where they are
    more than a quarter of MAX_BOXES, each side's union (coarser, never smaller)."""
    parts = []
    for b in (old, new):
        if len(b) > MAX_BOXES // 4:
            b = np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])[None]
        parts.append(b)
    return np.concatenate(parts).reshape(-1, 2, 3)
