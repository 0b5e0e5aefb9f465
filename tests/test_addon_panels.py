"""The Light, Material and World panels of the engine draw what the export reads (drawn with a
stub layout that records the RNA paths), poll only for this engine; light exposure, temperature
and area normalisation reach the exported power and colour as Cycles emits them."""
import math

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender import ui
from hybrid_shadow_addon.blender.export.lights import export_light

pytestmark = [pytest.mark.blender]

ENGINE = "HYBRID_SHADOWS"


class StubLayout:
    """Records ``prop(data, name)`` calls; every sub-layout records into the same list."""

    def __init__(self, drawn=None):
        self.drawn = [] if drawn is None else drawn
        self.use_property_split = self.use_property_decorate = self.active = False

    def prop(self, data, name, **kw):
        assert hasattr(data, name), (data, name)
        owner = getattr(data, "identifier", None) or getattr(data, "name", "")
        self.drawn.append((owner, name))

    def _sub(self, *a, **kw):
        return StubLayout(self.drawn)

    row = column = split = box = _sub

    def label(self, **kw):
        self.drawn.append(("label", kw.get("text", "")))

    def separator(self, **kw):
        pass

    def operator(self, *a, **kw):
        return None

    def template_list(self, *a, **kw):
        self.drawn.append(("template_list", a[0]))

    def template_ID(self, data, name, **kw):  # noqa: N802 - Blender's UILayout method
        self.drawn.append(("template_ID", name))


class Ctx:
    def __init__(self, engine=ENGINE, **kw):
        self.engine = engine
        self.light = self.material = self.world = self.object = self.material_slot = None
        self.__dict__.update(kw)


def draw(panel, context):
    holder = type("P", (), {})()
    holder.layout = StubLayout()
    holder.split_layout = lambda: holder.layout
    assert panel.poll(context)
    panel.draw(holder, context)
    return holder.layout.drawn


@pytest.fixture
def empty():
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.mark.parametrize("kind,expected", [
    ("SUN", {"color", "energy", "angle"}),
    ("POINT", {"color", "energy", "shadow_soft_size"}),
    ("SPOT", {"color", "energy", "shadow_soft_size", "spot_size", "spot_blend"}),
    ("AREA", {"color", "energy", "shape", "size", "size_y"}),
])
def test_light_panel_draws_what_the_export_reads(empty, kind, expected):
    light = bpy.data.lights.new("L", kind)
    if kind == "AREA":
        light.shape = "RECTANGLE"
    names = {n for _, n in draw(ui.DATA_PT_hybrid_shadows_light_settings, Ctx(light=light))}
    assert expected <= names
    if hasattr(light, "exposure"):
        assert "exposure" in names
    if hasattr(light, "use_temperature"):
        assert {"use_temperature", "temperature"} <= names
    assert not ui.DATA_PT_hybrid_shadows_light_settings.poll(Ctx(engine="CYCLES", light=light))
    assert ("label", "Hybrid shadows are hard: the size only affects shading") not in draw(
        ui.DATA_PT_hybrid_shadows_light, Ctx(light=light, scene=SceneStub()))


class SceneStub:
    """A scene whose ``hybrid_shadows`` holds the engine's defaults (the add-on is not
    registered in this process)."""

    def __init__(self, mode="RAYTRACE", use_soft_shadows=True, samples=64):
        from types import SimpleNamespace

        self.hybrid_shadows = SimpleNamespace(mode=mode, use_soft_shadows=use_soft_shadows, samples=samples,
                                              identifier="hybrid_shadows")


@pytest.mark.parametrize("kind,size", [("SUN", "angle"), ("POINT", "shadow_soft_size"),
                                       ("SPOT", "shadow_soft_size"), ("AREA", "size")])
def test_light_shadow_panel_says_soft_or_hard_as_the_engine_does(empty, kind, size):
    """Soft shadows are on by default: a light with a size is soft, said with the samples; hard
    only with Soft Shadows off or a size of 0; the scene's Soft Shadows switch is drawn."""
    light = bpy.data.lights.new("L", kind)
    setattr(light, size, 0.3)
    drawn = draw(ui.DATA_PT_hybrid_shadows_light, Ctx(light=light, scene=SceneStub()))
    labels = [n for o, n in drawn if o == "label"]
    assert labels == ["Soft: up to 64 shadow rays per pixel over the light's "
                      + ui.LIGHT_SIZE[kind][1]], labels
    assert "use_soft_shadows" in {n for _, n in drawn}
    assert ui.shadow_note(light, SceneStub(mode="SHADOWMAP").hybrid_shadows).startswith("Soft: shadow maps")
    off = ui.shadow_note(light, SceneStub(use_soft_shadows=False).hybrid_shadows)
    assert off.startswith("Hard") and "Soft Shadows is off" in off
    assert ui.shadow_note(light, SceneStub(mode="NONE").hybrid_shadows).startswith("No shadows")
    assert ui.shadow_note(light, SceneStub(mode="SHADOWMAP", use_soft_shadows=False).hybrid_shadows).startswith(
        "Hard (PCF")
    setattr(light, size, 0.0)
    assert ui.shadow_note(light, SceneStub().hybrid_shadows).startswith("Hard")
    light.use_shadow = False
    assert ui.shadow_note(light, SceneStub().hybrid_shadows) == "Casts no shadow"


def test_material_settings_show_transparent_shadows(empty):
    """Material ▸ Settings draws the property the export reads for transparent shadows."""
    from hybrid_shadow_addon.blender.export.materials import blend_settings

    mat = bpy.data.materials.new("M")
    names = {n for _, n in draw(ui.MATERIAL_PT_hybrid_shadows_settings, Ctx(material=mat))}
    prop = "use_transparent_shadow" if hasattr(mat, "use_transparent_shadow") else "shadow_method"
    assert prop in names
    if prop == "use_transparent_shadow":
        mat.use_transparent_shadow = False
        assert blend_settings(mat)[2] is False
    assert not ui.MATERIAL_PT_hybrid_shadows_settings.poll(Ctx(engine="CYCLES", material=mat))


#: stock panels the engine reads nothing of: never enabled for it
NOT_READ = {"RENDER_PT_freestyle", "VIEWLAYER_PT_freestyle", "RENDER_PT_stereoscopy", "DATA_PT_camera_stereoscopy",
            "RENDER_PT_output_views", "DATA_PT_lightprobe", "DATA_PT_context_lightprobe", "DATA_PT_volume_render",
            "RENDER_PT_gpencil", "EEVEE_MATERIAL_PT_viewport_settings", "VIEWLAYER_PT_layer_passes",
            "VIEWLAYER_PT_filter", "DATA_PT_spot", "OBJECT_PT_shading", "MATERIAL_PT_freestyle_line"}
#: stock panels whose settings the engine or its output reads
READ = {"RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_color_management",
        "DATA_PT_context_light", "DATA_PT_light", "DATA_PT_lens", "DATA_PT_camera", "DATA_PT_uv_texture",
        "OBJECT_PT_visibility", "VIEWLAYER_PT_layer", "PARTICLE_PT_hair_shape"}


def test_stock_panels_are_an_allow_list():
    """Every enabled stock panel is on the allow-list; Freestyle, stereoscopy, light probes,
    volumes and Grease Pencil are not; the camera, light type, output and colour management are."""
    from hybrid_shadow_addon.blender.stock_panels import ALLOWED_PANELS, is_allowed

    names = sorted(p.__name__ for p in ui.get_panels())
    print(len(names), "stock panels:", ", ".join(names))
    assert all(is_allowed(n) for n in names)
    assert not [n for n in names if "freestyle" in n.lower() or "stereo" in n.lower() or "lightprobe" in n
                or "_volume_" in n.replace("hair_dynamics_volume", "") or "gpencil" in n or "grease" in n]
    assert not NOT_READ & set(names) and not NOT_READ & ALLOWED_PANELS
    assert READ <= set(names), READ - set(names)
    assert len(names) < 260


def test_object_panel_draws_the_shadow_terminator_the_export_reads(empty):
    """The Object tab shows Cycles' Shadow Terminator offsets; the Geometry Offset reaches the
    exported instance, the Shading Offset (not applied) is reported."""
    import warnings

    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.export.common import ExportWarning

    bpy.ops.mesh.primitive_uv_sphere_add()
    ob = bpy.context.object
    drawn = draw(ui.OBJECT_PT_hybrid_shadows_terminator, Ctx(object=ob))
    assert {"shadow_terminator_geometry_offset", "shadow_terminator_shading_offset"} <= {n for _, n in drawn}
    assert not ui.OBJECT_PT_hybrid_shadows_terminator.poll(Ctx(engine="CYCLES", object=ob))
    ob.shadow_terminator_geometry_offset = 0.35
    bpy.ops.object.camera_add(location=(0, -5, 0), rotation=(math.pi / 2, 0, 0))
    bpy.context.scene.camera = bpy.context.object
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    row = scene.instances.names.index(ob.name)
    assert scene.instances.terminator[row] == pytest.approx(0.35)
    assert not [w for w in caught if issubclass(w.category, ExportWarning)]
    ob.shadow_terminator_shading_offset = 0.2
    with pytest.warns(ExportWarning, match="Shading Offset"):
        export_depsgraph(bpy.context.evaluated_depsgraph_get())


def test_material_panels(empty):
    bpy.ops.mesh.primitive_cube_add()
    ob = bpy.context.object
    mat = bpy.data.materials.new("M")
    mat.use_nodes = True
    ob.data.materials.append(mat)
    ctx = Ctx(object=ob, material=mat, material_slot=ob.material_slots[0], space_data=None)
    drawn = draw(ui.MATERIAL_PT_hybrid_shadows_context, ctx)
    assert ("template_list", "MATERIAL_UL_matslots") in drawn and ("template_ID", "active_material") in drawn
    drawn = draw(ui.MATERIAL_PT_hybrid_shadows_surface, ctx)
    assert [o for o, n in drawn if n == "default_value"] == ["Base Color", "Alpha", "Specular IOR Level", "Roughness"]
    # a linked input is shown as not read (its default value is what the export takes)
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    drawn = draw(ui.MATERIAL_PT_hybrid_shadows_surface, ctx)
    assert any(o == "label" and "not read" in n for o, n in drawn)
    mat.use_nodes = False
    if not mat.use_nodes:  # (Blender 5.0+ materials always use nodes)
        names = {n for _, n in draw(ui.MATERIAL_PT_hybrid_shadows_surface, ctx)}
        assert {"use_nodes", "diffuse_color", "specular_intensity", "roughness"} <= names


def test_world_panel(empty):
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    drawn = draw(ui.WORLD_PT_hybrid_shadows, Ctx(world=world))
    assert [o for o, n in drawn if n == "default_value"] == ["Color", "Strength"]
    world.use_nodes = False
    if not world.use_nodes:  # (Blender 5.0+ worlds always use nodes)
        assert {"use_nodes", "color"} <= {n for _, n in draw(ui.WORLD_PT_hybrid_shadows, Ctx(world=world))}
    assert not ui.WORLD_PT_hybrid_shadows.poll(Ctx(engine="BLENDER_EEVEE_NEXT", world=world))


def _light_object(kind, **props):
    light = bpy.data.lights.new("L", kind)
    for k, v in props.items():
        setattr(light, k, v)
    return bpy.data.objects.new("L", light)


def test_exposure_temperature_and_normalize_reach_the_export(empty):
    base = export_light(_light_object("POINT", energy=100.0), np.eye(4), "L")
    if hasattr(bpy.types.Light, "exposure"):
        brighter = export_light(_light_object("POINT", energy=100.0, exposure=1.5), np.eye(4), "L")
        assert math.isclose(brighter.power, base.power * 2 ** 1.5, rel_tol=1e-6)
    if hasattr(bpy.types.Light, "use_temperature"):
        warm = _light_object("POINT", energy=100.0, use_temperature=True, temperature=3000.0)
        got = export_light(warm, np.eye(4), "L")
        want = np.array(warm.data.color) * np.array(warm.data.temperature_color)
        assert np.allclose(got.color, want) and got.color[2] < got.color[0]
    if hasattr(bpy.types.Light, "normalize"):
        for shape, area in (("RECTANGLE", 2.0 * 0.5), ("ELLIPSE", math.pi / 4 * 2.0 * 0.5), ("SQUARE", 4.0),
                            ("DISK", math.pi / 4 * 4.0)):
            kw = dict(energy=10.0, shape=shape, size=2.0, size_y=0.5)
            on = export_light(_light_object("AREA", **kw), np.eye(4), "L")
            off = export_light(_light_object("AREA", normalize=False, **kw), np.eye(4), "L")
            assert math.isclose(on.power, 10.0) and math.isclose(off.power, 10.0 * area, rel_tol=1e-6), shape


def test_preview_pixel_size(empty):
    from hybrid_shadow_addon.blender.viewport_engine import preview_pixel_size

    ctx = Ctx(scene=bpy.context.scene, preferences=bpy.context.preferences)
    for size, want in (("1", 1), ("2", 2), ("4", 4), ("8", 8)):
        bpy.context.scene.render.preview_pixel_size = size
        assert preview_pixel_size(ctx) == want
    bpy.context.scene.render.preview_pixel_size = "AUTO"
    assert preview_pixel_size(ctx) == max(1, round(bpy.context.preferences.system.pixel_size))


PASS_SCRIPT = r'''
import json, sys
import bpy
import hybrid_shadow_addon
hybrid_shadow_addon.register()
try:
    s = bpy.context.scene
    s.render.engine = "HYBRID_SHADOWS"
    if hasattr(s, "compositing_node_group"):  # Blender 5: the compositor is a node group
        s.compositing_node_group = bpy.data.node_groups.new("Compositor", "CompositorNodeTree")
        rl = s.compositing_node_group.nodes.new("CompositorNodeRLayers")
    else:
        s.use_nodes = True
        rl = [n for n in s.node_tree.nodes if n.type == "R_LAYERS"][0]
    sockets = lambda: [o.name for o in rl.outputs if o.enabled]
    vl = s.view_layers[0]
    out = {"before": sockets()}
    vl.hybrid_shadows.use_pass_albedo = True
    out["albedo"] = sockets()
    vl.hybrid_shadows.use_pass_shadow = True
    out["shadow"] = sockets()
    vl.hybrid_shadows.use_pass_albedo = False
    out["no_albedo"] = sockets()
    props = s.hybrid_shadows
    out["default_limit"] = props.to_settings(viewport=True).max_shadowed_lights
    props.viewport_max_shadowed_lights = 0
    out["zero_limit"] = props.to_settings(viewport=True).max_shadowed_lights
finally:
    hybrid_shadow_addon.unregister()
print(json.dumps(out))
'''


def test_pass_toggles_update_the_render_layers_sockets_and_zero_shadows_all(tmp_path):
    """Toggling the engine's passes re-registers them: the compositor's Render Layers node gains
    and loses the sockets; the viewport's light limit defaults to 4 and 0 means every light."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from tests.helpers.blender_env import isolated_env

    repo = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-c", PASS_SCRIPT], cwd=repo, env=isolated_env(tmp_path),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert "Albedo" not in out["before"] and "Albedo" in out["albedo"]
    assert any(n.startswith("Shadow ") for n in out["shadow"]), out["shadow"]  # the default scene's light
    assert "Albedo" not in out["no_albedo"] and any(n.startswith("Shadow ") for n in out["no_albedo"])
    assert out["default_limit"] == 4 and out["zero_limit"] is None


def test_status_text_counts_the_lights_the_viewport_limit_leaves_unshadowed(monkeypatch):
    """The viewport's stats line names the unshadowed lights only when the limit drops some."""
    from types import SimpleNamespace

    from hybrid_shadow_addon.blender import viewport_engine as vpe

    assert vpe.unshadowed_note(6, 4, 4).startswith(", 2 lights unshadowed (viewport limit 4")
    assert "0 shadows all" in vpe.unshadowed_note(5, 4, 4)
    assert vpe.unshadowed_note(5, 4, 4).startswith(", 1 light unshadowed")
    assert vpe.unshadowed_note(4, 4, 4) == "" and vpe.unshadowed_note(3, 3, 4) == ""
    lights = [SimpleNamespace(use_shadow=True)] * 6 + [SimpleNamespace(use_shadow=False)]
    state = SimpleNamespace(sync=SimpleNamespace(scene=SimpleNamespace(lights=lights)))
    monkeypatch.setattr(vpe, "shared", lambda engine: state)
    result = SimpleNamespace(settings=SimpleNamespace(mode="raytrace", max_shadowed_lights=4),
                             stats={"shadowed_lights": 4})
    assert vpe.light_limit_note(None, result).startswith(", 2 lights unshadowed")
    result.settings.max_shadowed_lights = None  # 0 in the panel: every light shadowed
    assert vpe.light_limit_note(None, result) == ""
    result.settings.mode, result.settings.max_shadowed_lights = "none", 4
    assert vpe.light_limit_note(None, result) == ""
