"""Bad input gives one clear line and exit code 2 from the CLI (``render`` and ``info``), and
leaves nothing half-written.

Decisions: a scene without lights renders (world colour only) with a warning line; an empty
scene (no mesh object) is an error for ``render`` (nothing to render) while ``info`` reports it
(bounds: empty); a zero-scale object is an error naming it (its transform has no inverse).
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.__main__ import main
from hybrid_shadow_addon.core.errors import GPUError

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
LIB = REPO / "test_scenes" / "_lib.py"

HEAD = f"""import runpy
L = runpy.run_path({str(LIB)!r})
scene = L["setup_scene"]("bad", (48, 32))
"""
CAMERA = 'L["add_camera"](scene, (5, -5, 4), (0, 0, 0))\n'
CUBE = 'L["add_object"]("Cube", L["box"]("Cube", (1, 1, 1)))\n'
SUN = 'L["add_sun"]("Sun", 45, 0)\n'

SCRIPTS = {
    "empty": CAMERA + SUN,
    "nocamera": CUBE + SUN,
    "nolights": CUBE + CAMERA,
    "nan": CUBE + 'ob = L["add_object"]("Broken", L["box"]("B", (1, 1, 1)))\n'
                  'ob.location = (float("nan"), 0, 0)\n' + SUN + CAMERA,
    "inf": CUBE + 'ob = L["add_object"]("Huge", L["box"]("H", (1, 1, 1)))\n'
                  'ob.scale = (float("inf"), 1, 1)\n' + SUN + CAMERA,
    "zero": CUBE + 'ob = L["add_object"]("Flat", L["box"]("F", (1, 1, 1)))\nob.scale = (1, 0, 1)\n' + SUN + CAMERA,
    "nanlight": CUBE + 'ob = L["add_sun"]("Bad sun", 45, 0)\nob.rotation_euler = (float("nan"), 0, 0)\n' + CAMERA,
    "lights": CUBE + "".join(f'L["add_light"]("P{i}", "POINT", location=({i}, 0, 3))\n' for i in range(5)) + CAMERA,
    "ok": CUBE + SUN + CAMERA,
}


@pytest.fixture
def script(tmp_path):
    def make(kind):
        p = tmp_path / f"{kind}.py"
        p.write_text(HEAD + SCRIPTS[kind])
        return str(p)
    return make


def run(capfd, *argv):
    code = main(list(argv))
    out, err = capfd.readouterr()
    return code, out, err


def error_lines(err: str) -> list:
    return [line for line in err.splitlines() if line.startswith("error:")]


def assert_one_line_error(code, err, *words):
    assert code == 2, err
    lines = error_lines(err)
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]


def outputs(tmp_path):
    return sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith(".py"))


@pytest.mark.parametrize("kind, words", [
    ("empty", ["'bad'", "empty"]),
    ("nocamera", ["no camera"]),
    ("nan", ["'Broken'", "NaN or infinite"]),
    ("inf", ["'Huge'", "infinite or absurd"]),
    ("zero", ["'Flat'", "zero scale"]),
    ("nanlight", ["'Bad sun'"]),
])
def test_render_rejects_bad_scenes_and_writes_nothing(kind, words, script, tmp_path, capfd):
    code, out, err = run(capfd, "render", script(kind), "--output", str(tmp_path / "out.png"),
                         "--masks-dir", str(tmp_path / "masks"), "--stats", str(tmp_path / "stats.json"))
    assert_one_line_error(code, err, *words)
    assert outputs(tmp_path) == []


@pytest.mark.parametrize("kind, words", [
    ("nocamera", ["no camera"]), ("nan", ["'Broken'"]), ("inf", ["'Huge'"]), ("zero", ["'Flat'"]),
])
def test_info_rejects_bad_scenes(kind, words, script, capfd):
    code, out, err = run(capfd, "info", script(kind), "--json")
    assert_one_line_error(code, err, *words)
    assert out == ""


def test_info_reports_an_empty_scene(script, capfd):
    code, out, err = run(capfd, "info", script("empty"))
    assert code == 0, err
    assert "bounds      empty" in out


def test_no_lights_renders_ambient_with_a_warning(script, tmp_path, capfd):
    out_path = tmp_path / "out.npy"
    code, out, err = run(capfd, "render", script("nolights"), "--output", str(out_path))
    assert code == 0, err
    assert sum("warning:" in line and "no lights" in line for line in err.splitlines()) == 1
    img = np.load(out_path)
    assert img.shape == (32, 48, 4) and np.isfinite(img).all()


def test_missing_egl_is_one_line_and_writes_nothing(script, tmp_path, capfd, monkeypatch):
    from hybrid_shadow_addon.core.gpu import context

    if not sys.platform.startswith("linux"):
        pytest.skip("EGL check is Linux only")
    monkeypatch.setattr(context, "_load_library", lambda name: name not in ("EGL", "GL"))
    monkeypatch.setenv("HYBRID_SHADOWS_RENDERER", "thread")  # (the libraries pretended missing here)
    code, out, err = run(capfd, "render", script("ok"), "--output", str(tmp_path / "out.png"),
                         "--masks-dir", str(tmp_path / "masks"))
    assert_one_line_error(code, err, "libEGL.so.1", "libGL.so.1", "apt-get install")
    assert outputs(tmp_path) == []


def test_more_lights_than_the_limit(script, tmp_path, capfd, monkeypatch, gl_ctx):
    from hybrid_shadow_addon.core.gpu import context

    limit = context.max_lights(gl_ctx)
    assert limit >= 1024
    with pytest.raises(GPUError, match=f"{limit + 1} lights.*at most {limit}"):
        context.check_light_count(gl_ctx, limit + 1)
    context.check_light_count(gl_ctx, limit)
    # through the CLI: pretend the light table allows only 3 lights
    monkeypatch.setattr(context, "LIGHT_TABLE_TEXELS", context.gpu_limits(gl_ctx)["max_texture_size"] // 3)
    monkeypatch.setenv("HYBRID_SHADOWS_RENDERER", "thread")  # (the limit pretended here)
    code, out, err = run(capfd, "render", script("lights"), "--output", str(tmp_path / "out.png"))
    assert_one_line_error(code, err, "5 lights", "at most 3")
    assert outputs(tmp_path) == []


def test_mesh_larger_than_one_texture_splits_into_layers(gl_ctx):
    """A 40k-triangle mesh with 4-texel-wide textures needs 2 layers of 16384 rows for its
    triangles: the GLSL tracer reads it exactly like the numpy one."""
    from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
    from hybrid_shadow_addon.core.oracle.tracer import trace_structured
    from hybrid_shadow_addon.core.scene import Instances, Model, Scene
    from tests.helpers.glsl import gl_trace

    rng = np.random.default_rng(0)
    n = 40000
    c = rng.uniform(-5, 5, (n, 1, 3))
    v = (c + rng.normal(scale=0.15, size=(n, 3, 3))).reshape(-1, 3)
    model = Model("big", v, np.arange(3 * n).reshape(-1, 3))
    scene = Scene(models=[model], instances=Instances(names=["big"], model_ids=[0], matrices=np.eye(4)[None]))
    baked = bake_scene(scene, BakeConfig(structure="grid", tex_width=4))
    assert baked.textures["tri"].layers > 1
    o = rng.uniform(-7, 7, (20000, 3))
    d = rng.normal(size=(20000, 3))
    ref = trace_structured(baked, o, d, np.inf)
    gl = gl_trace(gl_ctx, baked, o, d, np.inf)
    assert 0.05 < ref.mean() < 0.95
    assert (ref == gl).mean() >= 0.999


def test_a_limit_met_in_the_renderer_process_is_one_line(script, tmp_path, capfd, gl_ctx):
    """The command line renders in a renderer process: a GPU limit met there (a frame wider than
    the GPU's textures) comes back as the same one line, and nothing is written."""
    from hybrid_shadow_addon.core.gpu import context

    wide = context.gpu_limits(gl_ctx)["max_texture_size"] + 1
    code, out, err = run(capfd, "render", script("ok"), "--output", str(tmp_path / "out.png"),
                         "--resolution", f"{wide}x8")
    assert_one_line_error(code, err, f"{wide}x8", "outside this GPU's limits")
    assert outputs(tmp_path) == []


def test_textures_past_the_gpu_limits_fail_clearly(monkeypatch, gl_ctx):
    from hybrid_shadow_addon.core.bake import textures
    from hybrid_shadow_addon.core.bake.textures import TextureData
    from hybrid_shadow_addon.core.gpu.scene_textures import SceneTextures

    monkeypatch.setattr(textures, "MAX_LAYERS", 2)
    with pytest.raises(GPUError, match="scene too large for the GPU textures") as e:
        textures.texture_shape(3 * 16384 * 16, 16)
    assert "\n" not in str(e.value)
    # the GL limits are checked before allocating on the GPU
    layers = gl_ctx.info["GL_MAX_ARRAY_TEXTURE_LAYERS"] + 1
    fake = TextureData("tri", np.zeros((layers, 1, 4, 1), np.float32), "f4")  # tiny, but too many layers
    st = SceneTextures(gl_ctx)
    with pytest.raises(GPUError, match="this GPU allows"):
        st._create(fake)


def cli(*args):
    return subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=180)


@pytest.mark.parametrize("command", ["info", "render"])
def test_corrupted_blend(command, tmp_path):
    bad = tmp_path / "bad.blend"
    bad.write_bytes(b"BLENDER-v405 not really\x00" * 20)
    extra = ["--output", str(tmp_path / "out.png")] if command == "render" else []
    r = cli(command, str(bad), *extra)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert len(error_lines(r.stderr)) == 1 and "cannot open" in error_lines(r.stderr)[0]
    assert not (tmp_path / "out.png").exists()


@pytest.mark.parametrize("res, words", [("0x10", "at least 1"), ("100000x10", "outside this GPU's limits")])
def test_bad_resolution(res, words, tmp_path):
    r = cli("render", "cube_on_plane", "--resolution", res, "--output", str(tmp_path / "out.png"))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert words in r.stderr.strip().splitlines()[-1]
    assert list(tmp_path.iterdir()) == []


def test_bad_transparency_samples(tmp_path):
    r = cli("render", "cube_on_plane", "--transparency-samples", "0", "--output", str(tmp_path / "out.png"))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "transparency_samples must be between 1 and 4096" in r.stderr.strip().splitlines()[-1]
    assert list(tmp_path.iterdir()) == []


def test_render_transparency_samples_in_stats(tmp_path):
    """The see_through panes: 16 sub-frames by default, one with --transparency-samples 1."""
    import json

    for n, want in ((None, 16), (1, None)):
        extra = [] if n is None else ["--transparency-samples", str(n)]
        st = tmp_path / f"stats{n}.json"
        r = cli("render", "see_through", "--hard", "--quiet", "--output", str(tmp_path / f"out{n}.png"),
                "--stats", str(st), *extra)
        assert r.returncode == 0, r.stderr
        assert json.loads(st.read_text()).get("see_through_samples") == want
