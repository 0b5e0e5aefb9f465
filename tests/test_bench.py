"""``bench`` end to end on a small forest (its animated camera path, rolling spheres): the
files, the statistics per mode and the control; the path frames."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hybrid_shadow_addon.core.errors import HybridShadowError
from hybrid_shadow_addon.tools.bench import FIGURES, path_frames

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]


def test_path_frames():
    assert path_frames(1, 250, 1) == [1]
    assert path_frames(1, 250, 3) == [1, 126, 250]
    assert path_frames(1, 5, 10) == [1, 2, 3, 4, 5]
    assert path_frames(7, 7, 4) == [7]
    with pytest.raises(HybridShadowError):
        path_frames(1, 10, 0)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    r = subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", "bench",
                        "forest:trees=12,spheres=4,terrain=32,frames=40", "--frames", "3", "--repeats", "2",
                        "--resolution", "80x45", "--modes", "raytrace-high", "shadowmap-512",
                        "--output-dir", str(out)],
                       cwd=REPO, capture_output=True, text=True, timeout=240, env=dict(os.environ))
    assert r.returncode == 0, r.stderr[-3000:]
    return out, r


def test_bench_outputs(bench):
    out, r = bench
    assert (out / "bench.json").is_file() and (out / "summary.md").is_file()
    for f in FIGURES:
        assert (out / f).is_file() and (out / f).read_bytes()[:4] == b"\x89PNG", f
    summary = (out / "summary.md").read_text()
    for f in FIGURES:
        assert f"]({f})" in summary
    assert "none (control)" in r.stdout and "summary:" in r.stdout


def test_bench_statistics(bench):
    b = json.loads((bench[0] / "bench.json").read_text())
    assert b["frames"] == [1, 20, 40] and b["repeats"] == 2 and b["resolution"] == [80, 45]
    assert list(b["modes"]) == ["none", "raytrace-high", "shadowmap-512"]
    assert len(b["bake_ms"]) == 1  # only instances and the camera move: one bake, then updates
    assert b["update_ms"]["count"] > 0  # the rolling spheres
    for _name, m in b["modes"].items():
        s = m["stats"]
        assert len(m["frame_ms"]) == 2 and all(len(row) == 3 for row in m["frame_ms"])
        assert all(t > 0 for row in m["frame_ms"] for t in row)
        assert s["min_fps"] <= s["avg_fps"] <= s["max_fps"]
        assert s["std_rel"] >= 0 and s["erraticness"] >= 0 and len(s["erraticness_per_frame"]) == 3
        assert len(s["extra_ms_per_frame"]) == 3
    assert b["modes"]["none"]["stats"]["extra_ms"] == 0
    assert b["modes"]["raytrace-high"]["stats"]["avg_shadow_ms"] > b["modes"]["none"]["stats"]["avg_shadow_ms"]
