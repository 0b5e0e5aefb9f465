"""The viewport path, as far as it runs headless (in a subprocess: ``python
tests/test_addon_viewport.py OUT``):

- change detection: ``ViewportSync`` fed by a ``depsgraph_update_post`` handler (the same
  ``depsgraph.updates`` ``view_update`` receives) picks the least work, and incremental updates
  give the same masks as a fresh bake;
- ``viewport_camera`` reproduces a camera from its view and window matrices;
- the refine logic of ``view_draw`` (fast pass, then full quality; four frames with interlacing;
  the automatic navigation quality, one frame on this software rasteriser),
  rendered inline (the synchronous debugging mode) and by the worker thread; two engines of one
  scene share one worker and bake and apply the same depsgraph updates once; worker errors
  reach the engine once; freeing the last engine and unregistering stop the thread;
- the draw-data path into a ``gpu.types.GPUOffScreen`` once a tiny Workbench render made
  Blender's GPU context, with our own OpenGL context used in between.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
SCENE = "forest:trees=12,spheres=4,variants=2,terrain=32,width=160,height=120"


def driver(out_dir: str) -> None:  # noqa: C901 - one scripted session
    import bpy
    import numpy as np

    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender.engine import HybridShadowsEngine
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.gl import create_pipeline, gl_scope, release_pipeline
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.blender.viewport import DisplayImage, ViewportDisplay, ViewportSync, viewport_camera
    from hybrid_shadow_addon.core.runtime.remote import RemoteWorker
    from hybrid_shadow_addon.core.settings import Settings

    r = {}
    scene = open_scene(SCENE)
    hybrid_shadow_addon.register()
    pipe = ref = None
    try:
        scene.render.engine = "HYBRID_SHADOWS"
        dg = bpy.context.evaluated_depsgraph_get()
        pipe = create_pipeline()
        sync = ViewportSync(pipe)
        plans = []

        def handler(_scene, depsgraph):
            with gl_scope(pipe):
                plan = sync.update(depsgraph)
            plans.append({"full": plan.full, "moved": sorted(plan.moved), "geometry": sorted(plan.geometry),
                          "lights": plan.lights, "shading": plan.shading, "world": plan.world})

        sync.full_export(dg)
        with gl_scope(pipe):
            sync.ensure_baked()
        bpy.app.handlers.depsgraph_update_post.append(handler)
        settings = Settings()
        w, h = 160, 120

        def step(name, fn):
            plans.clear()
            n_log = len(sync.log)
            fn()
            bpy.context.view_layer.update()
            merged = {"full": any(p["full"] for p in plans), "moved": sorted({m for p in plans for m in p["moved"]}),
                      "geometry": sorted({g for p in plans for g in p["geometry"]}),
                      "lights": any(p["lights"] for p in plans), "shading": any(p["shading"] for p in plans)}
            r[name] = {"plan": merged, "log": [a for a, _ in sync.log[n_log:]]}

        def check_masks(name):
            """Masks of the incrementally updated pipeline == masks of a fresh bake."""
            fresh = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(w, h))
            with gl_scope(pipe):
                sync.scene.camera = fresh.camera
                a = pipe.render(sync.scene, settings, w, h)
                ma = {sync.scene.lights[i].name: a.mask_array(i) for i in a.lights}
            with gl_scope(ref):
                ref.set_scene(fresh)
                b = ref.render(fresh, settings, w, h)
                mb = {fresh.lights[i].name: b.mask_array(i) for i in b.lights}
            r[name]["masks_equal"] = sorted(ma) == sorted(mb) and all(
                np.array_equal(ma[k], mb[k], equal_nan=True) for k in ma)

        ref = create_pipeline()
        step("move", lambda: setattr(bpy.data.objects["Palm.0003"], "location",
                                     bpy.data.objects["Palm.0003"].location
                                     + type(bpy.data.objects["Palm.0003"].location)((2.0, 1.0, 0.0))))
        check_masks("move")

        def edit_terrain():
            me = bpy.data.objects["Terrain"].data
            co = np.empty(len(me.vertices) * 3, np.float32)
            me.vertices.foreach_get("co", co)
            co[2::3] += 0.5 * np.sin(co[0::3] / 5.0)
            me.vertices.foreach_set("co", co)
            me.update()

        step("geometry", edit_terrain)
        check_masks("geometry")
        step("light", lambda: setattr(bpy.data.lights["Dawn sun"], "energy", 3.0))
        step("light_move", lambda: setattr(bpy.data.objects["Lantern.0"], "location", (0.0, 0.0, 5.0)))
        step("material", lambda: bpy.data.materials["Grass"].node_tree.nodes["Principled BSDF"]
             .inputs["Base Color"].__setattr__("default_value", (0.5, 0.2, 0.1, 1.0)))
        step("setting", lambda: setattr(scene.hybrid_shadows, "mode", "SHADOWMAP"))
        scene.hybrid_shadows.mode = "RAYTRACE"

        def add_object():
            ob = bpy.data.objects.new("New box", bpy.data.objects["Ball.000"].data)
            scene.collection.objects.link(ob)

        step("new_object", add_object)
        step("sphere_flag", lambda: setattr(bpy.data.objects["Ball.001"], "hybrid_sphere",
                                            not bpy.data.objects["Ball.001"].hybrid_sphere))
        check_masks("sphere_flag")

        # image pixels are read again only when the image changed
        from hybrid_shadow_addon.blender.export.images import PIXELS

        img = bpy.data.images.new("Paint", 32, 32, alpha=True)
        mat = bpy.data.materials.new("Painted")
        mat.use_nodes = True
        tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
        tex.image = img
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        mat.node_tree.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])

        def add_card():
            me = bpy.data.meshes.new("Card")
            me.from_pydata([(0, 0, 3), (2, 0, 3), (2, 2, 3), (0, 2, 3)], [], [(0, 1, 2, 3)])
            me.uv_layers.new()
            me.materials.append(mat)
            scene.collection.objects.link(bpy.data.objects.new("Card", me))

        step("card", add_card)
        reads = PIXELS.reads
        step("card_colour", lambda: bsdf.inputs["Base Color"].__setattr__("default_value", (0.2, 0.5, 0.1, 1.0)))
        r["card_colour"]["reads"] = PIXELS.reads - reads
        reads = PIXELS.reads

        def paint():
            img.pixels[3] = 0.25
            img.update()
            img.update_tag()  # (what painting tags)

        step("paint", paint)
        r["paint"]["reads"] = PIXELS.reads - reads
        step("card_removed", lambda: bpy.data.objects.remove(bpy.data.objects["Card"]))
        bpy.app.handlers.depsgraph_update_post.remove(handler)

        # viewport camera from a camera's own view/window matrices == that camera
        dg = bpy.context.evaluated_depsgraph_get()
        cam_ob = scene.camera.evaluated_get(dg)
        view = cam_ob.matrix_world.normalized().inverted()
        win = cam_ob.calc_matrix_camera(dg, x=w, y=h)
        vc = viewport_camera(view, win, w, h)
        core = export_depsgraph(dg, resolution=(w, h))
        r["camera_projection_error"] = float(np.abs(vc.projection_matrix(w, h) - np.array(win)).max())
        r["camera_matrix_error"] = float(np.abs(vc.world_matrix_normalized()
                                                - core.camera.world_matrix_normalized()).max())

        # view_draw's refine logic, on a stand-in for the engine instance (inline worker first:
        # one frame per redraw, as the draw callback used to render)
        from hybrid_shadow_addon.blender import viewport_engine as vpe
        from hybrid_shadow_addon.core.runtime import worker as worker_mod

        class Stand:
            _view_render = HybridShadowsEngine._view_render

            def __init__(self):
                vpe.init(self)
                self._display = ViewportDisplay()
                self._display.upload = lambda image: setattr(self, "shown", shown_image(image))
                self.redraws, self.stats, self.reports = 0, [], []

            def tag_redraw(self):
                self.redraws += 1

            def update_stats(self, a, b):
                self.stats.append(b)

            def report(self, kind, msg):
                self.reports.append(msg)

        def shown_image(image):
            """What the display shows, as float32 top-down: a renderer process's frame decoded,
            an in-process one through the same half floats."""
            if isinstance(image, DisplayImage):
                return image.image()
            return np.clip(image, -65504.0, 65504.0).astype(np.float16).astype(np.float32)

        class RV3D:
            view_matrix, window_matrix = view, win

        class NoView:  # a context without a 3D view (the handler's)
            space_data = None

        def stand(dg=None):
            eng = Stand()
            vpe._acquire(eng, dg or bpy.context.evaluated_depsgraph_get(), None, export=True)
            return eng

        import time

        calls = []  # seconds per view_render call

        def run(eng, n, size=(w, h), wait=False):
            seq = []
            for _ in range(n):
                t0 = time.perf_counter()
                eng._view_render(scene, RV3D, *size)
                calls.append(time.perf_counter() - t0)
                seq.append(eng.stats[-1] if eng.stats else None)
                eng.stats.clear()
                if wait:
                    vpe.shared(eng).worker.wait_idle(120)
            return seq

        worker_mod.SYNCHRONOUS = True
        scene.hybrid_shadows.use_soft_shadows = False  # (hard lights: the fast-then-full state machine)
        # the automatic navigation quality (the default): on this software rasteriser the fast
        # pass keeps the viewport quality, so a change of a hard-lit view is a single frame
        r["navigation_default"] = scene.hybrid_shadows.navigation_quality
        eng = stand()
        r["auto"] = {"stats": run(eng, 3), "redraws": eng.redraws}
        vpe.free(eng)
        scene.hybrid_shadows.navigation_quality = "LOW"  # (the state machine below: fast, then full)
        eng = stand()
        r["inline_worker_thread"] = vpe.shared(eng).worker._thread is not None
        seq = run(eng, 3)
        r["refine_plain"] = {"stats": seq, "redraws": eng.redraws, "shape": list(eng.shown.shape)}
        inline_image = eng.shown
        vpe.free(eng)
        scene.hybrid_shadows.use_interlace = True
        eng = stand()
        r["refine_interlace"] = {"stats": run(eng, 7), "redraws": eng.redraws}
        vpe.free(eng)
        scene.hybrid_shadows.use_interlace = False
        # soft lights: after the fast pass, the first redraw gives the penumbrae 16 samples, the
        # next ones add 4 each until 20 are reached
        scene.hybrid_shadows.use_soft_shadows = True
        scene.hybrid_shadows.viewport_samples, scene.hybrid_shadows.viewport_frame_samples = 20, 4
        eng = stand()
        r["refine_soft"] = {"stats": run(eng, 5), "redraws": eng.redraws}
        vpe.free(eng)
        r["registry_after_inline"] = len(vpe._registry)

        # the worker thread: the same frames off the draw callback
        worker_mod.SYNCHRONOUS = False
        scene.hybrid_shadows.use_soft_shadows = False
        a = stand()
        wk = vpe.shared(a).worker
        r["threaded"] = not wk.synchronous and wk.thread_alive
        calls.clear()
        t0 = time.perf_counter()
        seq = run(a, 2, wait=True)
        r["renderer_process"] = isinstance(wk, RemoteWorker) and wk.pid not in (None, os.getpid())
        r["thread_first_call_ms"] = calls[0] * 1e3
        r["thread_until_idle_ms"] = (time.perf_counter() - t0 - calls[1]) * 1e3
        steps = [(s_, q, left) for v, _, s_, q, left in wk.log if v == a._vp_user]
        r["thread_plain"] = {"stats": seq, "steps": [list(x) for x in steps],
                             "same_image": bool(np.array_equal(a.shown, inline_image))}
        # a second viewport of the same scene shares the worker (one context, one bake)
        b = stand()
        r["shared_worker"] = vpe.shared(b) is vpe.shared(a)
        shared_state = vpe.shared(a)
        n_log, bakes_before = len(shared_state.sync.log), [x for x, _ in shared_state.sync.log].count("bake")

        # both engines receive the same depsgraph updates: applied once, and a genuine second
        # edit of the same object again
        def both(_scene, depsgraph):
            for e in (a, b):
                vpe.view_update(e, NoView, depsgraph)

        bpy.app.handlers.depsgraph_update_post.append(both)
        palm = bpy.data.objects["Palm.0003"]
        palm.location.x += 1.0
        bpy.context.view_layer.update()
        palm.location.x += 1.0
        bpy.context.view_layer.update()
        bpy.app.handlers.depsgraph_update_post.remove(both)
        r["dedup_log"] = [x for x, _ in shared_state.sync.log[n_log:]]
        r["stale_after_update"] = shared_state.generation != a._vp_generation
        run(a, 2, wait=True)
        run(b, 2, size=(w // 2, h // 2), wait=True)
        r["b_shape"] = list(b.shown.shape)
        # a's image of the moved scene == a fresh export's, rendered directly
        dg = bpy.context.evaluated_depsgraph_get()
        fresh = export_depsgraph(dg, resolution=(w, h))
        fresh.camera = viewport_camera(view, win, w, h)
        props = scene.hybrid_shadows
        with gl_scope(ref):
            ref.set_scene(fresh)
            ref.render(fresh, props.to_settings(viewport=True, navigating=True), w, h)
            want = ref.render(fresh, props.to_settings(viewport=True), w, h).image
        r["moved_image_error"] = float(np.abs(a.shown - shown_image(want)).max())
        r["bakes_while_shared"] = [x for x, _ in shared_state.sync.log].count("bake") - bakes_before
        # the redraw timer (no event loop runs timers here: called directly) tags the engines
        # with a new frame, and only those
        a._view_render(scene, RV3D, w - 2, h - 2)
        shared_state.worker.wait_idle(120)
        ra, rb = a.redraws, b.redraws
        ret = vpe._poll()
        r["timer"] = {"a": a.redraws - ra, "b": b.redraws - rb, "ret": ret, "background": bpy.app.background}
        run(a, 1)
        # an error raised in the worker: reported once, the worker goes on
        run(a, 3, size=(10 ** 6, 8), wait=True)  # beyond the GPU's limits
        r["error_reports"] = list(a.reports)
        r["error_hidden"] = a._vp_error is not None
        seq = run(a, 2, wait=True)
        r["after_error"] = {"stats": seq, "error": a._vp_error}
        # the last engine releases the worker: its thread stops, its context is released
        vpe.free(a)
        r["after_first_free"] = {"alive": wk.thread_alive, "registry": len(vpe._registry)}
        vpe.free(b)
        gone(lambda: not wk.thread_alive)
        r["after_last_free"] = {"alive": wk.thread_alive, "registry": len(vpe._registry),
                                "pipe": getattr(wk, "_pipe", None) is None}
        # unregister stops what is still running
        c = stand()
        wc = vpe.shared(c).worker
        run(c, 1)

        # the GPU path: Blender's GPU context from a tiny Workbench render, then an offscreen
        scene.render.engine = "BLENDER_WORKBENCH"
        rx, ry, pc = scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage
        scene.render.resolution_x = scene.render.resolution_y = 8
        scene.render.resolution_percentage = 100
        bpy.ops.render.render()
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = rx, ry, pc
        scene.render.engine = "HYBRID_SHADOWS"
        import gpu
        from mathutils import Matrix

        off = gpu.types.GPUOffScreen(w, h, format="RGBA32F")
        display = ViewportDisplay()
        vp_pipe = create_pipeline()  # created while Blender's context is current
        with off.bind():
            fb = gpu.state.active_framebuffer_get()
            fb.clear(color=(0.0, 0.0, 0.0, 0.0))
            with gl_scope(vp_pipe):
                vp_pipe.set_scene(core)
                frame = vp_pipe.render(core, settings, w, h, film_transparent=True)
            display.upload(frame.image)
            with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                gpu.matrix.load_matrix(Matrix.Identity(4))
                gpu.matrix.load_projection_matrix(Matrix.Translation((-1.0, -1.0, 0.0))
                                                  @ Matrix.Diagonal((2.0 / w, 2.0 / h, 1.0, 1.0)))
                display.draw(scene, w, h)
            pixels = np.array(fb.read_color(0, 0, w, h, 4, 0, "FLOAT").to_list(), np.float32).reshape(h, w, 4)
        release_pipeline(vp_pipe)
        off.free()
        want = np.clip(frame.image[::-1], 0.0, 65504.0)
        r["offscreen_error"] = float(np.abs(pixels - want).max())
        r["offscreen_mean"] = float(pixels[..., :3].mean())
    finally:
        release_pipeline(pipe)
        release_pipeline(ref)
        hybrid_shadow_addon.unregister()
    import threading

    gone(lambda: not wc.thread_alive and not [t for t in threading.enumerate() if t.name.startswith("hybrid-shadows")])
    r["after_unregister"] = {"alive": wc.thread_alive, "registry": len(vpe._registry),
                             "threads": [t.name for t in threading.enumerate() if t.name.startswith("hybrid-shadows")]}
    Path(out_dir, "viewport.json").write_text(json.dumps(r, indent=1))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from tests.helpers.blender_env import isolated_env

    tmp = tmp_path_factory.mktemp("viewport")
    proc = subprocess.run([sys.executable, __file__, str(tmp)], cwd=REPO, env=isolated_env(tmp),
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads((tmp / "viewport.json").read_text())


def test_transform_only_change_moves_instances(report):
    m = report["move"]
    assert m["plan"]["moved"] == ["Palm.0003"] and not m["plan"]["full"] and not m["plan"]["geometry"]
    assert m["log"] == ["move"]
    assert m["masks_equal"]


def test_geometry_change_rebuilds_that_model(report):
    g = report["geometry"]
    assert g["plan"]["geometry"] == ["Terrain"] and not g["plan"]["full"]
    assert g["log"] == ["model"]
    assert g["masks_equal"]


@pytest.mark.parametrize("name", ["light", "light_move", "material", "setting"])
def test_light_material_and_setting_changes_rebake_nothing(report, name):
    s = report[name]
    assert not s["plan"]["full"] and not s["plan"]["geometry"] and not s["plan"]["moved"]
    assert "bake" not in s["log"] and "full" not in s["log"]
    if name == "light":  # (its power: no mask changes)
        assert s["plan"]["lights"] and s["log"] == ["lights"]
    if name == "light_move":  # (that light's history alone is forgotten)
        assert s["plan"]["lights"] and s["log"] == ["reset light", "lights"]
    if name == "material":
        assert s["log"] == ["shading"]


def test_image_pixels_are_read_again_only_when_the_image_changed(report):
    assert report["card"]["log"] == ["full"]
    assert report["card_colour"]["log"] == ["shading"] and report["card_colour"]["reads"] == 0
    assert report["paint"]["plan"]["shading"] and report["paint"]["reads"] == 1


def test_structural_changes_export_again(report):
    assert report["new_object"]["plan"]["full"] and report["new_object"]["log"] == ["full"]
    assert report["sphere_flag"]["plan"]["full"]
    assert report["sphere_flag"]["masks_equal"]


def test_viewport_camera_matches_camera(report):
    assert report["camera_projection_error"] < 1e-4
    assert report["camera_matrix_error"] < 1e-5


def test_refine_after_fast_pass(report):
    plain = report["refine_plain"]
    assert "Ray traced low" in plain["stats"][0] and "refining" in plain["stats"][0]
    assert "Ray traced high" in plain["stats"][1] and "refining" not in plain["stats"][1]
    assert plain["stats"][2] is None  # nothing changed: nothing rendered
    assert plain["redraws"] == 1 and plain["shape"] == [120, 160, 4]
    inter = report["refine_interlace"]
    rendered = [s for s in inter["stats"] if s]
    assert len(rendered) == 5 and inter["redraws"] == 4 and inter["stats"][5] is None
    soft = report["refine_soft"]
    assert "Ray traced low" in soft["stats"][0]
    assert "16/20 soft samples" in soft["stats"][1] and "refining" in soft["stats"][1]
    assert "20/20 soft samples" in soft["stats"][2] and "refining" not in soft["stats"][2]
    assert soft["stats"][3] is None and soft["redraws"] == 2


def test_automatic_navigation_is_one_frame_on_a_software_rasteriser(report):
    assert report["navigation_default"] == "AUTO"
    auto = report["auto"]
    assert "Ray traced high" in auto["stats"][0] and "refining" not in auto["stats"][0], auto
    assert auto["stats"][1] is None and auto["stats"][2] is None and auto["redraws"] == 0, auto


def test_refine_runs_inline_in_the_synchronous_mode(report):
    assert report["inline_worker_thread"] is False and report["registry_after_inline"] == 0


def test_the_worker_thread_renders_the_same_frames(report):
    assert report["threaded"] and report["renderer_process"]
    t = report["thread_plain"]
    assert t["steps"] == [[0, "low", 1], [1, "high", 0]]  # fast pass, then full quality
    assert "Ray traced high" in t["stats"][-1] and "refining" not in t["stats"][-1]
    assert t["same_image"]  # as rendered inline
    assert t["stats"][0] is None  # the call returned before the worker had a frame: no wait
    assert report["thread_first_call_ms"] < report["thread_until_idle_ms"] / 4


def test_viewports_of_a_scene_share_one_worker_and_apply_updates_once(report):
    assert report["shared_worker"]
    assert report["dedup_log"] == ["move", "move"]  # two edits, two engines: each edit once
    assert report["stale_after_update"]
    assert report["bakes_while_shared"] == 0  # the second viewport used the bake already made
    assert report["b_shape"] == [60, 80, 4]
    assert report["moved_image_error"] <= 1e-6  # the moved scene, as a fresh export renders it


def test_the_timer_tags_the_engines_with_news(report):
    t = report["timer"]
    assert t["a"] == 1 and t["b"] == 0 and t["ret"] > 0


def test_worker_errors_reach_the_engine_once(report):
    assert len(report["error_reports"]) == 1 and "outside this GPU's limits" in report["error_reports"][0]
    assert report["error_hidden"]
    after = report["after_error"]
    assert after["error"] is None and "Ray traced high" in after["stats"][-1]


def test_the_last_engine_and_unregister_stop_the_worker(report):
    assert report["after_first_free"] == {"alive": True, "registry": 1}
    assert report["after_last_free"] == {"alive": False, "registry": 0, "pipe": True}
    assert report["after_unregister"] == {"alive": False, "registry": 0, "threads": []}


def test_draw_into_offscreen(report):
    assert report["offscreen_mean"] > 0.01
    assert report["offscreen_error"] < 2e-3  # RGBA16F texture


def gone(done, timeout: float = 5.0) -> None:
    """Wait until ``done()`` (a renderer process exits, its threads end) or ``timeout`` s."""
    import time

    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        time.sleep(0.02)


if __name__ == "__main__":
    driver(sys.argv[1])
