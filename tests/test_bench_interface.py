"""``benchmarks/bench_interface.py`` end to end on a tiny scene: it exits cleanly (the engine
unregistered) and ``--json`` writes one viewport and one final-render case per scene, each with
the interface's longest wait, main-thread ms per redraw, frames per second and peak GPU memory."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    from tests.helpers.blender_env import isolated_env

    tmp = tmp_path_factory.mktemp("bench_interface")
    out = tmp / "interface.json"
    r = subprocess.run([sys.executable, "-m", "benchmarks.bench_interface", "--scenes", "cube_on_plane",
                        "--size", "64x36", "--frames", "1", "--json", str(out)],
                       cwd=REPO, env=isolated_env(tmp), capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "cube_on_plane viewport" in r.stdout and "max gap ms" in r.stdout
    return json.loads(out.read_text())["cases"]


def test_one_viewport_and_one_final_case_per_scene(cases):
    assert [c["name"] for c in cases] == ["cube_on_plane viewport", "cube_on_plane final"]
    for c in cases:
        assert {"name", "max_gap_ms", "main_ms_per_redraw", "fps", "peak_gpu_mb"} <= set(c)
        assert c["max_gap_ms"] > 0 and c["fps"] > 0
        assert c["peak_gpu_mb"] is None or c["peak_gpu_mb"] >= 0


def test_viewport_case_measures_its_redraws(cases):
    vp, final = cases
    assert vp["main_ms_per_redraw"] > 0 and vp["redraws"] >= 1 and vp["frames"] >= 1
    assert vp["max_gap_ms"] >= vp["main_ms_per_redraw"]  # a redraw is a gap of the main thread
    assert final["main_ms_per_redraw"] is None
    # a viewport frame's host counts: at least its image read back, with its wait
    assert vp["waits"] >= 1 and vp["read_back_kb"] >= vp["image_kb"] > 0 and vp["trace_path"]
