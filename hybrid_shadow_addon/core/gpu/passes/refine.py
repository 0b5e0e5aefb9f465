"""Refinement of coarse shadow rays (``Settings.quality`` medium/low, and interlaced frames).

A coarse set of rays (every 2nd or 4th pixel, or this frame's interlaced phase) is classified
per full-resolution pixel: ``shaders/refine_geometry.glsl`` (once per frame: which surrounding
samples lie on the pixel's surface; none where the camera sees it at a grazing angle, ``RULES``
``view_cos``), ``shaders/refine_cells.glsl`` (per light, at the coarse
resolution: do the samples around a cell agree) and ``shaders/refine_classify.glsl`` (per light:
the coarse answer, or a mark that the pixel needs its own ray, which is exactly the ray ``high``
traces for it; with the ``group`` rule, on llvmpipe, so does every pixel of a SIMD group that
holds such a pixel, unless it is known without a ray: the trace under the depth test pays the
group its slowest lane anyway). The marks go to a depth buffer (0: ray, 1: done), and the
full-resolution trace then runs under the depth test (window depth 0.5, depth function ``>``,
no depth writes), so unmarked pixels are rejected before shading (early depth test). Occlusion
queries count the pixels with geometry and the rays traced, without reading masks.

On the compute path the marked pixels are queued instead and traced with full lanes
(:meth:`Refiner.trace_marked`, :mod:`.queue`). The rules, ``group`` too, decide which pixels
get a ray on either path, so both give the same masks on one renderer.
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..targets import TargetCache, set_uniforms

#: the ways to trace the marked pixels (``RaytraceOptions.refine_method``)
METHODS = ("depth",)


def check_method(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`, else a ValueError that names them."""
    if method not in METHODS:
        raise ValueError(f"refinement method must be one of {', '.join(METHODS)}, not {method!r}")
    return method


class Refiner:
    """Classify and refine draws for the ray-traced pass, and their ray counts."""

    #: default refinement rules (see the shaders named in the module docstring); ``group``
    #: None: :meth:`group_default` for the context
    RULES = dict(plane_tol=0.02, normal_cos=0.9, grazing=0.05, ring=1, view_cos=0.5, group=None)

    def __init__(self, gpu, **rules):
        unknown = sorted(set(rules) - set(self.RULES))
        if unknown:
            raise ValueError(f"unknown refinement rule(s) {', '.join(unknown)}; the rules are {', '.join(self.RULES)}")
        self.ctx = gpu.ctx
        self.programs = gpu.programs
        self.budget = gpu.budget
        self.rules = {**self.RULES, **rules}
        self.can_vote = "GL_ARB_shader_group_vote" in self.ctx.extensions
        self.queue = None  # the compute path's RayQueue (its queues count too)
        if self.rules["group"] is None:
            self.rules["group"] = self.group_default(self.ctx)
        self.defines()  # (checks the rules: group needs the vote)
        self._work = TargetCache(self.ctx, what="refinement target")  # role -> target
        self._depth = None
        self._fbos: dict = {}  # key -> (attachments, framebuffer with the depth buffer)
        self._grid: dict = {}
        self._pool: list = []  # occlusion queries, reused
        self._used = 0
        self.counted: list = []  # (kind, key, query) of the last frame

    # -- queries ------------------------------------------------------------------------------
    def begin_frame(self) -> None:
        self._used = 0
        self.counted = []

    def _query(self, kind: str, key):
        if self._used == len(self._pool):
            self._pool.append(self.ctx.query(samples=True))
        q = self._pool[self._used]
        self._used += 1
        self.counted.append((kind, key, q))
        return q

    def count(self, kind: str) -> int:
        """Samples passed by the last frame's draws of ``kind``, and texels queued as ``kind`` by
        its compute traces (waits for the GPU)."""
        queued = self.queue.count(kind) if self.queue is not None else 0
        return int(sum(q.samples for k, _, q in self.counted if k == kind)) + queued

    def count_valid(self, gbuffer, size, scale: int, kind: str, offset=None) -> None:
        """Count the texels of a ``size`` grid whose source pixel (texel q: ``q * scale + offset``,
        ``offset`` ``scale // 2`` by default, as ``mask_source_pixel``) has geometry."""
        prog, vao = self.programs.fullscreen("ray_count")
        gbuffer.bind(prog)
        off = (scale // 2, scale // 2) if offset is None else tuple(int(v) for v in offset)
        set_uniforms(prog, {"u_scale": int(scale), "u_offset": off, "u_full_size": gbuffer.size})
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self._work.get("count", *size).use(self.ctx)
        with self._query(kind, None):
            vao.render(moderngl.TRIANGLES, vertices=3)

    # -- per frame ----------------------------------------------------------------------------
    def prepare(self, gbuffer, scale: int, offset, interlace: bool, geometry: bool = True) -> None:
        """Once per frame: the grid of coarse samples (spacing ``scale``, sample (0, 0) at pixel
        ``offset``; ``interlace``: samples read from the full-resolution interlaced trace) and
        which samples can stand for each pixel (``shaders/refine_geometry.glsl``; not drawn
        when ``geometry`` is False: a frame that classifies nothing)."""
        ox, oy = (int(v) for v in offset)
        w, h = gbuffer.size
        if interlace:
            cells = (max(1, -(-(w - ox) // scale)), max(1, -(-(h - oy) // scale)))
        else:
            cells = (max(1, -(-w // scale)), max(1, -(-h // scale)))
        self._grid = dict(scale=int(scale), offset=(ox, oy), interlace=bool(interlace), cells=cells)
        if not geometry:
            return
        prog, vao = self.programs.fullscreen("refine_geometry", self._grid_defines())
        unit = gbuffer.bind(prog)
        set_uniforms(prog, {**self._grid_uniforms(gbuffer), "u_plane_tol": float(self.rules["plane_tol"]),
                            "u_normal_cos": float(self.rules["normal_cos"]),
                            "u_view_cos": float(self.rules["view_cos"])})
        if not interlace:  # (sample_grid() reads the coarse mask's size: a texture of that size)
            self._work.get("cells", *cells).texture.use(unit)
            set_uniforms(prog, {"u_coarse": unit})
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self._work.get("geometry", w, h).use(self.ctx)
        vao.render(moderngl.TRIANGLES, vertices=3)

    def _grid_defines(self) -> dict:
        return {"HS_INTERLACE": 1} if self._grid["interlace"] else {}

    def _grid_uniforms(self, gbuffer) -> dict:
        g = self._grid
        return {"u_scale": g["scale"], "u_offset": g["offset"], "u_full_size": gbuffer.size}

    @staticmethod
    def group_default(ctx) -> bool:
        """The ``group`` rule's default: on where the renderer is Mesa's llvmpipe with
        ``GL_ARB_shader_group_vote``. There a fragment shader runs a fixed 4x2 block of pixels
        in lock-step, the same block in the classify and the trace draws, and the trace under
        the depth test costs each block its slowest marked lane: the block's other rays are
        traced at no extra cost (``BENCHMARKS.md``, "A marked pixel's SIMD group traces
        whole"). On a GPU the early depth test packs the surviving pixels into the trace's
        groups, so the extra rays would cost; off there. The compute path keeps the rule where it
        is on (its extra rays then cost there too), so both paths give one renderer the same
        masks."""
        return ("GL_ARB_shader_group_vote" in ctx.extensions
                and "llvmpipe" in str(ctx.info.get("GL_RENDERER", "")).lower())

    def defines(self) -> dict:
        """Extra defines of the classify program for these rules."""
        out = {}
        if self.rules["group"]:
            if not self.can_vote:
                raise ValueError("the refinement rule group needs GL_ARB_shader_group_vote, which this "
                                 f"renderer ({self.ctx.info.get('GL_RENDERER', '?')}) does not offer")
            out["HS_GROUP_VOTE"] = 1
        return out

    # -- per light ----------------------------------------------------------------------------
    def classify(self, key, target, gbuffer, coarse, defines: dict, uniforms: dict) -> None:
        """Write the coarse answers into ``target`` (full resolution) and mark the pixels that
        need their own ray. ``coarse``: the coarse mask (or, with ``HS_INTERLACE`` in
        ``defines``, this frame's interlaced full-resolution trace); ``uniforms``: the light's."""
        ctx = self.ctx
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        cprog, cvao = self.programs.fullscreen("refine_cells", self._grid_defines())
        coarse.use(0)
        set_uniforms(cprog, {**self._grid_uniforms(gbuffer), "u_coarse": 0, "u_ring": int(self.rules["ring"])})
        cells = self._work.get("cells", *self._grid["cells"])
        cells.use(ctx)
        cvao.render(moderngl.TRIANGLES, vertices=3)
        prog, vao = self.programs.fullscreen("refine_classify", defines)
        unit = gbuffer.bind(prog)
        coarse.use(unit)
        cells.texture.use(unit + 1)
        self._work.get("geometry", *gbuffer.size).texture.use(unit + 2)
        set_uniforms(prog, {**uniforms, **self._grid_uniforms(gbuffer), "u_coarse": unit, "u_cells": unit + 1,
                            "u_geometry": unit + 2, "u_grazing": float(self.rules["grazing"])})
        self._draw_marks(self._fbo(key, target), target, vao)

    def marked(self) -> np.ndarray:
        """The pixels the last :meth:`classify` (or :meth:`mark`) marked for a ray: (H, W) bool,
        row 0 the top row (read from the depth buffer, which the refine draws do not write)."""
        if self._depth is None:
            raise ValueError("nothing was classified")
        w, h = self._depth.size
        d = np.frombuffer(self._depth.read(), np.float32).reshape(h, w)[::-1]
        return d < 0.5

    def refine(self, key, target, vao, kind: str = "refined", extra=()) -> None:
        """Draw the (already set up) full-resolution trace ``vao`` into ``target`` (and
        ``extra``, targets of its further outputs) where :meth:`classify` (or :meth:`mark`)
        marked pixels, counted as ``kind``."""
        fbo = self._fbo(key, target, extra)
        with self._masked(fbo, target):
            with self._query(kind, key):
                self.budget.draw(vao, target.texture.size)

    def trace_marked(self, key, target, trace, kind: str | None = "refined", extra=(), lanes: int = 1,
                     read: bool = False) -> None:
        """:meth:`refine` on the compute path: the marked pixels queued and traced by the
        program ``trace()`` binds and returns (``raytrace.glsl``'s tracing kernel) into
        ``target`` (and ``extra``), counted as ``kind`` (None: not counted); ``lanes`` and
        ``read`` as :meth:`.queue.RayQueue.trace` takes them."""
        self._fbo(key, target, extra)  # (the depth buffer of target's size)
        self.queue.trace_marked(self._depth, trace, [target.texture, *(t.texture for t in extra)], kind, key,
                                lanes, read)

    def mark(self, key, target, vao, color: bool = True, extra=()) -> None:
        """Draw ``vao``, a full-screen program that writes its answers and marks (``gl_FragDepth``
        0: the next :meth:`draw_marked` shades the pixel, 1: done), into ``target`` (``color``
        False: the marks alone, ``target`` kept; ``extra``: targets of its further outputs)."""
        self.ctx.disable(moderngl.BLEND)
        fbo = self._fbo(key, target, extra)
        n = 1 + len(extra)
        fbo.color_mask = ((color,) * 4,) * n if n > 1 else (color,) * 4
        try:
            self._draw_marks(fbo, target, vao)
        finally:
            fbo.color_mask = ((True,) * 4,) * n if n > 1 else (True,) * 4

    def mark_kept(self, key, target, vao, kind: str, extra=()) -> None:
        """Draw ``vao``, a full-screen program that writes the pixels it settles and discards
        the others, into ``target`` (``extra``: targets of its further outputs): the discarded
        pixels are marked for the next :meth:`refine`, the settled ones counted as ``kind``."""
        self.ctx.disable(moderngl.BLEND)
        fbo = self._fbo(key, target, extra)
        fbo.use()
        fbo.clear(depth=0.0)  # (every pixel marked; the draw's own depth, 0.5, settles one)
        with self._query(kind, key):
            self._draw_marks(fbo, target, vao)

    def _draw_marks(self, fbo, target, vao) -> None:
        """A full-screen draw into ``fbo`` (``target``'s) that writes the depth marks."""
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "1"
        fbo.depth_mask = True
        fbo.use()
        ctx.viewport = (0, 0, *target.texture.size)
        vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.DEPTH_TEST)

    def draw_marked(self, key, target, vao, add: bool = False) -> None:
        """Draw the full-screen ``vao`` into ``target`` only where :meth:`mark` marked pixels
        (early depth test: the others are not shaded); ``add``: added to what is there."""
        fbo = self._fbo(key, target)
        with self._masked(fbo, target):
            if add:
                self.ctx.enable(moderngl.BLEND)
                self.ctx.blend_func = moderngl.ONE, moderngl.ONE
            self.budget.draw(vao, target.texture.size)
            self.ctx.disable(moderngl.BLEND)

    # -- depth-masked targets -----------------------------------------------------------------
    class _Masked:
        def __init__(self, ctx, fbo, target):
            self.ctx, self.fbo, self.target = ctx, fbo, target

        def __enter__(self):
            self.ctx.disable(moderngl.BLEND)
            self.ctx.enable(moderngl.DEPTH_TEST)
            self.ctx.depth_func = ">"
            self.fbo.depth_mask = False
            self.fbo.use()
            self.ctx.viewport = (0, 0, *self.target.texture.size)

        def __exit__(self, *exc):
            self.ctx.disable(moderngl.DEPTH_TEST)
            self.ctx.depth_func = "<"

    def _masked(self, fbo, target):
        return self._Masked(self.ctx, fbo, target)

    def _fbo(self, key, target, extra=()):
        size = target.texture.size
        if self._depth is None or self._depth.size != size:
            self._release_fbos()
            if self._depth is not None:
                self._depth.release()
            self._depth = self.ctx.depth_texture(size)
            self._depth.compare_func = ""  # (the compute path reads the marks themselves)
        colors = [target.texture, *(t.texture for t in extra)]
        hit = self._fbos.get(key)
        if hit is None or len(hit[0]) != len(colors) or any(a is not b for a, b in zip(hit[0], colors)):
            if hit is not None:
                hit[1].release()
            hit = self._fbos[key] = (colors, self.ctx.framebuffer(color_attachments=colors,
                                                                depth_attachment=self._depth))
        return hit[1]

    # -- release ------------------------------------------------------------------------------
    def _release_fbos(self) -> None:
        for _, fbo in self._fbos.values():
            fbo.release()
        self._fbos.clear()

    def release(self) -> None:
        self._release_fbos()
        self._work.release()
        if self._depth is not None:
            self._depth.release()
            self._depth = None
        self._pool.clear()
