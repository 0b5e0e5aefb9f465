"""The export report on the ``materials`` scene through the command line: printed once after the
export by ``render`` and ``compare``, in ``--stats`` as ``warnings``, listed in the compare
report; and the scene's hard shadows against Cycles' per-light references."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hybrid_shadow_addon.tools.report import _warnings_html

pytestmark = [pytest.mark.blender]

REPO = Path(__file__).resolve().parents[1]
#: lines the materials scene's report must hold (each a prefix)
EXPECTED = ("material 'Panel': emissive", "material 'Glass': Glass BSDF drawn opaque", "world 'materials world': Sky")


def cli(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def _has(lines, prefix):
    return any(w.startswith(prefix) for w in lines)


def test_render_prints_the_report_and_stats_list_it(tmp_path):
    stats = tmp_path / "stats.json"
    r = cli("render", "materials", "--resolution", "80x60", "--output", str(tmp_path / "out.png"),
            "--stats", str(stats), "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("export report:") == 1, r.stderr
    warnings = json.loads(stats.read_text())["warnings"]
    for prefix in EXPECTED:
        assert _has(warnings, prefix), warnings
        assert f"  - {prefix}" in r.stderr
    assert len(warnings) == len(set(warnings))


def test_compare_lists_the_report_and_matches_cycles(tmp_path):
    r = cli("compare", "materials", "--resolution", "320x240", "--modes", "raytrace-high", "--repeats", "1",
            "--warmup", "0", "--output-dir", str(tmp_path), "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("export report:") == 1, r.stderr
    m = json.loads((tmp_path / "metrics.json").read_text())
    for prefix in EXPECTED:
        assert _has(m["warnings"], prefix), m["warnings"]
    page = (tmp_path / "report.html").read_text()
    assert "Export report" in page and "material &#x27;Panel&#x27;: emissive" in page
    for light, err in m["variants"][0]["per_light"].items():
        assert err["mismatch_pct"] < 0.5, (light, err)


def test_warnings_html_lists_each_line_escaped():
    assert _warnings_html({"warnings": []}) == ""
    page = _warnings_html({"warnings": ["material 'A': x < y", "Curves object 'Fur': not drawn"]})
    assert page.count("<li>") == 2 and "x &lt; y" in page and "&#x27;Fur&#x27;" in page
