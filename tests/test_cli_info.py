"""``python -m hybrid_shadow_addon info SCENE [--json]`` in a subprocess.

Contract: it prints instances, models, triangles, lights by type and world bounds; user errors
give one line on stderr and exit code 2, never a traceback.
"""
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender]

REPO = Path(__file__).resolve().parents[1]


def info(*args):
    return subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", "info", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120)


def test_info_json_cube_on_plane():
    r = info("cube_on_plane", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert (s["instances"], s["models"], s["triangles"]) == (2, 2, 14)
    assert s["lights"] == {"SUN": 1, "POINT": 0, "SPOT": 0, "AREA": 0}
    assert s["resolution"] == [320, 240]
    assert s["world_bounds"]["min"] == pytest.approx([-5, -5, 0], abs=1e-5)
    assert s["world_bounds"]["max"] == pytest.approx([5, 5, 2], abs=1e-5)


def test_info_json_with_params_and_frame():
    r = info("forest:trees=10,spheres=4,terrain=8,variants=1,frames=20", "--json", "--frame", "7")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["instances"] == 15 and s["frame"] == 7
    assert s["sphere_primitives"] == 2
    assert s["lights"]["SUN"] == 1 and s["lights"]["POINT"] == 3 and s["lights"]["SPOT"] == 2


def test_info_text():
    r = info("cube_on_plane")
    assert r.returncode == 0, r.stderr
    out = r.stdout.lower()
    for word in ("instances", "models", "triangles", "lights", "bounds", "sun"):
        assert word in out


def test_info_unknown_scene_is_one_line():
    r = info("no_such_scene")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "no_such_scene" in lines[0] and "forest" in lines[0]
    assert r.stdout == ""


@pytest.mark.parametrize("content, expected", [
    ("raise RuntimeError('kaput')", "scene script bad.py failed: RuntimeError: kaput"),
    (None, "cannot open"),
])
def test_info_broken_inputs(tmp_path, content, expected):
    if content is None:
        path = tmp_path / "bad.blend"
        path.write_bytes(b"\x00garbage" * 100)
    else:
        path = tmp_path / "bad.py"
        path.write_text(content)
    r = info(str(path))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert expected in r.stderr
    assert sum(expected in line for line in r.stderr.splitlines()) == 1
