"""The engine's persistent data: an animation render (``bpy.ops.render.render(animation=True)``,
what ``blender -b file.blend -a`` runs) with ``use_persistent_data`` bakes once and updates the
bake between frames; its frames equal single-frame renders without persistent data.

The bpy work runs in a subprocess (``python tests/test_addon_animation.py OUT``) with the add-on
registered from the source tree and unregistered before it exits.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
FRAMES = (1, 2, 3, 4)


def driver(out_dir: str) -> None:
    import bpy

    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender import final_render
    from hybrid_shadow_addon.blender.load import open_scene
    from tests.helpers.blender_env import bake_counts

    out = Path(out_dir)
    scene = open_scene("animated")  # factory settings first: they would reset the add-ons
    hybrid_shadow_addon.register()
    report = {}
    frames = []
    final_render.frame_handlers.append(frames.append)
    try:
        scene.render.engine = "HYBRID_SHADOWS"
        scene.render.image_settings.file_format = "PNG"
        scene.render.dither_intensity = 0.0
        scene.view_settings.view_transform = "Standard"
        scene.render.use_persistent_data = True
        scene.render.filepath = str(out / "anim_####")
        bpy.ops.render.render(animation=True)
        report["persistent"] = bake_counts(frames)
        # a light edit between two persistent renders of the last frame: no bake
        scene.frame_set(FRAMES[-1])
        bpy.data.objects["Lamp"].location.x += 0.5
        scene.render.filepath = str(out / "lamp_persistent.png")
        bpy.ops.render.render(write_still=True)
        report["after_light_edit"] = bake_counts(frames)
        scene.render.use_persistent_data = False
        scene.render.filepath = str(out / "lamp_single.png")
        bpy.ops.render.render(write_still=True)
        bpy.data.objects["Lamp"].location.x -= 0.5
        for f in FRAMES:
            scene.frame_set(f)
            scene.render.filepath = str(out / f"single_{f}.png")
            bpy.ops.render.render(write_still=True)
        report["single"] = bake_counts(frames)
    finally:
        hybrid_shadow_addon.unregister()
    (out / "report.json").write_text(json.dumps(report))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from tests.helpers.blender_env import isolated_env

    tmp = tmp_path_factory.mktemp("animation")
    proc = subprocess.run([sys.executable, __file__, str(tmp)], cwd=REPO, env=isolated_env(tmp),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return {"tmp": tmp, "report": json.loads((tmp / "report.json").read_text()), "log": proc.stdout}


def png(path):
    from PIL import Image

    return np.asarray(Image.open(path))


def test_animation_bakes_once(run):
    r = run["report"]
    assert r["persistent"] == {"full": 1, "incremental": 3, "none": 0}
    assert "bake: incremental" in run["log"]


def test_light_edit_needs_no_bake(run):
    r = run["report"]
    assert r["after_light_edit"] == {"full": 1, "incremental": 3, "none": 1}
    np.testing.assert_array_equal(png(run["tmp"] / "lamp_persistent.png"), png(run["tmp"] / "lamp_single.png"))


def test_without_persistent_data_every_frame_bakes(run):
    r = run["report"]
    assert r["single"]["full"] == r["after_light_edit"]["full"] + 1 + len(FRAMES)


def test_frames_equal_single_frame_renders(run):
    tmp = run["tmp"]
    anim = [png(tmp / f"anim_{f:04d}.png") for f in FRAMES]
    assert (anim[0] != anim[-1]).any(axis=-1).sum() > 500  # the cube moves
    for f, a in zip(FRAMES, anim):
        assert a.shape[:2] == (120, 160)
        np.testing.assert_array_equal(a, png(tmp / f"single_{f}.png"), err_msg=f"frame {f}")


if __name__ == "__main__":
    driver(sys.argv[1])
