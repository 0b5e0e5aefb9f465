"""``compare`` end to end on cube_on_plane at 80x60 with real Cycles: the report's files, every
image the HTML names, raytrace-high within 0.1 % of Cycles, the reference cache; the variants;
the Blender operator in background mode."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hybrid_shadow_addon.core.errors import HybridShadowError
from hybrid_shadow_addon.tools.variants import VARIANTS, resolve_variants

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable


def cli(*args, env_extra=None, timeout=240):
    env = dict(os.environ, **(env_extra or {}))
    return subprocess.run([PY, "-m", "hybrid_shadow_addon", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    base = tmp_path_factory.mktemp("compare")
    out, cache = base / "out", base / "cache"
    args = ["compare", "cube_on_plane", "--resolution", "80x60", "--output-dir", str(out), "--repeats", "2",
            "--warmup", "1", "--cache-dir", str(cache)]
    first = cli(*args)
    assert first.returncode == 0, first.stderr[-3000:]
    return out, cache, first, args


def test_outputs_exist(report):
    out, _, run, _ = report
    for name in ("metrics.json", "error_vs_time.png", "report.html"):
        assert (out / name).is_file(), name
    assert "report:" in run.stdout and str(out / "report.html") in run.stdout
    assert "raytrace high" in run.stdout  # the table
    assert "compare [" in run.stderr  # the progress bar


def test_every_html_image_exists(report):
    out = report[0]
    html = (out / "report.html").read_text()
    srcs = re.findall(r'<img src="([^"]+)"', html)
    m = json.loads((out / "metrics.json").read_text())
    assert "error_vs_time.png" in srcs
    assert len(srcs) >= 1 + len(m["lights"]) * (1 + 2 * len(m["variants"]))
    for s in srcs:
        p = out / s
        assert p.is_file(), s
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for name in re.findall(r'<a href="([^"]+)"', html):
        assert (out / name).is_file()


def test_metrics_content(report):
    m = json.loads((report[0] / "metrics.json").read_text())
    assert m["resolution"] == [80, 60] and m["lights"] == ["Sun"]
    assert [v["name"] for v in m["variants"]] == list(VARIANTS)
    by = {v["name"]: v for v in m["variants"]}
    high = by["raytrace-high"]["overall"]
    assert high["valid_pixels"] > 2000
    assert high["mismatch_pct"] <= 0.1, high
    # no shadows at all must miss every shadowed pixel the reference has, and never cast one
    none = by["none"]["overall"]
    assert none["mismatch_pct"] > 1.0 and none["false_pixels"] == 0
    assert none["missed_pixels"] == none["mismatch_pixels"]
    for v in m["variants"]:
        assert v["total_ms"] > 0 and v["shadow_ms"] >= 0 and len(v["total_ms_samples"]) == 2
        assert set(v["per_light"]) == {"Sun"}
    assert m["reference"]["total_ms"] > 0 and m["reference"]["cached"] is False
    assert m["pareto"] and all(by[n]["pareto"] for n in m["pareto"])
    # the sun's light grid was built in the warm-up (the timed frames trace it), reported apart
    assert m["light_grid_build_ms"] > 0


def test_reference_is_cached(report):
    out, cache, _, args = report
    assert len(list(cache.glob("*.npz"))) == 1
    again = cli(*args[:-4], "--repeats", "1", "--modes", "raytrace-high", "none", "--cache-dir", str(cache),
                "--quiet")
    assert again.returncode == 0, again.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["reference"]["cached"] is True and [v["name"] for v in m["variants"]] == ["raytrace-high", "none"]
    assert m["variants"][0]["overall"]["mismatch_pct"] <= 0.1


def test_bad_mode_is_a_user_error(tmp_path):
    r = cli("compare", "cube_on_plane", "--output-dir", str(tmp_path), "--modes", "pathtrace")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "unknown mode 'pathtrace'" in r.stderr


def test_resolve_variants():
    assert [v.name for v in resolve_variants(None)] == list(VARIANTS)
    assert [v.name for v in resolve_variants(["none,raytrace-low", "shadowmap"])] == [
        "raytrace-low", "shadowmap-512", "shadowmap-1024", "shadowmap-2048", "shadowmap-4096", "none"]
    v = resolve_variants(["shadowmap-256"])[0]
    assert v.settings.shadowmap_size == 256
    assert resolve_variants(["raytrace-interlaced"])[0].settings.interlace is True
    with pytest.raises(HybridShadowError):
        resolve_variants(["shadowmap-1"])


def test_operator_background(tmp_path, monkeypatch):
    """The Blender operator, run at once in background mode, writes the same report, with
    neither OpenEXR nor matplotlib (Blender's own Python has neither)."""
    import bpy

    for name in ("OpenEXR", "matplotlib"):
        monkeypatch.setitem(sys.modules, name, None)

    from hybrid_shadow_addon.blender import compare_operator
    from hybrid_shadow_addon.blender.load import open_scene

    compare_operator.register()
    try:
        open_scene("cube_on_plane:width=160,height=120")
        out = tmp_path / "op"
        res = bpy.ops.render.hybrid_shadows_compare(output_dir=str(out), modes="raytrace-high,none", repeats=1,
                                                    resolution_percentage=50)
        assert res == {"FINISHED"}
        m = json.loads((out / "metrics.json").read_text())
        assert m["resolution"] == [80, 60] and (out / "report.html").is_file()
        assert (out / "error_vs_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert m["variants"][0]["overall"]["mismatch_pct"] <= 0.1
        assert bpy.context.scene.render.resolution_x == 160
        from hybrid_shadow_addon.blender.gl import final_renderer

        renderer = final_renderer()  # (the variants rendered there, not on this thread)
        assert renderer.starts == 1 and renderer.pid not in (None, os.getpid())
    finally:
        compare_operator.unregister()
        from hybrid_shadow_addon.blender.gl import release_shared

        release_shared()


def test_cancel_restores_the_scene(tmp_path):
    """A progress callback raising Cancelled stops the comparison; the user's scene is as before."""
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import CyclesReferenceProvider
    from hybrid_shadow_addon.blender.frames import current_scene
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.errors import Cancelled
    from hybrid_shadow_addon.tools.compare import run_compare

    scene = open_scene("cube_on_plane:width=40,height=30")
    before = (scene.render.engine, scene.render.film_transparent, scene.render.resolution_x)
    calls = []

    def progress(done, total, label):
        calls.append(label)
        raise Cancelled("cancelled")

    with pytest.raises(Cancelled):
        run_compare(current_scene(), tmp_path / "c", reference=CyclesReferenceProvider(scene), progress=progress,
                    use_cache=False)
    assert len(calls) == 1 and calls[0].startswith("Cycles reference")
    assert (scene.render.engine, scene.render.film_transparent, scene.render.resolution_x) == before
    assert not (tmp_path / "c" / "metrics.json").exists()
    assert bpy.context.scene is scene
