"""The Flamenco job type (tools/flamenco/hybrid_shadows.js): its compileJob under Node.js with a
stand-in of Flamenco's authoring API (tests/flamenco_stub.js), the commands it produces, and one
produced chunk's command line run with ``bpy`` in place of the ``blender`` binary
(tests/helpers/blender_env.py)."""
from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
JOB_TYPE = REPO / "tools/flamenco/hybrid_shadows.js"
STUB = REPO / "tests/flamenco_stub.js"
NODE = shutil.which("node") or shutil.which("nodejs")

pytestmark = [pytest.mark.skipif(NODE is None, reason="Node.js not found: tools/setup.sh installs it "
                                 "(apt-get install nodejs, as root); the job type cannot be evaluated without it"),
              pytest.mark.blender, pytest.mark.gpu]

BASE = {"frames": "1-10", "chunk_size": 4, "shadow_mode": "RAYTRACE", "shadow_quality": "MEDIUM",
        "render_output_root": "/farm/renders", "render_output_path": "/farm/renders/shot/{timestamp}/######",
        "blendfile": "/farm/shot.blend", "scene": "animated", "format": "PNG", "image_file_extension": ".png",
        "samples": 16}


def compile_job(tmp_path, **settings):
    job = {"name": "shot", "created": "2026-12-01T21:30:05", "settings": {**BASE, **settings}}
    spec = tmp_path / "job.json"
    spec.write_text(json.dumps(job))
    p = subprocess.run([NODE, str(STUB), str(JOB_TYPE), str(spec)], capture_output=True, text=True, timeout=60)
    out = json.loads(p.stdout)
    if p.returncode != 0:
        return out
    assert "error" not in out
    return out


def blender_args(task) -> list:
    """The argv after the executable that the Worker runs: exeArgs, argsBefore, blendfile, args."""
    (cmd,) = [c for c in task["commands"] if c["type"] == "blender-render"]
    p = cmd["parameters"]
    assert p["exe"] == "{blender}" and p["exeArgs"] == "{blenderArgs}"
    return ["-b", "-y", *p["argsBefore"], p["blendfile"], *p["args"]]


def arg(args, flag):
    return args[args.index(flag) + 1]


def test_settings_declared(tmp_path):
    out = compile_job(tmp_path)
    assert out["label"] == "Hybrid Shadows Render"
    assert {"frames", "chunk_size", "blendfile", "render_output_path", "shadow_mode", "shadow_quality",
            "samples", "soft_shadows", "format"} <= set(out["setting_keys"])


def test_descriptions_match_the_engine():
    """The job type describes the engine's soft shadows (no claim that it has none)."""
    import re

    text = JOB_TYPE.read_text() + (REPO / "tools/flamenco/README.md").read_text()
    assert not re.search(r"no soft|not passed|passes it to nothing", text, re.I)
    assert "use_soft_shadows" in text and "s.hybrid_shadows.samples" in text


def test_chunks_become_blender_commands_with_this_engine(tmp_path):
    out = compile_job(tmp_path)
    tasks = out["tasks"]
    assert [t["name"] for t in tasks] == ["render-1-4", "render-5-8", "render-9-10"]
    for t, frames in zip(tasks, ("1..4", "5..8", "9..10")):
        assert t["type"] == "blender"
        args = blender_args(t)
        assert args[2] == "/farm/shot.blend"
        assert arg(args, "-E") == "HYBRID_SHADOWS"
        assert arg(args, "--render-frame") == frames
        assert arg(args, "--render-output") == "/farm/renders/shot/2026-12-01_213005/######"
        assert arg(args, "--render-format") == "PNG"
        assert arg(args, "--scene") == "animated"
        assert arg(args, "--python-exit-code") == "1"
        expr = arg(args, "--python-expr")
        assert "s.hybrid_shadows.mode = 'RAYTRACE'" in expr and "s.hybrid_shadows.quality = 'MEDIUM'" in expr
        assert "use_persistent_data = True" in expr
        # Blender applies arguments in order: the settings before the frames are rendered
        assert args.index("--scene") < args.index("-E") < args.index("--python-expr") < args.index("--render-frame")
        assert "16" not in args  # samples: set in the --python-expr, not a command-line argument
        assert "s.hybrid_shadows.samples = 16" in expr and "s.hybrid_shadows.use_soft_shadows = True" in expr
    assert out["settings"]["render_output_path"] == "/farm/renders/shot/2026-12-01_213005/######"


def test_settings_map_to_the_scene(tmp_path):
    out = compile_job(tmp_path, shadow_mode="SHADOWMAP", shadow_quality="LOW", persistent_bake=False,
                      frames="3,5-6", chunk_size=10, soft_shadows=False, samples=7)
    (task,) = out["tasks"]
    args = blender_args(task)
    assert arg(args, "--render-frame") == "3,5..6"
    expr = arg(args, "--python-expr")
    assert "'SHADOWMAP'" in expr and "'LOW'" in expr and "use_persistent_data = False" in expr
    assert "s.hybrid_shadows.use_soft_shadows = False" in expr and "s.hybrid_shadows.samples = 7" in expr


@pytest.mark.parametrize("settings, words", [
    ({"shadow_mode": "CYCLES"}, "shadow_mode"), ({"shadow_quality": "ULTRA"}, "shadow_quality"),
    ({"chunk_size": 0}, "chunk_size"), ({"samples": 0}, "samples"), ({"samples": 2.5}, "samples"),
    ({"soft_shadows": "yes"}, "soft_shadows"), ({"render_output_path": "/farm/out/frame.png"}, "#"),
])
def test_bad_settings_fail_the_job(tmp_path, settings, words):
    out = compile_job(tmp_path, **settings)
    assert words in out["error"]


def test_a_chunk_renders_its_frames(tmp_path):
    py = sys.executable
    helper = str(REPO / "tests/helpers/blender_env.py")
    blend = tmp_path / "shot.blend"
    from tests.helpers.blender_env import isolated_env

    env = isolated_env(tmp_path)
    made = subprocess.run([py, helper, "--make-blend", "animated", str(blend)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr[-2000:]
    out = compile_job(tmp_path, blendfile=str(blend), frames="1-4", chunk_size=3,
                      render_output_path=str(tmp_path / "frames" / "shot_######"))
    task = out["tasks"][0]
    args = blender_args(task)
    assert arg(args, "--render-frame") == "1..3"
    print("blender " + shlex.join(args))
    p = subprocess.run([py, helper, *args], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    report = json.loads(p.stdout.strip().splitlines()[-1])
    assert report["rendered"] == [1, 2, 3] and report["python_errors"] == 0
    assert report["bakes"] == {"full": 1, "incremental": 2, "none": 0}  # persistent bake within the chunk
    files = sorted(x.name for x in (tmp_path / "frames").iterdir())
    assert files == ["shot_000001.png", "shot_000002.png", "shot_000003.png"]
    from PIL import Image

    imgs = [np.asarray(Image.open(tmp_path / "frames" / f)) for f in files]
    assert all(i.shape[:2] == (120, 160) for i in imgs)
    assert (imgs[0] != imgs[2]).any(axis=-1).sum() > 500  # the cube moves


def test_missing_extension_fails_the_task(tmp_path):
    """Without the engine registered, the --python-expr fails and Blender exits with code 1."""
    out = compile_job(tmp_path)
    expr = arg(blender_args(out["tasks"][0]), "--python-expr")
    code = f"import bpy\nbpy.ops.wm.read_factory_settings(use_empty=True)\ntry:\n    exec({expr!r})\n" \
           "except TypeError as e:\n    print('engine missing:', e)\n"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "engine missing" in p.stdout, p.stdout + p.stderr
