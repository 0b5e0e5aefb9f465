"""export_depsgraph and load_scene on small scenes built here with bpy."""

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender import export
from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.core.scene import affine_inverse
from hybrid_shadow_addon.blender.load import (SCENES_DIR, builtin_scenes, load_scene, open_scene,
                                              parse_scene_arg)
from hybrid_shadow_addon.core.errors import SceneError, SceneLoadError
from hybrid_shadow_addon.core.scene import Instances, Model, Scene

pytestmark = [pytest.mark.blender]


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _cube_mesh(name="cube"):
    me = bpy.data.meshes.new(name)
    v = [(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
    f = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    me.from_pydata(v, [], f)
    return me


def _add(name, data, collection=None, location=(0, 0, 0)):
    ob = bpy.data.objects.new(name, data)
    (collection or bpy.context.scene.collection).objects.link(ob)
    ob.location = location
    return ob


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    cam = _add("Cam", bpy.data.cameras.new("Cam"), location=(0, -10, 2))
    sc.camera = cam
    return sc


def _export(**kw):
    return export_depsgraph(bpy.context.evaluated_depsgraph_get(), **kw)


def _bpy_triangles(name):
    ob = bpy.data.objects[name].evaluated_get(bpy.context.evaluated_depsgraph_get())
    return len(ob.data.loop_triangles)


def _gn_instancer(name, points, instance_node):
    """A mesh object of ``points`` whose node tree instances ``instance_node``'s geometry on them."""
    pts = bpy.data.meshes.new(name)
    pts.vertices.add(len(points))
    pts.vertices.foreach_set("co", np.asarray(points, np.float32).ravel())
    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    iop = tree.nodes.new("GeometryNodeInstanceOnPoints")
    source = instance_node(tree)
    tree.links.new(gin.outputs[0], iop.inputs["Points"])
    tree.links.new(source, iop.inputs["Instance"])
    tree.links.new(iop.outputs[0], gout.inputs[0])
    ob = _add(name, pts)
    ob.modifiers.new("GN", "NODES").node_group = tree
    return ob


def _object_info(target, as_instance):
    def make(tree):
        node = tree.nodes.new("GeometryNodeObjectInfo")
        node.inputs["Object"].default_value = target
        node.inputs["As Instance"].default_value = as_instance
        return node.outputs["Geometry"]
    return make


def _reference_counts():
    """Mesh instances and triangles in the depsgraph, minus those of hide_render objects."""
    n = tris = 0
    for inst in bpy.context.evaluated_depsgraph_get().object_instances:
        owner = inst.parent if inst.is_instance else inst.object
        if inst.object.type == "MESH" and not owner.original.hide_render:
            n += bool(len(inst.object.data.loop_triangles))
            tris += len(inst.object.data.loop_triangles)
    return n, tris


# --------------------------------------------------------------------------------------------
# instancing
# --------------------------------------------------------------------------------------------
def test_linked_duplicates_share_one_model(scene):
    me = _cube_mesh()
    for i in range(5):
        _add(f"C{i}", me, location=(3 * i, 0, 0))
    s = _export()
    assert len(s.instances) == 5 and len(s.models) == 1
    assert s.triangle_count == 60 and s.unique_triangle_count == 12
    np.testing.assert_allclose(sorted(s.instances.matrices[:, 0, 3]), [0, 3, 6, 9, 12])


def test_collection_instances_share_one_model(scene):
    coll = bpy.data.collections.new("Src")
    _add("InColl", _cube_mesh(), coll, location=(1, 0, 0))
    for i in range(3):
        e = _add(f"E{i}", None, location=(0, 5 * i, 0))
        e.instance_type, e.instance_collection = "COLLECTION", coll
    s = _export()
    assert len(s.instances) == 3 and len(s.models) == 1
    np.testing.assert_allclose(sorted(s.instances.matrices[:, 1, 3]), [0, 5, 10])
    np.testing.assert_allclose(s.instances.matrices[:, 0, 3], 1)


@pytest.mark.parametrize("as_instance", [False, True])
def test_geometry_nodes_instances_share_one_model(scene, as_instance):
    src = _add("Src", _cube_mesh(), location=(0, 0, 50))
    src.hide_render = True  # the source does not render; its instances do
    points = np.random.default_rng(0).uniform(-20, 20, (200, 3))
    gn = _gn_instancer("GN", points, _object_info(src, as_instance))
    gn.location = (1, 2, 3)
    s = _export()
    assert len(s.instances) == 200 and len(s.models) == 1
    assert s.triangle_count == 200 * 12
    np.testing.assert_allclose(np.sort(s.instances.matrices[:, :3, 3], axis=0), np.sort(points + (1, 2, 3), axis=0),
                               atol=1e-4)
    ref = {tuple(np.round(np.array(i.matrix_world, np.float64)[:3, 3], 3))
           for i in bpy.context.evaluated_depsgraph_get().object_instances if i.is_instance}
    assert ref == {tuple(np.round(m[:3, 3], 3)) for m in s.instances.matrices}


def test_vectorised_and_iterated_geometry_nodes_instances_agree(monkeypatch):
    open_scene("scaling:triangles=3000,instances=150,models=3")
    fast = _export()
    monkeypatch.setattr(export._Exporter, "_vectorise", lambda self, ob: False)
    slow = _export()
    assert len(fast.instances) == len(slow.instances) == 151
    assert sorted(m.triangle_count for m in fast.models) == sorted(m.triangle_count for m in slow.models)
    order_f = np.lexsort(fast.instances.matrices.reshape(-1, 16).T)
    order_s = np.lexsort(slow.instances.matrices.reshape(-1, 16).T)
    np.testing.assert_allclose(fast.instances.matrices[order_f], slow.instances.matrices[order_s], atol=1e-4)
    np.testing.assert_allclose(fast.instances.inverse[order_f], slow.instances.inverse[order_s], atol=1e-3)
    np.testing.assert_array_equal(fast.instances.base_color[order_f], slow.instances.base_color[order_s])


def test_affine_inverse():
    rng = np.random.default_rng(1)
    m = np.tile(np.eye(4), (50, 1, 1))
    m[:, :3, :] = rng.normal(size=(50, 3, 4))
    m[3, :3, :3] = 0  # singular
    m[7, 0, 3] = np.nan
    inv = affine_inverse(m)
    ok = np.ones(50, bool)
    ok[[3, 7]] = False
    np.testing.assert_allclose(inv[ok], np.linalg.inv(m[ok]), rtol=1e-9, atol=1e-9)
    assert np.isnan(inv[~ok]).all()


def test_nested_and_collection_geometry_nodes_instances(scene):
    coll = bpy.data.collections.new("Pair")
    me = _cube_mesh()
    _add("P1", me, coll, location=(0, 0, 0))
    _add("P2", me, coll, location=(0, 0, 3))

    def collection_info(tree):
        node = tree.nodes.new("GeometryNodeCollectionInfo")
        node.inputs["Collection"].default_value = coll
        return node.outputs[0]
    inner = _gn_instancer("Inner", [(0, 0, 0), (5, 0, 0)], collection_info)
    inner.hide_render = True
    _gn_instancer("Outer", [(0, 0, 0), (0, 10, 0), (0, 20, 0)], _object_info(inner, True))
    s = _export()
    n, tris = _reference_counts()
    assert (len(s.instances), s.triangle_count) == (n, tris) == (12, 144)
    assert len(s.models) == 1


def test_geometry_nodes_instancing_a_curve_counts_once(scene):
    curve = bpy.data.curves.new("Crv", "CURVE")
    curve.dimensions, curve.bevel_depth = "3D", 0.2
    spline = curve.splines.new("POLY")
    spline.points.add(1)
    spline.points[1].co = (2, 0, 0, 1)
    src = _add("Crv", curve)
    src.hide_render = True
    _gn_instancer("GN", [(0, 0, 0), (0, 5, 0)], _object_info(src, True))
    s = _export()
    n, tris = _reference_counts()
    assert (len(s.instances), s.triangle_count) == (n, tris)
    assert n == 2 and tris > 0


def test_non_mesh_objects_are_triangulated_once(scene):
    text = bpy.data.curves.new("Txt", "FONT")
    text.body, text.extrude = "Hi", 0.1
    _add("Text", text)
    ball = bpy.data.metaballs.new("Meta")
    ball.elements.new().radius = 1
    _add("Meta", ball, location=(5, 0, 0))
    s = _export()
    dg = bpy.context.evaluated_depsgraph_get()
    expected = 0
    for name in ("Text", "Meta"):
        ob = bpy.data.objects[name].evaluated_get(dg)
        expected += len(ob.to_mesh().loop_triangles)
        ob.to_mesh_clear()
    assert len(s.instances) == 2
    assert s.triangle_count == expected > 0


# --------------------------------------------------------------------------------------------
# modifiers, visibility, flags, materials
# --------------------------------------------------------------------------------------------
def test_modifiers_are_applied(scene):
    sub = _add("Sub", _cube_mesh("a"))
    sub.modifiers.new("S", "SUBSURF").levels = 2
    arr = _add("Arr", _cube_mesh("b"), location=(0, 10, 0))
    arr.modifiers.new("A", "ARRAY").count = 4
    s = _export()
    assert _bpy_triangles("Sub") == 192 and _bpy_triangles("Arr") == 48
    assert s.triangle_count == 192 + 48
    assert sorted(m.triangle_count for m in s.models) == [48, 192]


def test_smooth_shading_normals_are_exported(scene):
    flat = _cube_mesh("flat")
    flat.polygons.foreach_set("use_smooth", np.zeros(len(flat.polygons), bool))
    smooth = _cube_mesh("smooth")
    smooth.polygons.foreach_set("use_smooth", np.ones(len(smooth.polygons), bool))
    smooth.update()
    _add("Flat", flat)
    _add("Smooth", smooth, location=(5, 0, 0))
    s = _export()
    by_name = {m.name: m for m in s.models}
    assert by_name["flat"].normals is None
    n = by_name["smooth"].normals
    assert n.shape == (12, 3, 3)
    # smooth cube corners: normals along the corner's diagonal, the vertex position direction
    corner = by_name["smooth"].vertices[by_name["smooth"].triangles]
    np.testing.assert_allclose(n, corner / np.linalg.norm(corner, axis=2, keepdims=True), atol=1e-5)


def test_hide_render_objects_and_collections_are_excluded(scene):
    me = _cube_mesh()
    _add("Shown", me)
    _add("Hidden", me).hide_render = True
    coll = bpy.data.collections.new("HiddenColl")
    scene.collection.children.link(coll)
    coll.hide_render = True
    _add("InHidden", me, coll)
    light = _add("HiddenLamp", bpy.data.lights.new("L", "POINT"))
    light.hide_render = True
    s = _export()
    assert s.instances.names == ["Shown"]
    assert s.lights == []


def test_visible_shadow_and_sphere_flags(scene):
    me = _cube_mesh()
    _add("Caster", me)
    _add("NoShadow", me, location=(3, 0, 0)).visible_shadow = False
    _add("Ball", me, location=(6, 0, 0))["hybrid_sphere"] = True
    s = _export()
    flags = dict(zip(s.instances.names, zip(s.instances.casts_shadow, s.instances.sphere)))
    assert flags == {"Caster": (True, False), "NoShadow": (False, False), "Ball": (True, True)}


def test_material_colours(scene):
    me_red = _cube_mesh("red")
    mat = bpy.data.materials.new("Red")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.9, 0.1, 0.05, 1)
    bsdf.inputs["Specular IOR Level"].default_value = 0.25
    bsdf.inputs["Roughness"].default_value = 0.7
    me_red.materials.append(mat)
    _add("Red", me_red)
    plain = _cube_mesh("plain")
    _add("Grey", plain)
    _add("Tinted", plain).color = (0.1, 0.2, 0.3, 1)
    s = _export()
    rows = {n: i for i, n in enumerate(s.instances.names)}
    inst = s.instances
    np.testing.assert_allclose(inst.base_color[rows["Red"]], (0.9, 0.1, 0.05, 1), rtol=1e-6)
    assert (inst.specular[rows["Red"]], inst.roughness[rows["Red"]]) == pytest.approx((0.25, 0.7))
    np.testing.assert_allclose(inst.base_color[rows["Grey"]], (0.8, 0.8, 0.8, 1))
    np.testing.assert_allclose(inst.base_color[rows["Tinted"]], (0.1, 0.2, 0.3, 1), rtol=1e-6)


# --------------------------------------------------------------------------------------------
# lights, camera, world, resolution
# --------------------------------------------------------------------------------------------
def test_lights_of_every_type(scene):
    specs = {
        "Sun": ("SUN", dict(angle=0.1)),
        "Point": ("POINT", dict(shadow_soft_size=0.3)),
        "Spot": ("SPOT", dict(spot_size=1.0, spot_blend=0.4, shadow_soft_size=0.2)),
        "Area": ("AREA", dict(shape="RECTANGLE", size=2.0, size_y=0.5)),
        "Disk": ("AREA", dict(shape="DISK", size=1.5)),
    }
    for i, (name, (kind, props)) in enumerate(specs.items()):
        light = bpy.data.lights.new(name, kind)
        light.energy, light.color = 10.0 * (i + 1), (1, 0.5, 0.25)
        for k, v in props.items():
            setattr(light, k, v)
        ob = _add(name, light, location=(i, 2 * i, 3 * i))
        ob.rotation_euler = (0.3 * i, 0.1, 0.2)
    bpy.data.lights["Point"].use_shadow = False
    s = _export()
    got = {light.name: light for light in s.lights}
    assert s.lights_by_type() == {"SUN": 1, "POINT": 1, "SPOT": 1, "AREA": 2}
    for name, (kind, props) in specs.items():
        light, ob = got[name], bpy.data.objects[name]
        assert light.type == kind and light.power == pytest.approx(ob.data.energy)
        np.testing.assert_allclose(light.matrix, np.array(ob.matrix_world), atol=1e-6)
        np.testing.assert_allclose(light.color, (1, 0.5, 0.25))
    assert got["Sun"].angle == pytest.approx(0.1)
    assert not got["Point"].use_shadow and got["Spot"].use_shadow
    assert got["Point"].radius == pytest.approx(0.3)
    assert (got["Spot"].spot_size, got["Spot"].spot_blend, got["Spot"].radius) == pytest.approx((1.0, 0.4, 0.2))
    assert (got["Area"].size, got["Area"].size_y, got["Area"].area_shape) == (2.0, 0.5, "RECTANGLE")
    assert (got["Disk"].size, got["Disk"].size_y) == (1.5, 1.5)


def test_camera_world_and_resolution(scene):
    cam = scene.camera.data
    cam.type, cam.ortho_scale, cam.sensor_fit = "ORTHO", 12.0, "VERTICAL"
    cam.shift_x, cam.clip_start, cam.clip_end = 0.1, 0.5, 300.0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 1001, 500, 50
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.2, 0.4, 0.6, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.5
    scene.world = world
    s = _export()
    c = s.camera
    assert (c.type, c.ortho_scale, c.sensor_fit, c.shift_x) == ("ORTHO", 12.0, "VERTICAL", pytest.approx(0.1))
    assert (c.clip_start, c.clip_end) == (0.5, 300.0)
    np.testing.assert_allclose(c.matrix, np.array(scene.camera.matrix_world))
    assert s.resolution == (500, 250)
    assert _export(resolution=(64, 32)).resolution == (64, 32)
    np.testing.assert_allclose(s.world_color, (0.1, 0.2, 0.3), rtol=1e-6)


# --------------------------------------------------------------------------------------------
# invalid values
# --------------------------------------------------------------------------------------------
def test_nan_transform_is_rejected_naming_the_object(scene):
    _add("Fine", _cube_mesh())
    _add("Broken", _cube_mesh("b")).location = (float("nan"), 0, 0)
    with pytest.raises(SceneError, match="'Broken'.*NaN"):
        _export()


def test_nan_light_transform_is_rejected(scene):
    _add("Lamp", bpy.data.lights.new("Lamp", "POINT")).location = (0, float("nan"), 0)
    with pytest.raises(SceneError, match="light 'Lamp'"):
        _export()


def test_core_scene_rejects_infinite_transform():
    m = np.eye(4)
    m[0, 3] = np.inf
    scene = Scene(models=[Model("tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])],
                  instances=Instances(names=["Far"], matrices=[m]))
    with pytest.raises(SceneError, match="'Far'"):
        scene.validate(require_camera=False)


# --------------------------------------------------------------------------------------------
# load_scene
# --------------------------------------------------------------------------------------------
def test_parse_scene_arg():
    assert parse_scene_arg("scaling:triangles=1000000,instances=100000,k=0.5,s=abc") == (
        "scaling", {"triangles": 1000000, "instances": 100000, "k": 0.5, "s": "abc"})
    assert parse_scene_arg("forest") == ("forest", {})
    assert parse_scene_arg("/tmp/a:b.py") == ("/tmp/a:b.py", {})


def test_load_builtin_with_params():
    s = load_scene("scaling:triangles=600,instances=20")
    assert len(s.instances) == 21 and s.name == "scaling"
    assert all((SCENES_DIR / f"{n}.py").is_file() for n in builtin_scenes())


def test_load_script_and_blend(tmp_path):
    script = tmp_path / "mine.py"
    script.write_text(
        "import bpy\n"
        "sc = bpy.context.scene\n"
        "me = bpy.data.meshes.new('t')\n"
        "me.from_pydata([(0,0,0),(1,0,0),(0,1,0)], [], [(0,1,2)])\n"
        "sc.collection.objects.link(bpy.data.objects.new('Tri', me))\n"
        "cam = bpy.data.objects.new('Cam', bpy.data.cameras.new('Cam'))\n"
        "sc.collection.objects.link(cam); sc.camera = cam\n"
        "cam.location = (0, 0, PARAMS.get('z', 5))\n")
    s = load_scene(f"{script}:z=7")
    assert s.instances.names == ["Tri"] and s.camera.matrix[2, 3] == 7
    blend = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    s = load_scene(str(blend), frame=3)
    assert s.instances.names == ["Tri"] and s.frame == 3


@pytest.mark.parametrize("arg, error, pattern", [
    ("/nonexistent/scene.py", SceneLoadError, "not found: /nonexistent/scene.py"),
    ("/nonexistent/scene.blend", SceneLoadError, "not found"),
    ("no_such_scene", SceneLoadError, "unknown scene 'no_such_scene'.*cube_on_plane.*forest"),
    ("_lib", SceneLoadError, "unknown scene"),
])
def test_load_errors(arg, error, pattern):
    with pytest.raises(error, match=pattern) as info:
        load_scene(arg)
    assert "\n" not in str(info.value)


def test_load_failing_script(tmp_path):
    script = tmp_path / "boom.py"
    script.write_text("x = 1\nraise ValueError('the model is broken\\nsecond line')\n")
    with pytest.raises(SceneLoadError, match=r"^scene script boom.py failed: ValueError: the model is broken$"):
        load_scene(str(script))


def test_load_corrupted_blend(tmp_path):
    bad = tmp_path / "bad.blend"
    bad.write_bytes(b"BLENDER-v405 this is not a blend file" * 10)
    with pytest.raises(SceneLoadError, match="cannot open .*bad.blend") as info:
        load_scene(str(bad))
    assert "\n" not in str(info.value)


def test_load_without_camera(tmp_path):
    script = tmp_path / "nocam.py"
    script.write_text("import bpy\nbpy.context.scene.name = 'Empty'\n")
    with pytest.raises(SceneError, match="'Empty'.*no camera"):
        load_scene(str(script))


def test_open_scene_keeps_bpy_scene():
    sc = open_scene("cube_on_plane", frame=2)
    assert sc == bpy.context.scene and sc.frame_current == 2
    assert {o.name for o in sc.objects} >= {"Cube", "Plane", "Sun", "Camera"}


def test_the_viewport_shows_objects_hidden_from_render(scene):
    """As Cycles' and EEVEE's rendered viewports: hidden from render is still drawn there."""
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = _cube_mesh()
    _add("Shown", me)
    _add("Hidden", me).hide_render = True
    light = _add("HiddenLamp", bpy.data.lights.new("L", "POINT"))
    light.hide_render = True
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    assert sorted(sync.scene.instances.names) == ["Hidden", "Shown"]
    assert [l.name for l in sync.scene.lights] == ["HiddenLamp"]
    assert _export().instances.names == ["Shown"]  # what F12 renders


def test_simplify_limits_subdivision(scene):
    """Render ▸ Simplify (shown for this engine) reaches the export through the evaluated mesh."""
    from hybrid_shadow_addon.blender import ui

    ob = _add("Sub", _cube_mesh())
    mod = ob.modifiers.new("sub", "SUBSURF")
    mod.levels = 2
    full = _export().triangle_count
    scene.render.use_simplify = True
    scene.render.simplify_subdivision = 0
    assert _export().triangle_count == 12 < full
    assert bpy.types.RENDER_PT_simplify in ui.get_panels()


def test_the_viewport_in_local_view_shows_only_its_objects(scene):
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = _cube_mesh()
    _add("A", me)
    _add("B", me)
    _add("Lamp", bpy.data.lights.new("L", "POINT"))
    dg = bpy.context.evaluated_depsgraph_get()
    sync = ViewportSync()
    sync.full_export(dg)
    assert sorted(sync.scene.instances.names) == ["A", "B"]
    assert sync.set_local_view(dg, ["A"])
    assert sync.scene.instances.names == ["A"] and sync.scene.lights == []
    assert not sync.set_local_view(dg, ["A"])  # unchanged: no export
    assert sync.set_local_view(dg, None)
    assert sorted(sync.scene.instances.names) == ["A", "B"] and [l.name for l in sync.scene.lights] == ["Lamp"]
