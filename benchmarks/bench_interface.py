"""How long the interface waits while the engine renders: the rendered viewport driven as
Blender drives it (``view_update``, then ``view_draw`` at 60 Hz into an offscreen with a view
that orbits a little every redraw, the worker thread rendering behind it, the real
``ViewportDisplay`` upload and draw), and a final render (``bpy.ops.render.render()`` with the
engine), per scene.

Per case it prints:

- ``max_gap_ms``: the longest gap between two ticks of the interface. Viewport: the main
  thread's loop, which ticks every millisecond between redraws (its own redraw work and every
  wait for Python's lock count). Final render (it runs on the calling thread in background
  mode, on a job thread in the interface): a thread that sleeps 1 ms at a time and must get
  Python's lock to tick (``max_thread_gap_ms`` is the same thread's figure for the viewport);
- ``main_ms_per_redraw``: mean ms spent inside ``view_draw`` (null for a final render);
- ``fps``: finished frames shown per second over the run (a final render: one frame);
- ``waits``, ``read_back_kb``: the most waits for the GPU, and KB read back, of one viewport frame
  shown (its ``--stats`` counts), next to ``image_kb``, the frame's image, and ``trace_path``;
- ``peak_gpu_mb``: the GPU memory taken at the peak of the case, where the GL reports it
  (``GL_NVX_gpu_memory_info`` / ``GL_ATI_meminfo``), else what the renderer counted of its own
  textures and buffers (the viewport's most in use, a final frame's peak), else null.

The viewport runs after a warm-up (the first export, bake and frame are not measured) until
``--frames`` frames were shown.

    .venv/bin/python -m benchmarks.bench_interface [--scenes forest scaling:...] [--size 1280x720]
        [--frames 3] [--json OUT]
"""
from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import json
import math
import os
import re
import sys
import threading
import time
from pathlib import Path

DEFAULT_SCENES = ["forest", "scaling:triangles=1000000,instances=1000"]
GL_NVX_AVAILABLE_KB = 0x9049  # GL_GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX
GL_ATI_TEXTURE_FREE = 0x87FC  # GL_TEXTURE_FREE_MEMORY_ATI (4 ints, the first: free KB)


class Ticker(threading.Thread):
    """A thread that sleeps 1 ms at a time and records the longest gap between its ticks (it
    needs Python's lock to tick, as the interface's Python does)."""

    def __init__(self):
        super().__init__(daemon=True, name="bench-ticker")
        self.max_gap = 0.0
        self.running = True

    def run(self):
        last = time.perf_counter()
        while self.running:
            time.sleep(0.001)
            now = time.perf_counter()
            self.max_gap = max(self.max_gap, now - last)
            last = now

    def stop(self) -> float:
        """Stop; the longest gap in ms."""
        self.running = False
        self.join(5)
        return self.max_gap * 1e3


class GpuMemoryProbe(threading.Thread):
    """Samples the free video memory every 20 ms on its own context, where the GL reports it;
    ``peak_mb()``: the most taken beyond the level at :meth:`reset`, None without a report."""

    def __init__(self):
        super().__init__(daemon=True, name="bench-gpu-memory")
        self.query = None
        self.baseline = self.lowest = None
        self.ready = threading.Event()
        self.running = True
        self.lock = threading.Lock()

    def run(self):
        try:
            import moderngl

            ctx = moderngl.create_standalone_context(backend="egl")
            ext = ctx.extensions
            lib = ctypes.CDLL(ctypes.util.find_library("OpenGL") or "libOpenGL.so.0")
            get = lib.glGetIntegerv
            get.argtypes = [ctypes.c_uint, ctypes.POINTER(ctypes.c_int)]
            out = (ctypes.c_int * 4)()
            if "GL_NVX_gpu_memory_info" in ext:
                pname = GL_NVX_AVAILABLE_KB
            elif "GL_ATI_meminfo" in ext:
                pname = GL_ATI_TEXTURE_FREE
            else:
                return

            def query() -> int:
                get(pname, out)
                return int(out[0])

            self.query = query
        except Exception as exc:  # no probe: the figure is null
            print(f"(no GPU memory probe: {exc})", file=sys.stderr)
            return
        finally:
            self.ready.set()
        while self.running:
            free = self.query()
            with self.lock:
                if self.baseline is None:
                    self.baseline = self.lowest = free
                self.lowest = min(self.lowest, free)
            time.sleep(0.02)

    def reset(self) -> None:
        with self.lock:
            self.baseline = self.lowest = None

    def peak_mb(self):
        with self.lock:
            if self.query is None or self.baseline is None:
                return None
            return round((self.baseline - self.lowest) / 1024.0, 1)


def make_blender_gpu_context(scene) -> None:
    """Blender makes its GPU context (which ``gpu`` needs) in background mode only for a render:
    a tiny Workbench one."""
    r = scene.render
    old = r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage
    r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = "BLENDER_WORKBENCH", 8, 8, 100
    import bpy

    bpy.ops.render.render()
    r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = old


class Engine:
    """The engine's viewport methods on a stand-in instance (a ``RenderEngine`` cannot be made
    outside a 3D view): counts the frames its display receives."""

    def __init__(self):
        from hybrid_shadow_addon.blender import viewport_engine as vpe
        from hybrid_shadow_addon.blender.engine import HybridShadowsEngine
        from hybrid_shadow_addon.blender.viewport import ViewportDisplay

        self._view_update = HybridShadowsEngine.view_update
        self._view_draw = HybridShadowsEngine.view_draw
        vpe.init(self)
        self._display = ViewportDisplay()
        upload = self._display.upload
        self.shown = 0

        def counted(image):
            upload(image)
            self.shown += 1

        self._display.upload = counted
        self.errors = []
        self.frame_stats = []  # the stats of each frame shown
        show = vpe.show_result

        def show_result(engine, worker):
            poll = worker.poll

            def polled(view):
                result, errors = poll(view)
                if result is not None and engine is self:  # (the image as read back: RGBA32F)
                    h, w = getattr(result.image, "array", result.image).shape[:2]
                    self.frame_stats.append((result.stats, w * h * 16))
                return result, errors

            worker.poll = polled
            try:
                return show(engine, worker)
            finally:
                del worker.poll

        vpe.show_result = show_result

    def view_update(self, context, depsgraph):
        self._view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        self._view_draw(self, context, depsgraph)

    def _view_render(self, scene, rv3d, width, height):
        from hybrid_shadow_addon.blender import viewport_engine as vpe

        vpe.view_render(self, scene, rv3d, width, height)

    def tag_redraw(self):
        pass

    def update_stats(self, a, b):
        self.stats = b
        m = re.search(r"GPU (\d+) MB", b)
        if m:
            self.gpu_mb = max(getattr(self, "gpu_mb", 0.0), float(m.group(1)))

    def report(self, kind, msg):
        self.errors.append(msg)

    def bind_display_space_shader(self, scene):
        pass

    def unbind_display_space_shader(self):
        pass


class Context:
    """What ``view_update``/``view_draw`` read from ``bpy.context`` in a 3D view."""

    def __init__(self, scene, width, height, view, window):
        import bpy

        self.scene = scene
        self.preferences = bpy.context.preferences
        self.view_layer = bpy.context.view_layer
        self.space_data = None  # (no local view)
        self.region = type("Region", (), {"width": width, "height": height})()
        self.region_data = type("RegionView3D", (), {"view_matrix": view, "window_matrix": window})()


def orbit(matrix, angle):
    """A view matrix turned by ``angle`` radians about the world Z axis."""
    from mathutils import Matrix

    return matrix @ Matrix.Rotation(angle, 4, "Z")


def viewport_case(scene, w, h, frames, probe, timeout_s) -> dict:
    """The rendered viewport, redrawn at 60 Hz with a view changing every redraw, until
    ``frames`` frames were shown after the warm-up."""
    import bpy
    import gpu
    from mathutils import Matrix

    from hybrid_shadow_addon.blender import viewport_engine as vpe

    dg = bpy.context.evaluated_depsgraph_get()
    cam = scene.camera.evaluated_get(dg)
    view = cam.matrix_world.normalized().inverted()
    window = cam.calc_matrix_camera(dg, x=w, y=h)
    context = Context(scene, w, h, view, window)
    eng = Engine()
    off = gpu.types.GPUOffScreen(w, h)

    def redraw():
        with off.bind(), gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
            gpu.matrix.load_matrix(Matrix.Identity(4))
            gpu.matrix.load_projection_matrix(Matrix.Translation((-1.0, -1.0, 0.0))
                                              @ Matrix.Diagonal((2.0 / w, 2.0 / h, 1.0, 1.0)))
            eng.view_draw(context, dg)

    try:
        probe.reset()
        t0 = time.perf_counter()
        eng.view_update(context, dg)
        while eng.shown == 0:  # warm-up: export, bake, first frame
            redraw()
            if eng.errors:
                raise RuntimeError(eng.errors[0])
            time.sleep(0.01)
        warmup = time.perf_counter() - t0
        ticker = Ticker()
        ticker.start()
        start_shown, draw_times = eng.shown, []
        eng.frame_stats.clear()
        max_gap, step = 0.0, 0
        t_start = last = next_redraw = time.perf_counter()
        while eng.shown - start_shown < frames and last - t_start < timeout_s:
            now = time.perf_counter()
            max_gap, last = max(max_gap, now - last), now
            if now >= next_redraw:
                step += 1
                context.region_data.view_matrix = orbit(view, 0.02 * math.sin(step * 0.1))
                t0 = time.perf_counter()
                redraw()
                draw_times.append(time.perf_counter() - t0)
                next_redraw = t0 + vpe.POLL_S
                last = time.perf_counter()
                max_gap = max(max_gap, last - now)
            time.sleep(0.001)
        elapsed = time.perf_counter() - t_start
        shown = eng.shown - start_shown
        thread_gap = ticker.stop()
        state = vpe.shared(eng)
        if state is not None:
            state.worker.wait_idle(120)
        if eng.errors:
            raise RuntimeError(eng.errors[0])
        return {"max_gap_ms": round(max_gap * 1e3, 1),
                "main_ms_per_redraw": round(1e3 * sum(draw_times) / max(1, len(draw_times)), 2),
                "fps": round(shown / elapsed, 3), "peak_gpu_mb": _peak(probe.peak_mb(), getattr(eng, "gpu_mb", None)),
                "max_thread_gap_ms": round(thread_gap, 1), "redraws": len(draw_times), "frames": shown,
                "max_redraw_ms": round(1e3 * max(draw_times, default=0.0), 1),
                **_frame_counts(eng.frame_stats),
                "warmup_s": round(warmup, 2), "seconds": round(elapsed, 2)}
    finally:
        vpe.free(eng)
        off.free()


def _frame_counts(seen) -> dict:
    """The most waits and bytes read back of one of the frames ``seen`` ((stats, image bytes))."""
    if not seen:
        return {"waits": None, "read_back_kb": None, "image_kb": None, "trace_path": None}
    return {"waits": max(s.get("waits", 0) for s, _ in seen),
            "read_back_kb": round(max(s.get("bytes_read_back", 0) for s, _ in seen) / 1024, 1),
            "image_kb": round(max(n for _, n in seen) / 1024, 1),
            "trace_path": sorted({str(s.get("trace_path")) for s, _ in seen})}


def final_case(scene, w, h, probe) -> dict:
    """One F12 render with the engine, a ticker thread running."""
    import bpy

    r = scene.render
    r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = "HYBRID_SHADOWS", w, h, 100
    probe.reset()
    ticker = Ticker()
    ticker.start()
    t0 = time.perf_counter()
    bpy.ops.render.render()
    elapsed = time.perf_counter() - t0
    gap = ticker.stop()
    from hybrid_shadow_addon.blender import final_render

    return {"max_gap_ms": round(gap, 1), "main_ms_per_redraw": None, "fps": round(1.0 / elapsed, 3),
            "peak_gpu_mb": _peak(probe.peak_mb(), getattr(final_render, "LAST_STATS", {}).get("gpu_peak_mb")),
            "seconds": round(elapsed, 2)}


def _peak(reported, counted):
    """The driver's figure where it reports one, else what the renderer counted (its textures
    and buffers; None for a tree that does not count)."""
    return reported if reported is not None else counted


def short_name(arg: str) -> str:
    return arg.split(":", 1)[0]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=DEFAULT_SCENES)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--frames", type=int, default=3, help="viewport frames shown per case (after the warm-up)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds at most per viewport case")
    ap.add_argument("--json", dest="json_out", help="write the cases here")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))

    import bpy

    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender.load import open_scene

    probe = GpuMemoryProbe()
    probe.start()
    probe.ready.wait(30)
    cases = []
    registered = False
    try:
        for arg in args.scenes:
            scene = open_scene(arg)
            if not registered:
                hybrid_shadow_addon.register()
                registered = True
            make_blender_gpu_context(scene)
            scene.render.engine = "HYBRID_SHADOWS"
            name = short_name(arg)
            cases.append({"name": f"{name} viewport", "scene": arg, **viewport_case(scene, w, h, args.frames,
                                                                                    probe, args.timeout)})
            print_case(cases[-1])
            cases.append({"name": f"{name} final", "scene": arg, **final_case(scene, w, h, probe)})
            print_case(cases[-1])
    finally:
        if registered:
            hybrid_shadow_addon.unregister()  # (bpy 4.5 hangs at exit with the engine registered)
        probe.running = False
    del bpy
    out = {"size": [w, h], "frames": args.frames, "cases": cases}
    print_table(cases, w, h)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1))
    return out


def print_case(c: dict) -> None:
    print(f"  {c['name']}: {json.dumps({k: v for k, v in c.items() if k not in ('name', 'scene')})}", flush=True)


def print_table(cases, w, h) -> None:
    def fmt(v, spec):
        return format("null", f">{re.match(r'[0-9]*', spec).group()}") if v is None else format(v, spec)

    print(f"\n{w}x{h}")
    print(f"{'case':<22} {'max gap ms':>10} {'main ms/redraw':>15} {'fps':>8} {'peak GPU MB':>12} {'waits':>6} "
          f"{'read KB':>9} {'image KB':>9}")
    for c in cases:
        print(f"{c['name']:<22} {fmt(c['max_gap_ms'], '10.1f')} {fmt(c['main_ms_per_redraw'], '15.2f')} "
              f"{fmt(c['fps'], '8.3f')} {fmt(c['peak_gpu_mb'], '12.1f')} {fmt(c.get('waits'), '6d')} "
              f"{fmt(c.get('read_back_kb'), '9.1f')} {fmt(c.get('image_kb'), '9.1f')}")


if __name__ == "__main__":
    code = 0
    try:
        main()
    except BaseException:
        import traceback

        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
