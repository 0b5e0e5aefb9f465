"""Final renders through the engine (bpy in a subprocess): a render border, cropped or not,
fills exactly the border's pixels with what a full render has there; shadow passes follow the
view layer's own lights and keep Blender's 63-byte pass names without splitting a character; two
view layers render each from its own objects into its own layer."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
BORDER = (0.23, 0.71, 0.12, 0.64)  # min x, max x, min y, max y
W, H = 96, 64


def driver(out_dir: str) -> None:
    import bpy

    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender import final_render
    from hybrid_shadow_addon.blender.load import open_scene

    out = Path(out_dir)
    report = {}
    sc = open_scene("cube_on_plane")
    hybrid_shadow_addon.register()
    try:
        sc.render.engine = "HYBRID_SHADOWS"
        sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = W, H, 100
        vl = sc.view_layers[0]
        vl.hybrid_shadows.use_pass_shadow = True
        captured = {}
        orig = final_render.write_result

        def spy(engine, core, frame, scene, view_layer, width, height):
            captured["full"] = frame.image.copy()
            captured["region"] = final_render.border_region(scene, width, height)
            orig(engine, core, frame, scene, view_layer, width, height)
            captured["combined"] = None

        final_render.write_result = spy
        for crop in (False, True):
            sc.render.use_border = True
            sc.render.border_min_x, sc.render.border_max_x, sc.render.border_min_y, sc.render.border_max_y = BORDER
            sc.render.use_crop_to_border = crop
            bpy.ops.render.render()
            img = bpy.data.images["Render Result"]
            path = out / f"border_{int(crop)}.exr"
            sc.render.image_settings.file_format = "OPEN_EXR"
            img.save_render(str(path))
            np.save(out / f"full_{int(crop)}.npy", captured["full"])
            report[f"region_{int(crop)}"] = list(captured["region"])
        final_render.write_result = orig
        sc.render.use_border = False
        # pass names: a long multi-byte light name, two lights whose cut names collide, and a light
        # in a collection excluded from the view layer
        light = next(o for o in sc.objects if o.type == "LIGHT")
        light.name = "Lumière " + "é" * 40
        twin = light.copy()
        twin.name = "Lumière " + "é" * 41
        sc.collection.objects.link(twin)
        hidden = bpy.data.collections.new("excluded")
        sc.collection.children.link(hidden)
        other = light.copy()
        other.name = "Elsewhere"
        hidden.objects.link(other)
        vl.layer_collection.children["excluded"].exclude = True
        vl.update()
        layout = final_render.pass_layout(sc, vl)
        report["shadow_passes"] = [n for n, *_ in layout if n.startswith("Shadow ")]
        bpy.ops.render.render()
        # two view layers: a pillar in a collection the second layer excludes; one F12 renders
        # both, each from its own objects, into its own layer of the multilayer EXR
        hidden_pillar = bpy.data.collections.new("pillar")
        sc.collection.children.link(hidden_pillar)
        cube = next(o for o in sc.objects if o.type == "MESH" and "Cube" in o.name)
        pillar = cube.copy()
        pillar.name = "Pillar"
        pillar.location = (cube.location[0] - 1.2, cube.location[1] + 0.8, cube.location[2])
        hidden_pillar.objects.link(pillar)
        second = sc.view_layers.new("Without Pillar")
        second.layer_collection.children["pillar"].exclude = True
        second.layer_collection.children["excluded"].exclude = True
        for layer in sc.view_layers:
            layer.use = True
        layers = {}

        def spy_layers(engine, core, frame, scene, view_layer, width, height):
            layers[view_layer.name] = {"instances": sorted(core.instances.names)}
            np.save(out / f"layer_{len(layers)}.npy", frame.image)
            layers[view_layer.name]["image"] = f"layer_{len(layers)}.npy"
            orig(engine, core, frame, scene, view_layer, width, height)

        final_render.write_result = spy_layers
        im = sc.render.image_settings
        if hasattr(im, "media_type"):  # Blender 5.x
            im.media_type = "MULTI_LAYER_IMAGE"
        else:
            im.file_format = "OPEN_EXR_MULTILAYER"
        sc.render.filepath = str(out / "layers.exr")
        bpy.ops.render.render(write_still=True)
        final_render.write_result = orig
        report["layers"] = layers
        report["layers_exr"] = str(out / "layers.exr")
    finally:
        hybrid_shadow_addon.unregister()
    (out / "report.json").write_text(json.dumps(report))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from tests.helpers.blender_env import checkout_env

    tmp = tmp_path_factory.mktemp("border")
    proc = subprocess.run([sys.executable, __file__, str(tmp)], env=checkout_env(), capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return tmp, json.loads((tmp / "report.json").read_text())


def _read_exr(path):
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=False) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                if name.endswith("RGBA") or name == "RGBA":
                    return np.asarray(ch.pixels, np.float32)
    raise KeyError(path)


@pytest.mark.parametrize("crop", [False, True])
def test_border_render_fills_the_border(run, crop):
    tmp, report = run
    x0, y0, w, h = report[f"region_{int(crop)}"]
    assert (x0, w) == (int(BORDER[0] * W), int(BORDER[1] * W) - int(BORDER[0] * W))
    assert (y0, h) == (int(BORDER[2] * H), int(BORDER[3] * H) - int(BORDER[2] * H))
    img = _read_exr(tmp / f"border_{int(crop)}.exr")  # rows top-down
    full = np.load(tmp / f"full_{int(crop)}.npy")  # the frame the engine rendered, top-down
    rows = slice(H - (y0 + h), H - y0)
    want = full[rows, x0:x0 + w]
    if crop:
        assert img.shape[:2] == (h, w)
        got = img
    else:
        assert img.shape[:2] == (H, W)
        got = img[rows, x0:x0 + w]
        outside = np.ones((H, W), bool)
        outside[rows, x0:x0 + w] = False
        assert np.all(img[outside][:, 3] == 0)  # nothing rendered outside the border
    assert np.allclose(got, want, atol=1e-6)


def test_shadow_pass_names(run):
    names = run[1]["shadow_passes"]
    assert not any("Elsewhere" in n for n in names)  # its collection is excluded from the layer
    assert len(names) == len(set(names)) == 2
    for n in names:
        assert len(n.encode("utf-8")) <= 63
        n.encode("utf-8").decode("utf-8")  # whole characters only
    assert any(n.endswith(".001") for n in names)


def test_view_layers_render_their_own_objects(run):
    """An F12 with two view layers renders each from its own objects into its own EXR layer."""
    import OpenEXR

    tmp, report = run
    layers = report["layers"]
    assert sorted(layers) == ["ViewLayer", "Without Pillar"], sorted(layers)
    assert "Pillar" in layers["ViewLayer"]["instances"]
    assert "Pillar" not in layers["Without Pillar"]["instances"]
    got = {}
    with OpenEXR.File(report["layers_exr"], separate_channels=True) as f:
        for part in f.parts:
            for key, ch in part.channels.items():
                bits = key.split(".")
                if len(bits) >= 3 and bits[-2] == "Combined":
                    got.setdefault(".".join(bits[:-2]), {})[bits[-1]] = np.asarray(ch.pixels, np.float32)
    assert set(layers) <= set(got), sorted(got)
    images = {}
    for name, info in layers.items():
        want = np.load(tmp / info["image"])
        rgba = np.stack([got[name][c] for c in "RGBA"], axis=-1)
        assert rgba.shape == want.shape
        assert np.allclose(rgba, want, atol=1e-5), name
        images[name] = want
    differ = np.abs(images["ViewLayer"] - images["Without Pillar"]).max(axis=-1) > 1e-3
    assert differ.mean() > 0.01  # the pillar and its shadow are only in the first layer


if __name__ == "__main__":
    driver(sys.argv[1])
