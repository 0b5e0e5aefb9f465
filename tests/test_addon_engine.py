"""The installed extension as a render engine, headless: build the zip, install and enable it with
``bpy.ops.extensions.package_install_files``, F12-render a small forest in each shadow mode,
compare the shadow passes with the CLI's masks, disable the add-on, exit without hanging.

The bpy work runs in a subprocess (``python tests/test_addon_engine.py OUT``) so the add-on's
registration never outlives it inside the pytest process; it writes multilayer EXRs and a JSON
report that the tests below read.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
SCENE = "forest:trees=20,spheres=6,variants=2,terrain=64,width=160,height=120"
MODES = ("RAYTRACE", "SHADOWMAP", "NONE")
EXT_MODULE = "bl_ext.user_default.hybrid_shadows"


def read_exr(path) -> dict:
    """Multilayer EXR → {pass name: (H, W) or (H, W, C) float32}, rows top-down."""
    import OpenEXR

    out = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:  # one part (Blender 4.x) or one per pass (5.x)
            for key, ch in part.channels.items():
                parts = key.split(".")
                name, comp = ".".join(parts[1:-1]), parts[-1]
                out.setdefault(name, {})[comp] = np.asarray(ch.pixels, np.float32)
    order = {"Combined": "RGBA", "Normal": "XYZ", "Albedo": "RGB"}
    res = {}
    for name, comps in out.items():
        if len(comps) == 1:
            res[name] = next(iter(comps.values()))
        else:
            res[name] = np.stack([comps[c] for c in order.get(name, sorted(comps))], axis=-1)
    return res


# ------------------------------------------------------------------------------------------------
# The bpy side (runs in the subprocess)
# ------------------------------------------------------------------------------------------------
def engine_selectable(scene) -> bool:
    """Registered engines are not in bpy.types: try selecting it (and restore)."""
    old = scene.render.engine
    try:
        scene.render.engine = "HYBRID_SHADOWS"
    except TypeError:
        return False
    scene.render.engine = old
    return True


def driver(out_dir: str, zip_path: str) -> None:
    import bpy

    from hybrid_shadow_addon.blender.load import open_scene

    out = Path(out_dir)
    report = {}
    scene = open_scene(SCENE)  # factory settings first: they would reset the preferences
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    report["enabled"] = EXT_MODULE in bpy.context.preferences.addons
    report["engine_listed"] = engine_selectable(scene)
    try:
        scene.render.engine = "HYBRID_SHADOWS"
        vl = scene.view_layers[0]
        report["pass_defaults"] = {"shadow": vl.hybrid_shadows.use_pass_shadow,
                                   "albedo": vl.hybrid_shadows.use_pass_albedo}
        vl.hybrid_shadows.use_pass_shadow = vl.hybrid_shadows.use_pass_albedo = True
        vl.use_pass_z = True
        vl.use_pass_normal = True
        props = scene.hybrid_shadows
        report["defaults"] = {"max_shadowed_lights": props.max_shadowed_lights,
                              "viewport_max_shadowed_lights": props.viewport_max_shadowed_lights}
        report["undescribed"] = [
            f"{owner}.{p.identifier}" for owner, rna in (("scene", type(props).bl_rna),
                                                         ("view_layer", type(vl.hybrid_shadows).bl_rna))
            for p in rna.properties if p.identifier not in ("rna_type", "name") and not p.description]
        if not bpy.types.Object.bl_rna.properties["hybrid_sphere"].description:
            report["undescribed"].append("object.hybrid_sphere")
        from bl_ui.properties_data_light import DATA_PT_light

        report["light_panel_compat"] = "HYBRID_SHADOWS" in DATA_PT_light.COMPAT_ENGINES
        if hasattr(scene.render.image_settings, "media_type"):  # Blender 5.0+
            scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
        scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
        scene.render.image_settings.color_depth = "32"
        for mode in MODES:
            props.mode = mode
            bpy.ops.render.render()
            bpy.data.images["Render Result"].save_render(str(out / f"{mode}.exr"))
        # Compare with Cycles from the installed extension, as in Blender's own Python (neither
        # OpenEXR nor matplotlib): a real (tiny) run; then one with no EXR reader at all, which
        # must fail with one clear message
        blocked = ("OpenEXR", "matplotlib")
        saved = {n: sys.modules.get(n) for n in blocked + ("OpenImageIO",)}
        try:
            for n in blocked:
                sys.modules[n] = None  # as if the package were not installed
            compare_dir = out / "compare"
            bpy.ops.render.hybrid_shadows_compare(output_dir=str(compare_dir), modes="raytrace-high,none",
                                                  repeats=1, resolution_percentage=25, open_report=False)
            report["compare_files"] = sorted(p.name for p in compare_dir.iterdir())
            sys.modules["OpenImageIO"] = None
            try:
                bpy.ops.render.hybrid_shadows_compare(output_dir=str(out / "compare_missing"), open_report=False)
                report["compare_missing"] = None
            except RuntimeError as exc:
                report["compare_missing"] = str(exc)
        finally:
            for n, module in saved.items():
                if module is None:
                    sys.modules.pop(n, None)
                else:
                    sys.modules[n] = module
        report["compare_missing_wrote"] = (out / "compare_missing").exists()
        # a failure: a zero-scale object is reported by name, as an error of the render
        bpy.data.objects["Ball.001"].scale = (0, 0, 0)
        try:
            bpy.ops.render.render()
            report["error"] = None
        except RuntimeError as exc:
            report["error"] = str(exc)
    finally:
        bpy.ops.preferences.addon_disable(module=EXT_MODULE)
    panel_names = ("RENDER_PT_hybrid_shadows", "RENDER_PT_hybrid_shadows_debug", "OBJECT_PT_hybrid_shadows",
                   "DATA_PT_hybrid_shadows_light", "VIEWLAYER_PT_hybrid_shadows_passes")
    report["after_disable"] = {
        "engine_listed": engine_selectable(scene),
        "scene_property": hasattr(bpy.types.Scene, "hybrid_shadows"),
        "object_property": hasattr(bpy.types.Object, "hybrid_sphere"),
        "panels": [n for n in panel_names if hasattr(bpy.types, n)],
        "light_panel_compat": "HYBRID_SHADOWS" in DATA_PT_light.COMPAT_ENGINES,
    }
    (out / "report.json").write_text(json.dumps(report, indent=1))


# ------------------------------------------------------------------------------------------------
# pytest side
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from tests.helpers.blender_env import isolated_env

    tmp = tmp_path_factory.mktemp("addon")
    env = isolated_env(tmp)
    build = subprocess.run([PY, "-m", "tools.build_extension", "--platform", "linux-x64"],
                           cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    zip_path = REPO / "dist/hybrid_shadows-0.1.0-linux_x64.zip"
    assert zip_path.is_file()
    proc = subprocess.run([PY, __file__, str(tmp), str(zip_path)], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    masks = {}
    for mode in MODES:
        d = tmp / f"cli_{mode}"
        cli = subprocess.run([PY, "-m", "hybrid_shadow_addon", "render", SCENE, "--mode", mode.lower(),
                              "--output", str(tmp / f"cli_{mode}.npy"), "--masks-dir", str(d)],
                             cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
        assert cli.returncode == 0, cli.stderr
        masks[mode] = {p.name: np.load(p) for p in d.glob("mask_*.npy")}
    return {"tmp": tmp, "zip": zip_path, "report": json.loads((tmp / "report.json").read_text()),
            "exr": {m: read_exr(tmp / f"{m}.exr") for m in MODES}, "masks": masks, "log": proc.stdout}


def test_zip_layout(run):
    import zipfile

    names = zipfile.ZipFile(run["zip"]).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert any(n.startswith("hybrid_shadow_addon/blender/engine.py") for n in names)
    assert any(n.startswith("shaders/") for n in names)
    assert any(n.startswith("wheels/moderngl-") for n in names)
    assert not any(n.startswith(("tests/", "test_scenes/")) or "__pycache__" in n for n in names)


def test_zip_leaves_out_the_oracles(run):
    import zipfile

    names = zipfile.ZipFile(run["zip"]).namelist()
    assert any(n.startswith("hybrid_shadow_addon/core/gpu/") for n in names)
    assert not any(n.startswith("hybrid_shadow_addon/core/oracle") for n in names)


def test_compare_operator_from_the_installed_zip(run):
    r = run["report"]
    assert {"metrics.json", "report.html", "error_vs_time.png"} <= set(r["compare_files"]), r["compare_files"]
    msg = r["compare_missing"]
    assert msg is not None and "OpenImageIO" in msg and "pip" not in msg and "\n" not in msg.strip()
    assert not r["compare_missing_wrote"]


def test_shadow_and_albedo_passes_are_off_by_default(run):
    assert run["report"]["pass_defaults"] == {"shadow": False, "albedo": False}


def test_installed_and_enabled(run):
    r = run["report"]
    assert r["enabled"] and r["engine_listed"]
    assert r["light_panel_compat"]
    assert r["defaults"] == {"max_shadowed_lights": 0, "viewport_max_shadowed_lights": 4}
    assert r["undescribed"] == []


def test_passes_exist(run):
    for mode in MODES:
        layers = run["exr"][mode]
        assert {"Combined", "Depth", "Normal", "Albedo"} <= set(layers), sorted(layers)
        shadows = sorted(n for n in layers if n.startswith("Shadow "))
        assert shadows == sorted(f"Shadow {n}" for n in
                                 ("Dawn sun", "Lantern.0", "Lantern.1", "Lantern.2", "Spot.0", "Spot.1"))
        assert layers["Combined"].shape == (120, 160, 4)
        assert np.isfinite(layers["Combined"]).all()


def test_progress_reported(run):
    assert "Ray tracing shadows: Dawn sun" in run["log"]
    assert "Shadow map: Dawn sun" in run["log"]


@pytest.mark.parametrize("mode", MODES)
def test_shadow_passes_equal_cli_masks(run, mode):
    layers = run["exr"][mode]
    cli = run["masks"][mode]
    assert cli, "the CLI wrote no masks"
    for fname, mask in cli.items():
        light = fname[len("mask_"):-len(".npy")]
        got = layers[f"Shadow {light}"]
        valid = ~np.isnan(mask)
        assert valid.sum() > 1000
        np.testing.assert_allclose(got[valid], mask[valid], atol=1e-6, err_msg=f"{mode} {light}")
        assert (got[~valid] == 1.0).all()  # no geometry: written as lit


def test_shadow_mode_changes_image(run):
    c = {m: run["exr"][m]["Combined"] for m in MODES}
    assert np.abs(c["RAYTRACE"] - c["NONE"]).max() > 0.05
    assert np.abs(c["SHADOWMAP"] - c["NONE"]).max() > 0.05
    shadowed = sum(float((run["exr"]["RAYTRACE"][n] < 0.5).mean()) for n in run["exr"]["RAYTRACE"]
                   if n.startswith("Shadow "))
    assert shadowed > 0.01


def test_depth_and_normal(run):
    layers = run["exr"]["RAYTRACE"]
    d = layers["Depth"]
    geo = d < 1e9
    assert geo.mean() > 0.3 and (d[geo] > 0).all()
    n = layers["Normal"][geo]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=0.02)


def test_error_is_reported(run):
    err = run["report"]["error"]
    assert err is not None and "Ball.001" in err


def test_disable_unregisters_everything(run):
    after = run["report"]["after_disable"]
    assert after == {"engine_listed": False, "scene_property": False, "object_property": False,
                     "panels": [], "light_panel_compat": False}


if __name__ == "__main__":
    driver(sys.argv[1], sys.argv[2])
