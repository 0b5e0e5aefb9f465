"""Frame ranges: ``render --frames`` (tools/render.py ``render_frames``): one full bake then
incremental updates, frames equal to single-frame renders, per-frame all-or-nothing outputs,
resume, and the range and pattern rules."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools import render as R
from hybrid_shadow_addon.tools.render import FrameRangeError, frame_path, parse_frames

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
SCENE = "animated"
SETTINGS = Settings(mode="raytrace", quality="high", interlace=False)


# -- ranges and patterns ------------------------------------------------------------------------
@pytest.mark.parametrize("text, frames", [
    ("7", [7]), ("1-4", [1, 2, 3, 4]), ("1-10:3", [1, 4, 7, 10]), ("1..3", [1, 2, 3]),
    ("1-3, 8, 2-4", [1, 2, 3, 8, 4]), ("-2-1", [-2, -1, 0, 1]), (" 5 - 6 ", [5, 6]),
])
def test_parse_frames(text, frames):
    assert parse_frames(text) == frames


@pytest.mark.parametrize("text, words", [
    ("", "empty"), ("4-1", "ends before it starts"), ("1-4:0", "step"), ("a-b", "bad frame range"),
    ("1-4:", "bad frame range"), ("1-2-3", "bad frame range"), ("1,,2", "bad frame range"),
    ("1-99999999", "more than"),
])
def test_bad_frame_ranges(text, words):
    with pytest.raises(FrameRangeError, match=words):
        parse_frames(text)


@pytest.mark.parametrize("pattern, frame, path", [
    ("out/name_####.png", 7, "out/name_0007.png"),
    ("out/name_#.png", 12, "out/name_12.png"),
    ("out/a##_b###.exr", 5, "out/a##_b005.exr"),  # the last run of # in the file name
    ("out/##/name.png", 3, "out/##/name0003.png"),  # a # in a folder name is no frame number
    ("out/name.png", 3, "out/name0003.png"),  # no #: four digits before the extension
    ("out/name_####.npy", -3, "out/name_-0003.npy"),
])
def test_frame_path(pattern, frame, path):
    assert frame_path(pattern, frame) == path


# -- rendering ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def source():
    from hybrid_shadow_addon.blender.frames import BlenderFrames
    from hybrid_shadow_addon.blender.load import open_scene

    return BlenderFrames(open_scene(SCENE))


def png(path):
    from PIL import Image

    return np.asarray(Image.open(path))


def test_animation_bakes_once_and_equals_single_frames(tmp_path, source, pipeline):
    calls = []
    r = R.render_frames(source, [1, 2, 3, 4], SETTINGS, output=str(tmp_path / "a_####.png"),
                        stats_path=str(tmp_path / "stats.json"), masks_dir=str(tmp_path / "masks"),
                        pipeline=pipeline, progress=lambda d, t, label: calls.append((d, t)))
    assert r["rendered"] == 4 and r["skipped"] == 0
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert [e["frame"] for e in stats] == [1, 2, 3, 4]
    assert [e["bake"] for e in stats] == ["full", "incremental", "incremental", "incremental"]
    for e in stats:
        for k in ("bake_ms", "gbuffer_ms", "shadow_ms", "upsample_ms", "lighting_ms", "readback_ms", "total_ms"):
            assert isinstance(e[k], float) and e[k] >= 0, k
        assert e["bake_updates"]["instances"] == (0 if e["frame"] == 1 else 1)
    assert calls[0] == (0, 4) and calls[-1] == (4, 4)
    images = [png(tmp_path / f"a_{f:04d}.png") for f in (1, 2, 3, 4)]
    assert (images[0] != images[3]).any(axis=-1).sum() > 500  # the cube moves
    for f in (1, 3, 4):
        source.bscene.frame_set(f)
        from hybrid_shadow_addon.blender.frames import current_scene

        single = tmp_path / f"single_{f}.png"
        R.render_to_files(current_scene(), SETTINGS, output=str(single), masks_dir=str(tmp_path / f"sm{f}"),
                          pipeline=pipeline)
        np.testing.assert_array_equal(images[f - 1], png(single), err_msg=f"frame {f}")
        for m in (tmp_path / f"sm{f}").glob("mask_*.npy"):
            np.testing.assert_array_equal(np.load(tmp_path / "masks" / f"{f:04d}" / m.name), np.load(m))


def test_resume_skips_written_frames(tmp_path, source, pipeline):
    out = str(tmp_path / "r_##.png")
    stats = str(tmp_path / "stats.json")
    R.render_frames(source, [1, 2, 3, 4], SETTINGS, output=out, stats_path=stats, pipeline=pipeline)
    os.unlink(tmp_path / "r_03.png")
    before = {f: os.stat(tmp_path / f"r_0{f}.png").st_mtime_ns for f in (1, 2, 4)}
    r = R.render_frames(source, [1, 2, 3, 4], SETTINGS, output=out, stats_path=stats, pipeline=pipeline)
    assert r["rendered"] == 1 and r["skipped"] == 3
    assert {f: os.stat(tmp_path / f"r_0{f}.png").st_mtime_ns for f in (1, 2, 4)} == before
    entries = json.loads(Path(stats).read_text())
    assert [e["frame"] for e in entries] == [1, 2, 3, 4]
    assert [e.get("skipped", False) for e in entries] == [True, True, False, True]
    assert entries[2]["bake"] == "full"  # the first frame this run renders
    assert entries[1]["bake"] == "incremental" and "gbuffer_ms" in entries[1]  # kept from the first run
    r = R.render_frames(source, [1, 2, 3, 4], SETTINGS, output=out, pipeline=pipeline, overwrite=True)
    assert r["rendered"] == 4


def test_a_failing_frame_leaves_no_partial_files(tmp_path, source, pipeline, monkeypatch):
    real = R.write_image
    count = {"n": 0}

    def flaky(path, rgba):
        count["n"] += 1
        if count["n"] == 2:
            Path(path).write_bytes(b"half")
            raise OSError("disk full")
        real(path, rgba)

    monkeypatch.setattr(R, "write_image", flaky)
    with pytest.raises(OSError, match="disk full"):
        R.render_frames(source, [1, 2, 3], SETTINGS, output=str(tmp_path / "f_####.png"),
                        stats_path=str(tmp_path / "stats.json"), pipeline=pipeline)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0001.png", "stats.json"]
    assert [e["frame"] for e in json.loads((tmp_path / "stats.json").read_text())] == [1]


def test_shadowmap_frames_bake_nothing(tmp_path, source, pipeline):
    r = R.render_frames(source, [1, 2], Settings(mode="shadowmap", interlace=False), pipeline=pipeline,
                        output=str(tmp_path / "s_####.npy"))
    assert [e["bake"] for e in r["frames"]] == ["none", "none"]
    assert np.load(tmp_path / "s_0002.npy").shape == (120, 160, 4)


# -- the CLI ------------------------------------------------------------------------------------
def cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=180)


def test_cli_frames_with_step(tmp_path):
    p = cli("render", SCENE, "--frames", "1-4:2", "--output", str(tmp_path / "c_####.png"),
            "--stats", str(tmp_path / "s.json"))
    assert p.returncode == 0, p.stderr
    assert sorted(x.name for x in tmp_path.glob("c_*.png")) == ["c_0001.png", "c_0003.png"]
    assert [e["bake"] for e in json.loads((tmp_path / "s.json").read_text())] == ["full", "incremental"]
    assert "rendered 2 frames" in p.stdout and "1 full, 1 incremental" in p.stdout
    assert "2/2" in p.stderr  # the progress bar
    p = cli("render", SCENE, "--frames", "1-4:2", "--output", str(tmp_path / "c_####.png"))
    assert p.returncode == 0 and "2 skipped" in p.stdout


@pytest.mark.parametrize("args, words", [
    (["--frames", "5-1"], "ends before it starts"),
    (["--frames", "1-x"], "bad frame range"),
    (["--frames", "1-3", "--frame", "2"], "not both"),
])
def test_cli_bad_frames_is_one_clear_error(tmp_path, args, words):
    p = cli("render", SCENE, *args, "--output", str(tmp_path / "x_####.png"))
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and lines[0].startswith("error:"), p.stderr
    assert not list(tmp_path.iterdir())


def test_frames_reuse_hard_masks_when_told_to(tmp_path, source, pipeline):
    """Later frames keep the hard masks' pixels that no moved object can touch (``pixels_reused``,
    fewer ``rays_traced``), within the reuse's bound of fresh masks, with ``reuse=True`` (``--reuse``);
    by default they are traced whole; the stats say soft lights take their own samples."""
    kw = dict(pipeline=pipeline, overwrite=True)
    hard = SETTINGS.replace(hard=True)
    on = R.render_frames(source, [1, 2, 3], hard, output=str(tmp_path / "on_#.png"),
                         masks_dir=str(tmp_path / "on"), reuse=True, **kw)["frames"]
    off = R.render_frames(source, [1, 2, 3], hard, output=str(tmp_path / "off_#.png"),
                          masks_dir=str(tmp_path / "off"), **kw)["frames"]
    assert not pipeline.reuse  # (the pipeline's own setting again after)
    assert on[0]["pixels_reused"] == 0 and all(e["pixels_reused"] > 0 for e in on[1:])
    assert all(e["pixels_reused"] == 0 for e in off)
    assert [e["reuse"]["hard"] for e in on] == [False, True, True] and not any(e["reuse"]["hard"] for e in off)
    assert all(e["reuse"]["soft"] == "own samples" for e in on + off)
    for a, b in zip(on[1:], off[1:]):
        assert a["rays_traced"] < b["rays_traced"]
    bad = valid = 0
    for m in (tmp_path / "off").glob("*/mask_*.npy"):
        fresh, reused = np.load(m), np.load(tmp_path / "on" / m.parent.name / m.name)
        ok = np.isfinite(fresh)
        bad += int((np.abs(fresh - reused)[ok] > 1e-3).sum())
        valid += int(ok.sum())
    assert valid and bad <= 0.0002 * valid + 1, (bad, valid)
