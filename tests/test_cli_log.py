"""``--blender-log FILE``: Blender's and Cycles' own output goes to the file, the progress bar and
the results stay on the terminal."""
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

REPO = Path(__file__).resolve().parents[1]


def test_blender_output_goes_to_the_log(tmp_path):
    log = tmp_path / "blender.log"
    proc = subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", "--blender-log", str(log), "compare",
                           "cube_on_plane", "--resolution", "40x30", "--repeats", "1", "--warmup", "0",
                           "--modes", "raytrace-high", "--no-cache", "--output-dir", str(tmp_path / "c")],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Fra:" in log.read_text() or "render" in log.read_text()  # Cycles' own progress lines
    assert "Fra:" not in proc.stderr and "Fra:" not in proc.stdout
    assert "compare [" in proc.stderr  # the progress bar
    assert "raytrace high" in proc.stdout  # the table
