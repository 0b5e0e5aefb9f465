"""The depsgraph walk: linked duplicates, collection and geometry-nodes instances (both paths),
converted objects, render visibility, object flags and invalid transforms."""
import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender.export.objects import SceneExporter
from hybrid_shadow_addon.blender.load import open_scene
from hybrid_shadow_addon.core.errors import SceneError
from hybrid_shadow_addon.core.scene import Instances, Model, Scene, affine_inverse
from tests.helpers.export_scenes import add_object, cube_mesh, empty_scene, export_scene, gn_instancer, object_info

pytestmark = [pytest.mark.blender]


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()
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
    me = cube_mesh()
    for i in range(5):
        add_object(f"C{i}", me, location=(3 * i, 0, 0))
    s = export_scene()
    assert len(s.instances) == 5 and len(s.models) == 1
    assert s.triangle_count == 60 and s.unique_triangle_count == 12
    np.testing.assert_allclose(sorted(s.instances.matrices[:, 0, 3]), [0, 3, 6, 9, 12])


def test_collection_instances_share_one_model(scene):
    coll = bpy.data.collections.new("Src")
    add_object("InColl", cube_mesh(), coll, location=(1, 0, 0))
    for i in range(3):
        e = add_object(f"E{i}", None, location=(0, 5 * i, 0))
        e.instance_type, e.instance_collection = "COLLECTION", coll
    s = export_scene()
    assert len(s.instances) == 3 and len(s.models) == 1
    np.testing.assert_allclose(sorted(s.instances.matrices[:, 1, 3]), [0, 5, 10])
    np.testing.assert_allclose(s.instances.matrices[:, 0, 3], 1)


@pytest.mark.parametrize("as_instance", [False, True])
def test_geometry_nodes_instances_share_one_model(scene, as_instance):
    src = add_object("Src", cube_mesh(), location=(0, 0, 50))
    src.hide_render = True  # the source does not render; its instances do
    points = np.random.default_rng(0).uniform(-20, 20, (200, 3))
    gn = gn_instancer("GN", points, object_info(src, as_instance))
    gn.location = (1, 2, 3)
    s = export_scene()
    assert len(s.instances) == 200 and len(s.models) == 1
    assert s.triangle_count == 200 * 12
    np.testing.assert_allclose(np.sort(s.instances.matrices[:, :3, 3], axis=0), np.sort(points + (1, 2, 3), axis=0),
                               atol=1e-4)
    ref = {tuple(np.round(np.array(i.matrix_world, np.float64)[:3, 3], 3))
           for i in bpy.context.evaluated_depsgraph_get().object_instances if i.is_instance}
    assert ref == {tuple(np.round(m[:3, 3], 3)) for m in s.instances.matrices}


def test_vectorised_and_iterated_geometry_nodes_instances_agree(monkeypatch):
    open_scene("scaling:triangles=3000,instances=150,models=3")
    fast = export_scene()
    monkeypatch.setattr(SceneExporter, "_vectorise", lambda self, ob: False)
    slow = export_scene()
    assert len(fast.instances) == len(slow.instances) == 151
    assert sorted(m.triangle_count for m in fast.models) == sorted(m.triangle_count for m in slow.models)
    order_f = np.lexsort(fast.instances.matrices.reshape(-1, 16).T)
    order_s = np.lexsort(slow.instances.matrices.reshape(-1, 16).T)
    np.testing.assert_allclose(fast.instances.matrices[order_f], slow.instances.matrices[order_s], atol=1e-4)
    np.testing.assert_allclose(fast.instances.inverse[order_f], slow.instances.inverse[order_s], atol=1e-3)
    np.testing.assert_array_equal(fast.instances.base_color[order_f], slow.instances.base_color[order_s])


def test_nested_and_collection_geometry_nodes_instances(scene):
    coll = bpy.data.collections.new("Pair")
    me = cube_mesh()
    add_object("P1", me, coll, location=(0, 0, 0))
    add_object("P2", me, coll, location=(0, 0, 3))

    def collection_info(tree):
        node = tree.nodes.new("GeometryNodeCollectionInfo")
        node.inputs["Collection"].default_value = coll
        return node.outputs[0]
    inner = gn_instancer("Inner", [(0, 0, 0), (5, 0, 0)], collection_info)
    inner.hide_render = True
    gn_instancer("Outer", [(0, 0, 0), (0, 10, 0), (0, 20, 0)], object_info(inner, True))
    s = export_scene()
    n, tris = _reference_counts()
    assert (len(s.instances), s.triangle_count) == (n, tris) == (12, 144)
    assert len(s.models) == 1


def test_geometry_nodes_instancing_a_curve_counts_once(scene):
    curve = bpy.data.curves.new("Crv", "CURVE")
    curve.dimensions, curve.bevel_depth = "3D", 0.2
    spline = curve.splines.new("POLY")
    spline.points.add(1)
    spline.points[1].co = (2, 0, 0, 1)
    src = add_object("Crv", curve)
    src.hide_render = True
    gn_instancer("GN", [(0, 0, 0), (0, 5, 0)], object_info(src, True))
    s = export_scene()
    n, tris = _reference_counts()
    assert (len(s.instances), s.triangle_count) == (n, tris)
    assert n == 2 and tris > 0


def test_non_mesh_objects_are_triangulated_once(scene):
    text = bpy.data.curves.new("Txt", "FONT")
    text.body, text.extrude = "Hi", 0.1
    add_object("Text", text)
    ball = bpy.data.metaballs.new("Meta")
    ball.elements.new().radius = 1
    add_object("Meta", ball, location=(5, 0, 0))
    s = export_scene()
    dg = bpy.context.evaluated_depsgraph_get()
    expected = 0
    for name in ("Text", "Meta"):
        ob = bpy.data.objects[name].evaluated_get(dg)
        expected += len(ob.to_mesh().loop_triangles)
        ob.to_mesh_clear()
    assert len(s.instances) == 2
    assert s.triangle_count == expected > 0


# --------------------------------------------------------------------------------------------
# visibility and flags
# --------------------------------------------------------------------------------------------
def test_hide_render_objects_and_collections_are_excluded(scene):
    me = cube_mesh()
    add_object("Shown", me)
    add_object("Hidden", me).hide_render = True
    coll = bpy.data.collections.new("HiddenColl")
    scene.collection.children.link(coll)
    coll.hide_render = True
    add_object("InHidden", me, coll)
    light = add_object("HiddenLamp", bpy.data.lights.new("L", "POINT"))
    light.hide_render = True
    s = export_scene()
    assert s.instances.names == ["Shown"]
    assert s.lights == []


def test_the_viewport_shows_objects_hidden_from_render(scene):
    """As Cycles' and EEVEE's rendered viewports: hidden from render is still drawn there."""
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = cube_mesh()
    add_object("Shown", me)
    add_object("Hidden", me).hide_render = True
    light = add_object("HiddenLamp", bpy.data.lights.new("L", "POINT"))
    light.hide_render = True
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    assert sorted(sync.scene.instances.names) == ["Hidden", "Shown"]
    assert [light.name for light in sync.scene.lights] == ["HiddenLamp"]
    assert export_scene().instances.names == ["Shown"]  # what F12 renders


def test_the_viewport_in_local_view_shows_only_its_objects(scene):
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = cube_mesh()
    add_object("A", me)
    add_object("B", me)
    add_object("Lamp", bpy.data.lights.new("L", "POINT"))
    dg = bpy.context.evaluated_depsgraph_get()
    sync = ViewportSync()
    sync.full_export(dg)
    assert sorted(sync.scene.instances.names) == ["A", "B"]
    assert sync.set_local_view(dg, ["A"])
    assert sync.scene.instances.names == ["A"] and sync.scene.lights == []
    assert not sync.set_local_view(dg, ["A"])  # unchanged: no export
    assert sync.set_local_view(dg, None)
    assert sorted(sync.scene.instances.names) == ["A", "B"] and [light.name for light in sync.scene.lights] == ["Lamp"]


def test_visible_shadow_and_sphere_flags(scene):
    me = cube_mesh()
    add_object("Caster", me)
    add_object("NoShadow", me, location=(3, 0, 0)).visible_shadow = False
    add_object("Ball", me, location=(6, 0, 0))["hybrid_sphere"] = True
    s = export_scene()
    flags = dict(zip(s.instances.names, zip(s.instances.casts_shadow, s.instances.sphere)))
    assert flags == {"Caster": (True, False), "NoShadow": (False, False), "Ball": (True, True)}


def _ray_flags(s) -> dict:
    """``{instance name: (drawn, casts, holdout)}``."""
    i = s.instances
    return {n: (bool(i.visible_camera[k]), bool(i.casts_shadow[k]), bool(i.holdout[k])) for k, n in enumerate(i.names)}


@pytest.mark.parametrize("render_visibility", [None, False])
def test_camera_visibility_holdout_and_indirect_only(scene, render_visibility):
    """Cycles: camera visibility off is not drawn, holdouts (the object's or its collection's) are
    holes, an indirect-only collection is not drawn but casts (a holdout in it stays a holdout)."""
    me = cube_mesh()
    add_object("Seen", me)
    add_object("Unseen", me).visible_camera = False
    add_object("NoShadow", me).visible_shadow = False
    add_object("Hole", me).is_holdout = True
    mattes, ghosts = bpy.data.collections.new("Mattes"), bpy.data.collections.new("Ghosts")
    scene.collection.children.link(mattes)
    scene.collection.children.link(ghosts)
    add_object("Matte", me, mattes)
    add_object("Ghost", me, ghosts)
    add_object("HoleGhost", me, ghosts).is_holdout = True
    layers = scene.view_layers[0].layer_collection.children
    layers["Mattes"].holdout = True
    layers["Ghosts"].indirect_only = True
    assert _ray_flags(export_scene(render_visibility=render_visibility)) == {
        "Seen": (True, True, False), "Unseen": (False, True, False), "NoShadow": (True, False, False),
        "Hole": (True, True, True), "Matte": (True, True, True), "Ghost": (False, True, False),
        "HoleGhost": (True, True, True)}


def test_an_unreadable_indirect_only_is_reported():
    """Where the view layer's Indirect Only (or holdout) cannot be read, the export says so once
    per object and draws the object as the camera sees it (its own holdout kept)."""
    import warnings
    from types import SimpleNamespace

    from hybrid_shadow_addon.blender.export.common import ExportWarning
    from hybrid_shadow_addon.blender.export.ray_visibility import RayVisibility

    def fails(**_kw):
        raise RuntimeError("no such layer")

    orig = SimpleNamespace(name="Ghost", is_holdout=True, holdout_get=fails, indirect_only_get=fails,
                           as_pointer=lambda: 7)
    ob = SimpleNamespace(original=orig, visible_camera=True, visible_shadow=True, as_pointer=lambda: 8)
    vis = RayVisibility(SimpleNamespace(view_layer=object()))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        flags = vis.flags(ob)
        assert vis.flags(ob) is flags
    said = [str(w.message) for w in rec if issubclass(w.category, ExportWarning)]
    assert (flags.camera, flags.shadow, flags.holdout) == (True, True, True)
    assert len(said) == 2 and all("'Ghost'" in m for m in said), said
    assert "Indirect Only could not be read" in said[1] and "holdout could not be read" in said[0]


def test_collection_instances_combine_their_instancers_flags(scene):
    """Cycles ANDs an instance's camera and shadow visibility with its instancer's and takes
    holdout from the instancer alone."""
    coll = bpy.data.collections.new("Src")
    me = cube_mesh()
    add_object("A", me, coll)
    b = add_object("B", me, coll, location=(3, 0, 0))
    b.visible_camera = False
    b.is_holdout = True  # an instance's own holdout: not read (the instancer's is)
    for name, attr in (("NoShadow", "visible_shadow"), ("Unseen", "visible_camera"), ("Hole", "is_holdout")):
        e = add_object(name, None)
        e.instance_type, e.instance_collection = "COLLECTION", coll
        setattr(e, attr, attr == "is_holdout")
    assert _ray_flags(export_scene()) == {
        "NoShadow/A": (True, False, False), "NoShadow/B": (False, False, False),
        "Unseen/A": (False, True, False), "Unseen/B": (False, True, False),
        "Hole/A": (True, True, True), "Hole/B": (False, True, True)}


@pytest.mark.parametrize("vectorised", [True, False])
def test_geometry_nodes_instances_combine_their_instancers_flags(scene, monkeypatch, vectorised):
    if not vectorised:
        monkeypatch.setattr(SceneExporter, "_vectorise", lambda self, ob: False)
    src = add_object("Src", cube_mesh(), location=(0, 0, 50))
    src.hide_render = True
    src.visible_camera = False
    gn = gn_instancer("GN", [(0, 0, 0), (4, 0, 0)], object_info(src, True))
    gn.visible_shadow = False
    hole = gn_instancer("HoleGN", [(0, 4, 0)], object_info(src, True))
    hole.is_holdout = True
    s = export_scene()
    flags = _ray_flags(s)
    assert len(s.instances) == 3
    assert {v for k, v in flags.items() if k.startswith("GN/")} == {(False, False, False)}
    assert {v for k, v in flags.items() if k.startswith("HoleGN/")} == {(False, True, True)}


def _particle_emitter(scene, show_for_render=False, show_for_viewport=True):
    """An emitter whose hair particles instance a cone-like prototype hidden from render."""
    proto = add_object("Proto", cube_mesh("proto"), location=(0, 0, 20))
    proto.hide_render = True
    emitter = add_object("Emitter", cube_mesh("emitter"))
    emitter.modifiers.new("Scatter", "PARTICLE_SYSTEM")
    ps = emitter.particle_systems[0].settings
    ps.type, ps.count, ps.render_type, ps.instance_object = "HAIR", 6, "OBJECT", proto
    emitter.show_instancer_for_render = show_for_render
    emitter.show_instancer_for_viewport = show_for_viewport
    return emitter


def test_an_emitter_without_show_emitter_is_neither_drawn_nor_casting(scene):
    emitter = _particle_emitter(scene)
    emitter.visible_shadow = False
    flags = _ray_flags(export_scene())
    assert sorted(set(flags)) == ["Emitter/Proto"], "the emitter or the hidden prototype was exported"
    assert sum(1 for n in export_scene().instances.names if n == "Emitter/Proto") == 6
    assert set(flags.values()) == {(True, False, False)}  # the emitter's shadow flag reaches its particles
    emitter.show_instancer_for_render = True
    assert sorted(set(export_scene().instances.names)) == ["Emitter", "Emitter/Proto"]


def test_the_viewport_shows_an_emitter_by_its_viewport_setting(scene):
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    emitter = _particle_emitter(scene, show_for_render=False, show_for_viewport=True)
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    assert "Emitter" in sync.scene.instances.names
    emitter.show_instancer_for_viewport = False
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    assert "Emitter" not in sync.scene.instances.names
    assert "Emitter/Proto" in sync.scene.instances.names


def test_the_viewport_sync_follows_ray_visibility_changes(scene):
    """Toggling an object's camera visibility or holdout, or an instancer's, re-exports the
    viewport's scene (the G-buffer reads them; the bake is not involved)."""
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = cube_mesh()
    box = add_object("Box", me)
    coll = bpy.data.collections.new("Src")
    add_object("A", me, coll)
    e = add_object("E", None, location=(5, 0, 0))
    e.instance_type, e.instance_collection = "COLLECTION", coll
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())

    def handler(_scene, depsgraph):
        sync.update(depsgraph)

    bpy.app.handlers.depsgraph_update_post.append(handler)
    try:
        for ob, attr, value in ((box, "visible_camera", False), (box, "is_holdout", True),
                                (e, "visible_camera", False)):
            setattr(ob, attr, value)
            bpy.context.view_layer.update()
        flags = _ray_flags(sync.scene)
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(handler)
    assert flags == {"Box": (False, True, True), "E/A": (False, True, False)}


def _linked(s, light_name: str) -> dict:
    """``{instance name: (lit by the light, casts its shadow)}`` as its linking sets say."""
    from hybrid_shadow_addon.core.scene.linking import in_set

    light = next(li for li in s.lights if li.name == light_name)
    i = s.instances
    lit = in_set(i.light_sets, light.receiver_set)
    blocks = in_set(i.shadow_sets, light.blocker_set)
    return {n: (bool(lit[k]), bool(blocks[k])) for k, n in enumerate(i.names)}


def test_the_viewport_sync_follows_layer_holdout_and_light_linking_changes(scene):
    """A view-layer collection's holdout and indirect-only toggles and a light's receiver and
    blocker collections (set, edited, link state changed) reach the viewport's scene; moving a
    linked light keeps its sets."""
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = cube_mesh()
    add_object("Box", me)
    mattes = bpy.data.collections.new("Mattes")
    scene.collection.children.link(mattes)
    add_object("Matte", me, mattes, location=(4, 0, 0))
    lamp = add_object("Lamp", bpy.data.lights.new("Lamp", "POINT"), location=(0, 0, 5))
    recv = bpy.data.collections.new("Recv")
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    layer = scene.view_layers[0].layer_collection.children["Mattes"]
    seen = {}

    def handler(_scene, depsgraph):
        sync.update(depsgraph)

    def step(label, fn):
        fn()
        bpy.context.view_layer.update()
        seen[label] = (_ray_flags(sync.scene), _linked(sync.scene, "Lamp"))

    bpy.app.handlers.depsgraph_update_post.append(handler)
    try:
        step("holdout", lambda: setattr(layer, "holdout", True))
        step("indirect", lambda: (setattr(layer, "holdout", False), setattr(layer, "indirect_only", True)))
        step("receivers", lambda: (recv.objects.link(bpy.data.objects["Box"]),
                                   setattr(lamp.light_linking, "receiver_collection", recv)))
        step("excluded", lambda: setattr(recv.collection_objects[0].light_linking, "link_state", "EXCLUDE"))
        step("blockers", lambda: setattr(lamp.light_linking, "blocker_collection", recv))
        step("moved", lambda: setattr(lamp, "location", (1, 0, 5)))
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(handler)
    assert seen["holdout"][0]["Matte"] == (True, True, True)
    assert seen["indirect"][0]["Matte"] == (False, True, False)
    assert seen["receivers"][1] == {"Box": (True, True), "Matte": (False, True)}
    assert seen["excluded"][1] == {"Box": (False, True), "Matte": (True, True)}
    assert seen["blockers"][1] == {"Box": (False, False), "Matte": (True, True)}
    assert seen["moved"][1] == seen["blockers"][1]
    assert sync.scene.lights[0].position[0] == pytest.approx(1.0)


# --------------------------------------------------------------------------------------------
# transforms
# --------------------------------------------------------------------------------------------
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


def test_nan_transform_is_rejected_naming_the_object(scene):
    add_object("Fine", cube_mesh())
    add_object("Broken", cube_mesh("b")).location = (float("nan"), 0, 0)
    with pytest.raises(SceneError, match="'Broken'.*NaN"):
        export_scene()


def test_core_scene_rejects_infinite_transform():
    m = np.eye(4)
    m[0, 3] = np.inf
    scene = Scene(models=[Model("tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])],
                  instances=Instances(names=["Far"], matrices=[m]))
    with pytest.raises(SceneError, match="'Far'"):
        scene.validate(require_camera=False)
