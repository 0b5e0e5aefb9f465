"""The engine's final render through the final-render process: an F12 gives its GPU memory back
(without persistent data, to the level before it), Esc stops it within 0.2 s in the export and
in the render, writing nothing, and the next F12 renders normally.

The bpy work runs in a subprocess (``python tests/test_addon_final_process.py OUT``) with the
add-on registered from the source tree and unregistered before it exits. Esc is ``test_break``
turning True on a stand-in for the engine instance (background mode has no Esc key).
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]


class Stand:
    """What ``final_render.render`` calls on an engine instance; ``test_break`` turns True
    ``after`` s after the first call that asks."""

    def __init__(self, after: float):
        self.after = after
        self.t0 = None
        self.asked = None
        self.results = 0
        self.errors = []

    def test_break(self) -> bool:
        now = time.perf_counter()
        if self.t0 is None:
            self.t0 = now
        if now - self.t0 >= self.after:
            if self.asked is None:
                self.asked = now
            return True
        return False

    def update_stats(self, *_a):
        pass

    def update_progress(self, *_a):
        pass

    def report(self, kind, msg):
        if "ERROR" in kind:
            self.errors.append(msg)

    def begin_result(self, *_a, **_k):
        self.results += 1
        raise AssertionError("a cancelled render wrote a result")


def driver(out_dir: str) -> None:
    import bpy

    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender import final_render
    from hybrid_shadow_addon.blender.gl import final_renderer
    from hybrid_shadow_addon.blender.load import open_scene

    scene = open_scene("forest")
    hybrid_shadow_addon.register()
    report = {}
    frames = []
    final_render.frame_handlers.append(frames.append)
    try:
        scene.render.engine = "HYBRID_SHADOWS"
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 640, 360, 100
        scene.hybrid_shadows.use_soft_shadows = True
        bpy.ops.render.render()
        report["first"] = dict(frames[-1])
        bpy.ops.render.render()
        report["second"] = dict(frames[-1])
        pid = final_renderer().pid
        dg = bpy.context.evaluated_depsgraph_get()
        for name, after in (("export", 0.0), ("render", 1.0)):
            eng = Stand(after)
            t0 = time.perf_counter()
            final_render.render(eng, dg)
            end = time.perf_counter()
            report[name] = {"stop_s": end - (eng.asked or end), "total_s": end - t0, "results": eng.results,
                            "errors": eng.errors}
        bpy.ops.render.render()
        report["after_cancel"] = dict(frames[-1])
        report["same_process"] = final_renderer().pid == pid
        # an animation with persistent data and Reuse Between Frames: hard masks carry over
        scene.hybrid_shadows.use_soft_shadows = False
        scene.render.use_persistent_data = True
        scene.hybrid_shadows.use_reuse_animation = True
        for k in range(2):
            scene.frame_set(scene.frame_current + 1)
            bpy.ops.render.render()
            report[f"anim{k}"] = dict(frames[-1])
        scene.render.use_persistent_data = False
        bpy.ops.render.render()  # (the history is given back with the bake)
    finally:
        hybrid_shadow_addon.unregister()
    Path(out_dir, "report.json").write_text(json.dumps(report, default=str))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from tests.helpers.blender_env import isolated_env

    tmp = tmp_path_factory.mktemp("final_process")
    proc = subprocess.run([sys.executable, __file__, str(tmp)], cwd=REPO, env=isolated_env(tmp),
                          capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads((tmp / "report.json").read_text())


def test_an_f12_gives_its_gpu_memory_back(report):
    for k in ("first", "second", "after_cancel"):
        s = report[k]
        assert s["gpu_peak_mb"] > 10.0, s  # (6 soft lights' targets at 640x360)
        assert s["gpu_memory_after_mb"] == s["gpu_memory_before_mb"] == 0.0, s


def test_an_animation_reuses_hard_masks_with_persistent_data(report):
    """Render ▸ Shadows ▸ Limits ▸ Reuse Between Frames, with persistent data: the second frame
    keeps the hard masks' pixels its move cannot change (traced anew in the first)."""
    first, second = report["anim0"], report["anim1"]
    assert first["pixels_reused"] == 0 and second["pixels_reused"] > 0, (first, second)
    assert second["rays_traced"] < first["rays_traced"]
    assert second["reuse_ways"] == {"reused": second["shadowed_lights"] - second["lights_culled"], "plain": 0}


def test_esc_stops_the_export_and_the_render_within_0_2_s(report):
    for k in ("export", "render"):
        r = report[k]
        assert r["stop_s"] < 0.2 and r["results"] == 0 and not r["errors"], (k, r)
    assert report["render"]["total_s"] >= 1.0  # (it was rendering when Esc came)
    assert report["after_cancel"]["bake"] == "full"  # (in the same renderer, or a new one where it was ended)


if __name__ == "__main__":
    driver(sys.argv[1])
