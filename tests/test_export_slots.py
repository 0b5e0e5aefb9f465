"""Meshes with several material slots: one model per used slot, one instance per slot of every
object showing them (iterated, collection and geometry-nodes instances), object- and
data-linked slot materials; single-slot meshes export as without the split."""
import warnings

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender import export
from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.blender.export.common import ExportWarning
from hybrid_shadow_addon.blender.export.meshes import slot_name, slot_owner, smooth_normals
from hybrid_shadow_addon.blender.export.objects import SceneExporter
from hybrid_shadow_addon.blender.load import open_scene
from tests.helpers.export_scenes import add_object, empty_scene, gn_instancer, object_info
from tests.helpers.export_scenes import row as _row

pytestmark = [pytest.mark.blender]

BARK = (0.3, 0.15, 0.05, 1.0)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()


def _export(**kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExportWarning)
        return export_depsgraph(bpy.context.evaluated_depsgraph_get(), **kw).validate()


def _plain(name, rgba, roughness=0.5):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = rgba
    bsdf.inputs["Roughness"].default_value = roughness
    return mat


def _leaf_material(name="Leaf"):
    """An alpha-clipped leaf: colour and alpha from one image (Blender 4.2's Math node clip)."""
    img = bpy.data.images.new(name, 8, 8, alpha=True)
    px = np.random.default_rng(0).random((8, 8, 4)).astype(np.float32)
    px[..., 1] = 0.8
    img.pixels.foreach_set(px.ravel())
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = img
    clip = nodes.new("ShaderNodeMath")
    clip.operation = "GREATER_THAN"
    clip.inputs[1].default_value = 0.5
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(tex.outputs["Alpha"], clip.inputs[0])
    links.new(clip.outputs[0], bsdf.inputs["Alpha"])
    return mat


def _tree_mesh(name="tree", bark=None, leaf=None, leaves=3):
    """A trunk (a box, 6 quads, slot 0) and ``leaves`` leaf quads above it (slot 1), with UVs:
    slot 0's polygons come first, then interleaved so that the slots are not contiguous."""
    v = [(x * 0.2, y * 0.2, z * 2.0) for z in (0, 1) for y in (-1, 1) for x in (-1, 1)]
    box = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    faces, slots = [], []
    for i in range(leaves):
        z = 2.0 + 0.3 * i
        base = len(v)
        v += [(-1, -1 + i * 0.1, z), (1, -1, z), (1, 1, z + 0.2), (-1, 1, z + 0.2)]
        faces.append((base, base + 1, base + 2, base + 3))
        slots.append(1)
        if box:
            faces.append(box.pop(0))
            slots.append(0)
    faces += box
    slots += [0] * len(box)
    me = bpy.data.meshes.new(name)
    me.from_pydata(v, [], faces)
    me.polygons.foreach_set("material_index", slots)
    layer = me.uv_layers.new(name="UVMap")
    uv = np.random.default_rng(1).random((len(me.loops), 2)).astype(np.float32)
    layer.uv.foreach_set("vector", uv.ravel())
    me.materials.append(bark if bark is not None else _plain("Bark", BARK, 0.9))
    me.materials.append(leaf if leaf is not None else _leaf_material())
    me.update()
    return me


def _slot_reference(ob_name):
    """Per slot of an object's evaluated mesh, read here with Python loops: the world-space
    triangle corners (T, 3, 3), their UVs (T, 3, 2) and the polygon count."""
    dg = bpy.context.evaluated_depsgraph_get()
    ob = bpy.data.objects[ob_name].evaluated_get(dg)
    me = ob.data
    world = np.array(ob.matrix_world, np.float64)
    uv = me.uv_layers.active.data if len(me.uv_layers) else None
    out = {}
    for t in me.loop_triangles:
        k = min(t.material_index, len(ob.material_slots) - 1)
        corners = [tuple(me.vertices[i].co) for i in t.vertices]
        uvs = [tuple(uv[i].uv) for i in t.loops] if uv is not None else None
        out.setdefault(k, ([], []))
        out[k][0].append(corners)
        out[k][1].append(uvs)
    polys = {}
    for p in me.polygons:
        k = min(p.material_index, len(ob.material_slots) - 1)
        polys[k] = polys.get(k, 0) + 1
    res = {}
    for k, (corners, uvs) in out.items():
        c = np.array(corners, np.float64)
        c = c @ world[:3, :3].T + world[:3, 3]
        res[k] = (c, None if uvs[0] is None else np.array(uvs, np.float32), polys[k])
    return res


def _world_corners(s, row):
    m = s.models[int(s.instances.model_ids[row])]
    c = m.vertices[m.triangles].astype(np.float64)
    M = s.instances.matrices[row]
    return c @ M[:3, :3].T + M[:3, 3]


def _material_name(s, row):
    k = int(s.instances.material_ids[row])
    return None if k < 0 else s.materials[k].name


# --------------------------------------------------------------------------------------------
# names
# --------------------------------------------------------------------------------------------
def test_slot_names_round_trip():
    assert slot_name("Tree", 1) == "Tree [slot 1]"
    assert slot_owner("Tree [slot 1]") == "Tree" and slot_owner("GN/Tree[3] [slot 12]") == "GN/Tree[3]"
    for plain in ("Tree", "GN/Tree[3]", "Tree [slot x]", "Tree [slot 1] copy", "Tree [slot ]"):
        assert slot_owner(plain) == plain


# --------------------------------------------------------------------------------------------
# one object
# --------------------------------------------------------------------------------------------
def test_two_slots_become_two_models_and_two_instances(scene):
    ob = add_object("Tree", _tree_mesh(), location=(1, 2, 0))
    ob.rotation_euler = (0.1, 0.2, 0.3)
    ob.visible_shadow = False
    s = _export()
    assert [m.name for m in s.models] == ["tree [slot 0]", "tree [slot 1]"]
    assert s.instances.names == ["Tree", "Tree [slot 1]"]
    ref = _slot_reference("Tree")
    bark, leaf = _row(s, "Tree"), _row(s, "Tree [slot 1]")
    for row, k in ((bark, 0), (leaf, 1)):
        corners, uvs, n_poly = ref[k]
        model = s.models[int(s.instances.model_ids[row])]
        assert model.triangle_count == 2 * n_poly == len(corners)  # quads: 2 triangles each
        np.testing.assert_allclose(_world_corners(s, row), corners, atol=1e-5)
        # each slot's model has only the vertices its triangles use
        assert len(model.vertices) == len(np.unique(model.triangles))
    assert (ref[0][2], ref[1][2]) == (6, 3)
    np.testing.assert_array_equal(s.instances.matrices[bark], s.instances.matrices[leaf])
    np.testing.assert_allclose(s.instances.matrices[bark], np.array(ob.matrix_world), atol=1e-6)
    assert not s.instances.casts_shadow.any()
    # materials: opaque bark colour, textured alpha-clipped leaf
    assert _material_name(s, bark) is None and _material_name(s, leaf) == "Leaf"
    np.testing.assert_allclose(s.instances.base_color[bark], BARK, rtol=1e-6)
    assert s.instances.roughness[bark] == pytest.approx(0.9)
    (leaf_mat,) = s.materials
    assert leaf_mat.alpha_mode == "CLIP" and leaf_mat.alpha_image >= 0 and leaf_mat.color_image >= 0
    assert len(s.images) == 1
    # UVs only on the textured slot's model, those of its triangles
    assert s.models[int(s.instances.model_ids[bark])].uvs is None
    np.testing.assert_allclose(s.models[int(s.instances.model_ids[leaf])].uvs, ref[1][1], atol=1e-6)


def test_smooth_normals_follow_their_triangles(scene):
    me = _tree_mesh()
    me.shade_smooth()
    add_object("Tree", me)
    s = _export()
    full = smooth_normals(bpy.data.objects["Tree"].evaluated_get(bpy.context.evaluated_depsgraph_get()).data)
    index = np.array([t.material_index for t in me.loop_triangles])
    for k in (0, 1):
        model = s.models[int(s.instances.model_ids[k])]
        np.testing.assert_array_equal(model.normals, full[index == k])


def test_linked_duplicates_share_the_slot_models_and_names_stay_stable(scene):
    me = _tree_mesh()
    for i in range(3):
        add_object(f"Tree.{i}", me, location=(3 * i, 0, 0))
    first = _export()
    assert len(first.models) == 2 and len(first.instances) == 6
    assert len(set(first.instances.names)) == 6
    assert first.instances.names == ["Tree.0", "Tree.0 [slot 1]", "Tree.1", "Tree.1 [slot 1]",
                                     "Tree.2", "Tree.2 [slot 1]"]
    assert first.instances.model_ids.tolist() == [0, 1] * 3
    bpy.data.objects["Tree.1"].location.z = 5
    bpy.context.scene.frame_set(7)
    again = _export()
    assert again.instances.names == first.instances.names
    assert [m.name for m in again.models] == [m.name for m in first.models]
    np.testing.assert_allclose(again.instances.matrices[3, 2, 3], 5)


def test_object_linked_slot_materials(scene):
    me = _tree_mesh()
    red = _plain("Red", (1, 0, 0, 1))
    blue = _plain("Blue", (0, 0, 1, 1))
    a = add_object("A", me)
    a.material_slots[1].link = "OBJECT"
    a.material_slots[1].material = red  # the leaves of A are plain red
    b = add_object("B", me, location=(4, 0, 0))
    b.material_slots[0].link = "OBJECT"
    b.material_slots[0].material = blue  # the bark of B is blue, its leaves the data's
    s = _export()
    assert len(s.models) == 2
    colors = {n: tuple(np.round(c.astype(np.float64), 4)) for n, c in zip(s.instances.names, s.instances.base_color)}
    assert colors["A"] == BARK and colors["A [slot 1]"] == (1, 0, 0, 1)
    assert colors["B"] == (0, 0, 1, 1)
    assert _material_name(s, _row(s, "A [slot 1]")) is None
    assert _material_name(s, _row(s, "B [slot 1]")) == "Leaf"
    leaf_model = s.models[int(s.instances.model_ids[_row(s, "B [slot 1]")])]
    assert leaf_model.uvs is not None  # read for B's textured leaves, whoever comes first


def test_empty_slots_and_out_of_range_indices(scene):
    me = _tree_mesh()
    me.materials[0] = None  # empty slot 0: the object's colour (or grey)
    me.polygons[0].material_index = 7  # past the last slot: renders with the last one
    leaf_polys = sum(p.material_index >= 1 for p in me.polygons)
    ob = add_object("Tree", me)
    ob.color = (0.1, 0.9, 0.1, 1)
    s = _export()
    np.testing.assert_allclose(s.instances.base_color[0], (0.1, 0.9, 0.1, 1), rtol=1e-6)
    assert s.models[int(s.instances.model_ids[1])].triangle_count == 2 * leaf_polys


def test_a_mesh_using_one_of_its_slots(scene):
    """All triangles on one slot: one whole model; slot 0 keeps the plain names, another slot
    shows its own material under the object's name, its model suffixed."""
    me = _tree_mesh()
    me.polygons.foreach_set("material_index", [0] * len(me.polygons))
    me.update()
    add_object("Tree", me)
    s = _export()
    assert [m.name for m in s.models] == ["tree"] and s.instances.names == ["Tree"]
    assert s.models[0].triangle_count == 2 * len(me.polygons) and s.models[0].uvs is None
    np.testing.assert_allclose(s.instances.base_color[0], BARK, rtol=1e-6)
    me.polygons.foreach_set("material_index", [1] * len(me.polygons))
    me.update()
    s = _export()
    assert [m.name for m in s.models] == ["tree [slot 1]"] and s.instances.names == ["Tree"]
    assert s.models[0].triangle_count == 2 * len(me.polygons) and s.models[0].uvs is not None
    assert _material_name(s, 0) == "Leaf"


def test_slot_zero_unused(scene):
    me = _tree_mesh()
    me.materials.append(_plain("Moss", (0, 0.5, 0, 1)))
    index = np.array([p.material_index for p in me.polygons])
    index[index == 0] = 2
    me.polygons.foreach_set("material_index", index.tolist())
    me.update()
    add_object("Tree", me)
    s = _export()
    assert s.instances.names == ["Tree", "Tree [slot 2]"]  # the lowest used slot keeps the name
    assert [m.name for m in s.models] == ["tree [slot 1]", "tree [slot 2]"]
    assert _material_name(s, 0) == "Leaf"
    np.testing.assert_allclose(s.instances.base_color[1], (0, 0.5, 0, 1), rtol=1e-6)


def test_modifiers_and_curves_split_too(scene):
    ob = add_object("Tree", _tree_mesh())
    ob.modifiers.new("Sub", "SUBSURF").levels = 1
    curve = bpy.data.curves.new("Crv", "CURVE")
    curve.dimensions, curve.bevel_depth = "3D", 0.1
    curve.materials.append(_plain("C0", (1, 1, 0, 1)))  # first: the index is clamped to the slots
    curve.materials.append(_plain("C1", (0, 1, 1, 1)))
    for k in range(2):
        spline = curve.splines.new("POLY")
        spline.points.add(1)
        spline.points[0].co = (0, k, 0, 1)
        spline.points[1].co = (2, k, 0, 1)
        spline.material_index = k
    add_object("Crv", curve, location=(0, 5, 0))
    s = _export()
    names = s.instances.names
    assert names.count("Tree") == names.count("Tree [slot 1]") == 1
    assert names.count("Crv") == names.count("Crv [slot 1]") == 1
    ref = _slot_reference("Tree")
    for name, k in (("Tree", 0), ("Tree [slot 1]", 1)):
        np.testing.assert_allclose(_world_corners(s, _row(s, name)), ref[k][0], atol=1e-5)
    colors = {n: tuple(np.round(c.astype(np.float64), 4)) for n, c in zip(names, s.instances.base_color)}
    assert colors["Crv"] == (1, 1, 0, 1) and colors["Crv [slot 1]"] == (0, 1, 1, 1)
    crv = [s.models[int(s.instances.model_ids[_row(s, n)])].triangle_count for n in ("Crv", "Crv [slot 1]")]
    assert crv[0] == crv[1] > 0


def test_converted_objects_split_by_slot(scene):
    """The ``to_mesh()`` path (a non-mesh object without a mesh component), read once."""
    curve = bpy.data.curves.new("Crv", "CURVE")
    curve.dimensions, curve.bevel_depth = "3D", 0.1
    curve.materials.append(_plain("C0", (1, 1, 0, 1)))
    curve.materials.append(_leaf_material("C1"))
    for k in range(2):
        spline = curve.splines.new("POLY")
        spline.points.add(1)
        spline.points[1].co = (2, k, 0, 1)
        spline.material_index = k
    ob = add_object("Crv", curve).evaluated_get(bpy.context.evaluated_depsgraph_get())
    ex = SceneExporter(bpy.context.evaluated_depsgraph_get())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExportWarning)  # the bevel has UVs only when asked
        for name in ("A", "B"):
            ex._add_converted_instance(ob, ob.matrix_world, name)
    assert ex.names == ["A", "A [slot 1]", "B", "B [slot 1]"]
    assert [m.name for m in ex.models] == ["Crv [slot 0]", "Crv [slot 1]"] and ex.model_ids == [0, 1, 0, 1]
    assert ex.models[0].triangle_count == ex.models[1].triangle_count > 0


# --------------------------------------------------------------------------------------------
# instancers
# --------------------------------------------------------------------------------------------
def _gn_instancer(name, points, target, as_instance):
    return gn_instancer(name, points, object_info(target, as_instance))


def _summary(s):
    """Instances as sorted (model's slot, triangles, material, colour, position) rows (the two
    paths name the model of realised geometry differently)."""
    return sorted((s.models[m].name.rsplit(" [slot ", 1)[-1], s.models[m].triangle_count,
                   -1 if k < 0 else s.materials[k].name, tuple(np.round(c, 5)), tuple(np.round(mat[:3, 3], 4)))
                  for m, k, c, mat in zip(s.instances.model_ids, s.instances.material_ids, s.instances.base_color,
                                          s.instances.matrices))


@pytest.mark.parametrize("as_instance", [True, False])
def test_geometry_nodes_instances_split_by_slot(scene, monkeypatch, as_instance):
    src = add_object("Tree", _tree_mesh(), location=(0, 0, 50))
    src.hide_render = True
    red = _plain("Red", (1, 0, 0, 1))
    src.material_slots[0].link = "OBJECT"
    src.material_slots[0].material = red  # object-linked: only "as instance" keeps the object
    points = np.random.default_rng(0).uniform(-20, 20, (40, 3))
    _gn_instancer("GN", points, src, as_instance)
    fast = _export()
    assert len(fast.instances) == 80 and len(fast.models) == 2
    label = "Tree" if as_instance else None
    if label is None:  # realised geometry: labelled by the geometry's name
        label = fast.instances.names[0].split("/", 1)[1].rsplit("[", 1)[0]
    assert fast.instances.names == ([f"GN/{label}[{i}]" for i in range(40)]
                                    + [f"GN/{label}[{i}] [slot 1]" for i in range(40)])
    counts = sorted(m.triangle_count for m in fast.models)
    assert counts == [6, 12]
    leaf = [k for k, name in enumerate(fast.instances.names) if name.endswith(" [slot 1]")]
    bark = [k for k in range(80) if k not in leaf]
    assert {_material_name(fast, k) for k in leaf} == {"Leaf"}
    assert fast.models[int(fast.instances.model_ids[leaf[0]])].uvs is not None
    assert fast.models[int(fast.instances.model_ids[bark[0]])].uvs is None
    np.testing.assert_array_equal(fast.instances.matrices[bark], fast.instances.matrices[leaf])
    np.testing.assert_allclose(fast.instances.matrices[bark][:, :3, 3], points, atol=1e-4)
    bark_colors = {tuple(np.round(c.astype(np.float64), 4)) for c in fast.instances.base_color[bark]}
    assert bark_colors == {(1, 0, 0, 1)} if as_instance else len(bark_colors) == 1
    # the iterator agrees (names aside: it does not number the instances)
    monkeypatch.setattr(SceneExporter, "_vectorise", lambda self, ob: False)
    slow = _export()
    assert _summary(slow) == _summary(fast)
    assert sum(n.endswith(" [slot 1]") for n in slow.instances.names) == 40


def test_collection_instances_split_by_slot(scene):
    coll = bpy.data.collections.new("Grove")
    add_object("Tree", _tree_mesh(), coll, location=(1, 0, 0))
    for i in range(3):
        e = add_object(f"E{i}", None, location=(0, 5 * i, 0))
        e.instance_type, e.instance_collection = "COLLECTION", coll
    s = _export()
    assert len(s.models) == 2 and len(s.instances) == 6
    assert sorted(s.instances.names) == sorted(f"E{i}/Tree{sfx}" for i in range(3) for sfx in ("", " [slot 1]"))
    assert {_material_name(s, k) for k, n in enumerate(s.instances.names) if n.endswith(" [slot 1]")} == {"Leaf"}


# --------------------------------------------------------------------------------------------
# single-slot scenes: as without the split
# --------------------------------------------------------------------------------------------
def _content(s):
    i = s.instances
    return ([(m.name, m.vertices.tobytes(), m.triangles.tobytes(), None if m.normals is None else m.normals.tobytes(),
              None if m.uvs is None else m.uvs.tobytes()) for m in s.models],
            list(i.names), i.model_ids.tobytes(), i.matrices.tobytes(), i.casts_shadow.tobytes(),
            i.sphere.tobytes(), i.base_color.tobytes(), i.specular.tobytes(), i.roughness.tobytes(),
            i.material_ids.tobytes(), [m.name for m in s.materials], [m.name for m in s.images])


@pytest.mark.parametrize("arg", ["cube_on_plane", "forest:trees=40,spheres=10,terrain=32,variants=2,frames=50",
                                 "alpha_cards", "clusters:clusters=3,spheres=20", "city:blocks=1"])
def test_single_slot_scenes_export_as_without_the_split(monkeypatch, arg):
    """The built-in scenes (one slot per mesh) export exactly what the export without the
    split (slot_triangles switched off) does, names included."""
    open_scene(arg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours = export_depsgraph(bpy.context.evaluated_depsgraph_get())
        monkeypatch.setattr(export.meshes, "slot_triangles", lambda mesh, n_slots: None)
        before = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    assert _content(ours) == _content(before)
    assert not any(" [slot " in n for n in ours.instances.names + [m.name for m in ours.models])


def test_single_slot_names_and_counts():
    open_scene("cube_on_plane")
    s = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    assert [m.name for m in s.models] == ["Plane", "Cube"] and s.instances.names == ["Plane", "Cube"]
    open_scene("forest:trees=40,spheres=10,terrain=32,variants=2,frames=50")
    s = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    assert [m.name for m in s.models] == ["Terrain", "Palm 0", "Palm 1", "Ball"]
    assert len(s.instances) == 51 and s.instances.names[:3] == ["Terrain", "Palm.0000", "Palm.0001"]
    assert len(set(s.instances.names)) == 51


# --------------------------------------------------------------------------------------------
# the viewport's single-model rebuild
# --------------------------------------------------------------------------------------------
def test_viewport_rebuilds_only_slot_zero_meshes(scene):
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    me = _tree_mesh()
    ob = add_object("Tree", me)
    plain = add_object("Plain", _tree_mesh("plain"), location=(5, 0, 0))
    plain.data.polygons.foreach_set("material_index", [0] * len(plain.data.polygons))
    plain.data.update()
    sync = ViewportSync()
    dg = bpy.context.evaluated_depsgraph_get()
    sync.full_export(dg)
    assert sync._update_geometry(dg, "Plain", set())  # two slots, only slot 0 used
    assert not sync._update_geometry(dg, "Tree", set())  # split by slot
    # slot 0 only now, split at the last export: the full export must drop "Tree [slot 1]"
    me.polygons.foreach_set("material_index", [0] * len(me.polygons))
    me.update()
    dg = bpy.context.evaluated_depsgraph_get()
    assert not sync._update_geometry(dg, "Tree", set())
    # slot 1 only now: another material
    plain.data.polygons.foreach_set("material_index", [1] * len(plain.data.polygons))
    plain.data.update()
    dg = bpy.context.evaluated_depsgraph_get()
    assert not sync._update_geometry(dg, "Plain", set())
    sync.full_export(dg)
    assert sync.scene.models[int(sync.scene.instances.model_ids[sync.rows["Plain"][0]])].name == "plain [slot 1]"
    # ... and back to slot 0: the exported model shows slot 1, so a full export again
    plain.data.polygons.foreach_set("material_index", [0] * len(plain.data.polygons))
    plain.data.update()
    dg = bpy.context.evaluated_depsgraph_get()
    assert not sync._update_geometry(dg, "Plain", set())
    assert ob.name in sync.rows
