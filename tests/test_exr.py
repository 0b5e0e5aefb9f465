"""EXRs through the OpenImageIO module Blender ships, with OpenEXR and matplotlib unavailable:
a multilayer EXR written by Cycles reads as OpenEXR reads it, the CLI's EXR round-trips, and
the compare report's plot is drawn with numpy alone."""
import sys

import numpy as np
import pytest

from hybrid_shadow_addon.tools import exr


@pytest.fixture
def no_openexr(monkeypatch):
    """As if OpenEXR and matplotlib were not installed (Blender's own Python)."""
    for name in ("OpenEXR", "matplotlib"):
        monkeypatch.setitem(sys.modules, name, None)


def test_group_channels_joins_colour_layers_only():
    names = ["L.Combined.R", "L.Combined.G", "L.Combined.B", "L.Combined.A", "L.Position.X", "L.Position.Y",
             "L.DiffDir.R", "L.DiffDir.G", "L.DiffDir.B"]
    px = np.arange(2 * 3 * len(names), dtype=np.float32).reshape(2, 3, len(names))
    out = exr.group_channels(names, px)
    assert list(out) == ["L.Combined", "L.Position.X", "L.Position.Y", "L.DiffDir"]
    assert out["L.Combined"].shape == (2, 3, 4) and np.array_equal(out["L.Combined"], px[..., :4])
    assert np.array_equal(out["L.Position.Y"], px[..., 5]) and np.array_equal(out["L.DiffDir"], px[..., 6:])


@pytest.mark.blender
def test_image_io_found_in_the_bpy_package(no_openexr):
    import bpy  # noqa: F401

    oiio = exr.open_image_io()
    assert oiio is not None and hasattr(oiio, "ImageInput")
    assert exr.can_read_exr()


@pytest.mark.blender
def test_exr_round_trip_without_openexr(tmp_path, no_openexr):
    import bpy  # noqa: F401

    rgba = np.random.default_rng(1).random((5, 7, 4), dtype=np.float32)
    rgba[0, 0] = (4.0, -1.0, 0.5, 1.0)
    exr.write_exr(str(tmp_path / "a.exr"), rgba)
    back = exr.read_exr(str(tmp_path / "a.exr"))
    assert list(back) == ["RGBA"] and np.array_equal(back["RGBA"], rgba)


@pytest.mark.blender
@pytest.mark.cycles
def test_cycles_multilayer_exr_through_image_io(tmp_path, monkeypatch):
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import _configure, _normal, _position, _Saved
    from hybrid_shadow_addon.blender.load import open_scene

    scene = open_scene("cube_on_plane")
    path = str(tmp_path / "ref.exr")
    saved = _Saved()
    try:
        _configure(scene, saved, (40, 30), 1, path)
        bpy.ops.render.render(write_still=True, scene=scene.name)
    finally:
        saved.restore()
    try:
        import OpenEXR
        expected = exr._read_openexr(OpenEXR, path)
    except ImportError:
        expected = None
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    channels = exr.read_exr(path)
    combined = next(v for k, v in channels.items() if k.endswith(".Combined"))
    assert combined.shape == (30, 40, 4) and (combined[..., 3] == 1).mean() > 0.5
    pos, nrm = _position(channels), _normal(channels)
    assert pos.shape == nrm.shape == (30, 40, 3)
    covered = combined[..., 3] == 1
    assert np.allclose(np.linalg.norm(nrm[covered], axis=-1), 1, atol=1e-3)
    if expected is not None:  # the same names, shapes and values as OpenEXR's reader
        assert list(channels) == list(expected)
        for k, v in expected.items():
            assert np.array_equal(channels[k], v, equal_nan=True), k


def _metrics(soft: bool) -> dict:
    def row(mode, ms, err, pareto):
        return {"label": f"{mode} {ms}", "total_ms": ms, "settings": {"mode": mode}, "pareto": pareto,
                "overall": {"mismatch_pct": err, "mae": err / 100, "off_pct": err}}

    return {"soft": soft, "threshold": 0.5, "scene": "s", "resolution": [80, 60], "lights": ["L"],
            "reference": {"total_ms": 900.0},
            "variants": [row("raytrace", 40.0, 0.0, True), row("shadowmap", 8.0, 3.0, True),
                         row("none", 2.0, 40.0, False)]}


@pytest.mark.parametrize("soft", [False, True])
def test_plot_without_matplotlib(tmp_path, no_openexr, soft):
    from hybrid_shadow_addon.tools.report import plot_error_vs_time

    path = tmp_path / "error_vs_time.png"
    plot_error_vs_time(_metrics(soft), path)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    import struct
    import zlib

    w, h = struct.unpack(">II", data[16:24])
    assert w == (2 if soft else 1) * 560 and h == 360
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    px = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 3 * w)[:, 1:].reshape(h, w, 3)
    for colour in ((214, 39, 40), (31, 119, 180), (127, 127, 127), (44, 160, 44)):  # each mode; Cycles
        assert (px == colour).all(-1).sum() > 10, colour
