"""The export of materials: Principled colours, textured and alpha-cut-out materials (images,
UVs, Mapping nodes, alpha modes, fallbacks with warnings), on the alpha_cards scene and on small
scenes built here with bpy."""
import math
import warnings
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.blender.export.common import ExportWarning
from hybrid_shadow_addon.blender.export.lights import export_lights
from hybrid_shadow_addon.blender.export.materials import blend_settings
from hybrid_shadow_addon.blender.export.objects import SceneExporter
from hybrid_shadow_addon.blender.load import load_scene, open_scene
from tests.helpers.export_scenes import add_object, cube_mesh, empty_scene, export_scene
from tests.helpers.export_scenes import row as _row

pytestmark = [pytest.mark.blender]


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()
def _quad(name, uvs=((0, 0), (1, 0), (1, 1), (0, 1)), layers=("UVMap",)):
    """A unit quad with one UV layer per name in ``layers`` (the k-th layer's UVs are ``uvs``
    shifted by k in u)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    for k, layer_name in enumerate(layers):
        layer = me.uv_layers.new(name=layer_name)
        layer.uv.foreach_set("vector", (np.float32(uvs) + [k, 0]).ravel())
    return me


def _image(name="tex", w=8, h=4, seed=0, **kw):
    img = bpy.data.images.new(name, w, h, alpha=True, **kw)
    px = np.random.default_rng(seed).random((h, w, 4)).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    return img, px


def _textured(name, image, color=True, alpha="Alpha"):
    """A Principled material whose Base Color (``color``) and Alpha (the image's ``alpha``
    output; None: unlinked) read ``image``. Returns (material, nodes dict)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    if color:
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    if alpha:
        links.new(tex.outputs[alpha], bsdf.inputs["Alpha"])
    return mat, {"bsdf": bsdf, "tex": tex}


def _material_of(s, name):
    k = int(s.instances.material_ids[_row(s, name)])
    return None if k < 0 else s.materials[k]


def _bpy_uvs(mesh_name, layer=None):
    """(T, 3, 2) UVs of a mesh's loop triangles read here with plain Python loops."""
    me = bpy.data.meshes[mesh_name]
    me.calc_loop_triangles()
    data = (me.uv_layers[layer] if layer else me.uv_layers.active).data
    return np.array([[tuple(data[i].uv) for i in t.loops] for t in me.loop_triangles], np.float32)


def _export_warnings(fn):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        out = fn()
    return out, [str(w.message) for w in rec if issubclass(w.category, ExportWarning)]


# --------------------------------------------------------------------------------------------
# plain materials
# --------------------------------------------------------------------------------------------
def test_material_colours(scene):
    me_red = cube_mesh("red")
    mat = bpy.data.materials.new("Red")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.9, 0.1, 0.05, 1)
    bsdf.inputs["Specular IOR Level"].default_value = 0.25
    bsdf.inputs["Roughness"].default_value = 0.7
    me_red.materials.append(mat)
    add_object("Red", me_red)
    plain = cube_mesh("plain")
    add_object("Grey", plain)
    add_object("Tinted", plain).color = (0.1, 0.2, 0.3, 1)
    s = export_scene()
    rows = {n: i for i, n in enumerate(s.instances.names)}
    inst = s.instances
    np.testing.assert_allclose(inst.base_color[rows["Red"]], (0.9, 0.1, 0.05, 1), rtol=1e-6)
    assert (inst.specular[rows["Red"]], inst.roughness[rows["Red"]]) == pytest.approx((0.25, 0.7))
    np.testing.assert_allclose(inst.base_color[rows["Grey"]], (0.8, 0.8, 0.8, 1))
    np.testing.assert_allclose(inst.base_color[rows["Tinted"]], (0.1, 0.2, 0.3, 1), rtol=1e-6)


# --------------------------------------------------------------------------------------------
# the alpha_cards scene
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cards():
    """alpha_cards exported (validated), the Leaf card mesh's UVs and the Blender images'
    pixels read straight from bpy."""
    s = load_scene("alpha_cards")
    uvs = _bpy_uvs("Leaf card")
    pixels = {}
    for img in bpy.data.images:
        w, h = img.size
        buf = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(buf)
        pixels[img.name] = buf.reshape(h, w, 4)
    return s, uvs, pixels


def test_alpha_cards_materials_and_images(cards):
    s, _, pixels = cards
    mats = {m.name: m for m in s.materials}
    assert sorted(mats) == ["Fence", "Ground", "Leaf"]
    images = [i.name for i in s.images]
    assert sorted(images) == ["fence_wire", "ground_checker", "leaf"]
    assert {i.name: i.size for i in s.images} == {"ground_checker": (256, 256), "leaf": (128, 192),
                                                 "fence_wire": (64, 64)}
    ground, leaf, fence = mats["Ground"], mats["Leaf"], mats["Fence"]
    assert s.images[ground.color_image].name == "ground_checker" and ground.alpha_image == -1
    assert not ground.has_alpha and ground.textured
    assert s.images[leaf.color_image].name == "leaf" and leaf.alpha_image == leaf.color_image
    assert leaf.alpha_channel == "A" and leaf.alpha_mode == "BLEND" and leaf.transparent_shadow
    assert fence.color_image == -1 and s.images[fence.alpha_image].name == "fence_wire"
    # the Mapping node's scale repeats the wire image 24 x 8 times
    np.testing.assert_allclose(fence.uv_transform, [[24, 0, 0], [0, 8, 0]], atol=1e-6)
    np.testing.assert_allclose(leaf.uv_transform, [[1, 0, 0], [0, 1, 0]])
    by_name = {i.name: i for i in s.images}
    assert by_name["leaf"].extension == "CLIP" and by_name["fence_wire"].extension == "REPEAT"
    assert all(i.srgb and i.interpolation == "Linear" for i in s.images)
    # pixels as Blender stores them, row 0 at the bottom: the leaf's stalk is there, the tip on top
    for name, img in by_name.items():
        np.testing.assert_array_equal(img.pixels, np.round(pixels[name] * 255).astype(np.uint8))
    leaf_alpha = by_name["leaf"].pixels[..., 3]
    assert leaf_alpha[2, 62:66].min() == 255 and leaf_alpha[-2].max() == 0
    assert 0.2 < (leaf_alpha > 127).mean() < 0.8
    assert set(np.unique(by_name["fence_wire"].pixels[..., 3])) == {0, 255}


def test_alpha_cards_instances(cards):
    s, _, _ = cards
    inst = s.instances
    names = [None if k < 0 else s.materials[k].name for k in inst.material_ids.tolist()]
    of = dict(zip(inst.names, names))
    assert of["Ground"] == "Ground" and of["Fence"] == "Fence"
    for card in ("Card flat", "Card tilted", "Card steep", "Card upright"):
        assert of[card] == "Leaf"
    cluster = [n for n in inst.names if n.startswith("Leaf cluster/")]
    assert len(cluster) == 40 and all(of[n] == "Leaf" for n in cluster)
    assert all(of[f"Fence post.{i}"] is None for i in range(3))
    colors = dict(zip(inst.names, inst.base_color))
    np.testing.assert_allclose(colors["Ground"], (1, 1, 1, 1))
    np.testing.assert_allclose(colors["Card flat"], (1, 1, 1, 1))
    np.testing.assert_allclose(colors["Fence"][:3], (0.55, 0.56, 0.6), rtol=1e-6)  # not textured: its colour


def test_alpha_cards_uvs_and_alpha_models(cards):
    s, leaf_uvs, _ = cards
    with_uvs = {m.name for m in s.models if m.uvs is not None}
    assert with_uvs == {"Ground", "Leaf card", "Fence"}
    leaf = next(m for m in s.models if m.name == "Leaf card")
    assert leaf.uvs.shape == (2, 3, 2)
    np.testing.assert_array_equal(leaf.uvs, leaf_uvs)
    assert {tuple(map(float, uv)) for uv in leaf.uvs.reshape(-1, 2)} == {(0, 0), (1, 0), (1, 1), (0, 1)}
    alpha = {m.name for m, a in zip(s.models, s.alpha_models()) if a}
    assert alpha == {"Leaf card", "Fence"}
    assert s.summary()["alpha_models"] == 2


def test_alpha_cards_opaque_variant_has_no_alpha_models():
    s = load_scene("alpha_cards:opaque=1")
    assert not s.alpha_models().any()
    assert sorted(m.name for m in s.materials) == ["Ground", "Leaf"]  # the colour textures stay
    assert all(m.alpha_image == -1 and not m.has_alpha for m in s.materials)
    assert s.instances.material_ids[_row(s, "Fence")] == -1
    assert {m.name for m in s.models if m.uvs is not None} == {"Ground", "Leaf card"}


def test_vectorised_and_iterated_instances_agree_on_materials(monkeypatch):
    def summary(s):
        return sorted((s.models[m].name, -1 if k < 0 else s.materials[k].name, tuple(np.round(c, 5)))
                      for m, k, c in zip(s.instances.model_ids, s.instances.material_ids, s.instances.base_color))
    fast = load_scene("alpha_cards")
    monkeypatch.setattr(SceneExporter, "_vectorise", lambda self, ob: False)
    slow = load_scene("alpha_cards")
    assert summary(fast) == summary(slow)
    assert [m.name for m in slow.models if m.uvs is not None] == [m.name for m in fast.models if m.uvs is not None]


def test_opaque_scene_has_no_materials_images_or_uvs():
    s = load_scene("cube_on_plane")
    assert s.materials == [] and s.images == []
    assert all(m.uvs is None for m in s.models)
    assert (s.instances.material_ids == -1).all()
    assert not s.alpha_models().any()


# --------------------------------------------------------------------------------------------
# node set-ups
# --------------------------------------------------------------------------------------------
def test_colour_and_alpha_images(scene):
    img, px = _image("tex", 8, 4)
    mat, _ = _textured("Both", img)
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert warned == []
    (m,) = s.materials
    assert (m.color_image, m.alpha_image, m.alpha_channel, m.alpha) == (0, 0, "A", 1.0)
    (image,) = s.images
    assert image.size == (8, 4) and image.srgb
    np.testing.assert_array_equal(image.pixels, np.round(px * 255).astype(np.uint8))
    np.testing.assert_allclose(s.instances.base_color[0], (1, 1, 1, 1))
    np.testing.assert_array_equal(s.models[0].uvs, _bpy_uvs("q"))


def _write_png16(path, rgba16):
    """A 16-bit RGBA PNG of ``rgba16`` (H, W, 4) uint16, row 0 at the top."""
    import struct
    import zlib

    h, w = rgba16.shape[:2]
    rows = b"".join(b"\x00" + rgba16[y].astype(">u2").tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 6, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def test_a_float_image_keeps_its_values(scene, tmp_path):
    """A float image, and a 16-bit PNG (Blender holds both as floats), are exported as float32,
    unquantised: an alpha compared with a clip threshold keeps its side of it."""
    img = bpy.data.images.new("floaty", 8, 4, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    px = np.random.default_rng(0).random((4, 8, 4)).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    path = tmp_path / "sixteen.png"
    alpha16 = np.random.default_rng(1).integers(0, 65536, (4, 8), np.uint16)
    _write_png16(path, np.dstack([alpha16] * 4))
    sixteen = bpy.data.images.load(str(path))
    sixteen.colorspace_settings.name = "Non-Color"
    assert sixteen.is_float
    for k, image in enumerate((img, sixteen)):
        mat, _ = _textured(f"M{k}", image)
        me = _quad(f"q{k}")
        me.materials.append(mat)
        add_object(f"Q{k}", me, location=(2 * k, 0, 0))
    s = export_scene()
    s.validate()
    by_name = {i.name: i for i in s.images}
    got = by_name["floaty"]
    assert got.is_float and got.pixels.dtype == np.float32 and not got.srgb
    np.testing.assert_array_equal(got.pixels, np.clip(px, 0, 1))
    got16 = by_name[sixteen.name]
    assert got16.is_float
    np.testing.assert_allclose(got16.pixels[..., 3], alpha16[::-1] / 65535.0, atol=1e-6)
    assert not np.allclose(got16.pixels[..., 3] * 255, np.round(got16.pixels[..., 3] * 255), atol=1e-3)


def test_alpha_from_the_colour_output_is_luma(scene):
    img, _ = _image()
    mat, _ = _textured("Luma", img, color=False, alpha="Color")
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.2, 0.3, 0.4, 1)
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s = export_scene().validate()
    (m,) = s.materials
    assert (m.color_image, m.alpha_image, m.alpha_channel) == (-1, 0, "LUMA")
    np.testing.assert_allclose(s.instances.base_color[0], (0.2, 0.3, 0.4, 1), rtol=1e-6)


def test_constant_alpha_is_a_material_without_images_or_uvs(scene):
    mat = bpy.data.materials.new("Glass")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.25
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s = export_scene().validate()
    (m,) = s.materials
    assert m.alpha == pytest.approx(0.25) and not m.textured and m.has_alpha
    assert s.images == [] and s.models[0].uvs is None
    assert s.alpha_models().tolist() == [True]


def test_mapping_nodes_become_the_uv_transform(scene):
    img, _ = _image()
    loc, rot, scale = (0.3, -0.2, 0.7), (0.0, 0.0, 0.5), (2.0, 3.0, 1.5)

    def mapped(name, kind):
        mat, n = _textured(name, img)
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        uvmap, mapping = nodes.new("ShaderNodeUVMap"), nodes.new("ShaderNodeMapping")
        mapping.vector_type = kind
        mapping.inputs["Location"].default_value = loc
        mapping.inputs["Rotation"].default_value = rot
        mapping.inputs["Scale"].default_value = scale
        links.new(uvmap.outputs["UV"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], n["tex"].inputs["Vector"])
        return mat

    for i, kind in enumerate(("POINT", "TEXTURE")):
        me = _quad(f"q{kind}")
        me.materials.append(mapped(kind, kind))
        add_object(kind, me, location=(3 * i, 0, 0))
    s = export_scene().validate()
    c, sn = math.cos(0.5), math.sin(0.5)
    point = np.array([[c * 2, -sn * 3, 0.3], [sn * 2, c * 3, -0.2]])
    np.testing.assert_allclose(_material_of(s, "POINT").uv_transform, point, rtol=1e-5, atol=1e-6)
    # TEXTURE is the inverse of POINT
    tex = np.vstack([_material_of(s, "TEXTURE").uv_transform, [0, 0, 1]])
    np.testing.assert_allclose(np.vstack([point, [0, 0, 1]]) @ tex, np.eye(3), atol=1e-5)


def test_uv_map_node_selects_its_layer(scene):
    img, _ = _image()
    mat, n = _textured("Second UV", img)
    uvmap = mat.node_tree.nodes.new("ShaderNodeUVMap")
    uvmap.uv_map = "Second"
    mat.node_tree.links.new(uvmap.outputs["UV"], n["tex"].inputs["Vector"])
    me = _quad("q", layers=("UVMap", "Second"))
    me.materials.append(mat)
    add_object("Q", me)
    s = export_scene().validate()
    np.testing.assert_array_equal(s.models[0].uvs, _bpy_uvs("q", "Second"))
    assert s.models[0].uvs[..., 0].min() == 1.0  # the second layer is shifted by 1 in u


def test_unsupported_node_warns_once_naming_it_and_falls_back(scene):
    img, _ = _image()
    mat, n = _textured("Mixed", img, alpha=None)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.name = "Tint mix"
    links.new(n["tex"].outputs["Color"], mix.inputs["A"])
    links.new(mix.outputs["Result"], n["bsdf"].inputs["Base Color"])
    n["bsdf"].inputs["Base Color"].default_value = (0.1, 0.5, 0.9, 1)
    me = _quad("q")
    me.materials.append(mat)
    for i in range(5):
        add_object(f"Q{i}", me, location=(2 * i, 0, 0))
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert len(warned) == 1, warned
    assert "'Mixed'" in warned[0] and "'Tint mix'" in warned[0] and "Base Color" in warned[0]
    assert s.materials == [] and s.images == [] and s.models[0].uvs is None
    np.testing.assert_allclose(s.instances.base_color, np.tile([0.1, 0.5, 0.9, 1], (5, 1)), rtol=1e-6)


def test_unsupported_alpha_node_falls_back_to_the_alpha_value(scene):
    img, _ = _image()
    mat, n = _textured("Scaled alpha", img, color=False, alpha=None)
    math_node = mat.node_tree.nodes.new("ShaderNodeMath")
    math_node.operation = "MULTIPLY"
    mat.node_tree.links.new(n["tex"].outputs["Alpha"], math_node.inputs[0])
    mat.node_tree.links.new(math_node.outputs[0], n["bsdf"].inputs["Alpha"])
    n["bsdf"].inputs["Alpha"].default_value = 0.4
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert len(warned) == 1 and "'Scaled alpha'" in warned[0] and "Alpha" in warned[0]
    (m,) = s.materials
    assert m.alpha_image == -1 and m.alpha == pytest.approx(0.4)


def _normal_mapped(name, kind="ShaderNodeNormalMap", shader=None, via_reroute=False):
    """A material whose BSDF (the Principled, or a new node of type ``shader``) has its Normal
    fed by a ``kind`` node (Normal Map: its Color from an image; Bump: its Height from the
    image's alpha)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    if shader is not None:
        nodes.remove(bsdf)
        bsdf = nodes.new(shader)
        links.new(bsdf.outputs[0], nodes["Material Output"].inputs["Surface"])
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = _image(f"{name} normals")[0]
    bender = nodes.new(kind)
    links.new(tex.outputs["Color" if kind == "ShaderNodeNormalMap" else "Alpha"],
              bender.inputs["Color" if kind == "ShaderNodeNormalMap" else "Height"])
    out = bender.outputs["Normal"]
    if via_reroute:
        reroute = nodes.new("NodeReroute")
        links.new(out, reroute.inputs[0])
        out = reroute.outputs[0]
    links.new(out, bsdf.inputs["Normal"])
    return mat, bender


def test_normal_maps_are_listed_once_per_material(scene):
    """A Normal Map (or Bump) node feeding a BSDF's Normal: the export report lists the material
    once, however many objects show it; materials without one, a muted one, or one left
    unconnected are not listed."""
    mapped, _ = _normal_mapped("Bricks")
    bumped, _ = _normal_mapped("Bumpy", kind="ShaderNodeBump", shader="ShaderNodeBsdfDiffuse",
                                via_reroute=True)
    muted, node = _normal_mapped("Muted")
    node.mute = True
    loose, node = _normal_mapped("Loose")
    loose.node_tree.links.remove(loose.node_tree.nodes["Principled BSDF"].inputs["Normal"].links[0])
    plain = bpy.data.materials.new("Plain")
    plain.use_nodes = True
    for i, mat in enumerate((mapped, mapped, bumped, muted, loose, plain)):
        me = cube_mesh(f"m{i}")
        me.materials.append(mat)
        add_object(f"O{i}", me, location=(3 * i, 0, 0))
    s, warned = _export_warnings(export_scene)
    s.validate()
    listed = sorted(w for w in warned if "normal map not read (facing decided by the mesh's own normals)" in w)
    assert len(listed) == 2, warned
    assert "'Bricks'" in listed[0] and "'Normal Map'" in listed[0] and "'Principled BSDF'" in listed[0]
    assert "'Bumpy'" in listed[1] and "'Bump'" in listed[1] and "'Diffuse BSDF'" in listed[1]
    assert not any(n in w for w in warned for n in ("'Muted'", "'Loose'", "'Plain'")), warned
    assert s.materials == [] and s.images == []


def test_math_greater_than_is_alpha_clip(scene):
    """Blender 4.2 turns an old Alpha Clip material into alpha > threshold (a Math node)."""
    img, _ = _image()
    mat, n = _textured("Clipped", img, alpha=None)
    gt = mat.node_tree.nodes.new("ShaderNodeMath")
    gt.operation = "GREATER_THAN"
    gt.inputs[1].default_value = 0.3
    mat.node_tree.links.new(n["tex"].outputs["Alpha"], gt.inputs[0])
    mat.node_tree.links.new(gt.outputs[0], n["bsdf"].inputs["Alpha"])
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert warned == []
    (m,) = s.materials
    assert (m.alpha_mode, m.alpha_image, m.alpha_channel) == ("CLIP", 0, "A")
    assert m.alpha_threshold == pytest.approx(0.3)


def test_blend_settings():
    assert blend_settings(SimpleNamespace(blend_method="CLIP", alpha_threshold=0.25,
                                          use_transparent_shadow=True)) == ("CLIP", 0.25, True)
    assert blend_settings(SimpleNamespace(blend_method="BLEND", alpha_threshold=0.5,
                                          use_transparent_shadow=False)) == ("BLEND", 0.5, False)
    # before 4.2: the shadow mode
    assert blend_settings(SimpleNamespace(blend_method="CLIP", alpha_threshold=0.1,
                                          shadow_method="OPAQUE"))[2] is False
    assert blend_settings(SimpleNamespace(blend_method="HASHED", shadow_method="CLIP")) == ("BLEND", 0.5, True)
    # Blender 5: none of them
    assert blend_settings(SimpleNamespace()) == ("BLEND", 0.5, True)


def test_transparent_shadow_off(scene):
    img, _ = _image()
    mat, _ = _textured("Solid shadow", img)
    mat.use_transparent_shadow = False
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s = export_scene().validate()
    (m,) = s.materials
    assert m.transparent_shadow is False and m.has_alpha
    assert not s.alpha_models().any()


def test_missing_image_warns_and_falls_back(scene):
    img = bpy.data.images.new("gone", 4, 4)
    img.source = "FILE"
    img.filepath = "/nonexistent/hybrid-shadows/gone.png"
    mat, n = _textured("Lost", img)
    n["bsdf"].inputs["Base Color"].default_value = (0.3, 0.2, 0.1, 1)
    me = _quad("q")
    me.materials.append(mat)
    add_object("Q", me)
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert len(warned) == 1 and "'gone'" in warned[0] and "'Lost'" in warned[0]
    assert s.materials == [] and s.images == [] and s.models[0].uvs is None
    np.testing.assert_allclose(s.instances.base_color[0], (0.3, 0.2, 0.1, 1), rtol=1e-6)


def test_textured_mesh_without_uvs_drops_the_material(scene):
    img, _ = _image()
    mat, n = _textured("Needs UVs", img)
    n["bsdf"].inputs["Base Color"].default_value = (0.7, 0.1, 0.1, 1)
    me = _quad("bare", layers=())
    me.materials.append(mat)
    add_object("Bare", me)
    add_object("Bare.001", me, location=(3, 0, 0))
    s, warned = _export_warnings(export_scene)
    s.validate()
    assert len(warned) == 1 and "'Bare" in warned[0] and "UV" in warned[0]
    assert (s.instances.material_ids == -1).all() and s.models[0].uvs is None
    np.testing.assert_allclose(s.instances.base_color, np.tile([0.7, 0.1, 0.1, 1], (2, 1)), rtol=1e-6)


def test_one_mesh_with_and_without_a_textured_material(scene):
    img, _ = _image()
    tex_mat, _ = _textured("Textured", img)
    plain = bpy.data.materials.new("Plain")
    me = _quad("shared")
    me.materials.append(tex_mat)
    a = add_object("A plain", me)
    a.material_slots[0].link = "OBJECT"
    a.material_slots[0].material = plain
    add_object("B textured", me, location=(3, 0, 0))
    for _ in range(2):  # whichever comes first
        s = export_scene().validate()
        assert len(s.models) == 1 and s.models[0].uvs is not None
        assert _material_of(s, "A plain") is None
        assert _material_of(s, "B textured").name == "Textured"
        bpy.data.objects.remove(a)
        a = add_object("A plain", me)
        a.material_slots[0].link = "OBJECT"
        a.material_slots[0].material = plain


def test_image_colour_spaces_and_settings(scene):
    byte, _ = _image("byte")
    data, _ = _image("data")
    data.colorspace_settings.name = "Non-Color"
    flt, fpx = _image("float", float_buffer=True)
    opaque, _ = _image("no alpha")
    opaque.alpha_mode = "NONE"
    for i, (img, interp) in enumerate(((byte, "Cubic"), (data, "Closest"), (flt, "Linear"), (opaque, "Smart"))):
        mat, n = _textured(f"M{i}", img)
        n["tex"].interpolation = interp
        n["tex"].extension = ("EXTEND", "MIRROR", "CLIP", "REPEAT")[i]
        me = _quad(f"q{i}")
        me.materials.append(mat)
        add_object(f"Q{i}", me, location=(2 * i, 0, 0))
    s = export_scene().validate()
    imgs = {i.name: i for i in s.images}
    assert {n: (i.srgb, i.interpolation, i.extension) for n, i in imgs.items()} == {
        "byte": (True, "Cubic", "EXTEND"), "data": (False, "Closest", "MIRROR"),
        "float": (False, "Linear", "CLIP"), "no alpha": (True, "Cubic", "REPEAT")}  # Smart: Cycles' cubic
    np.testing.assert_array_equal(imgs["float"].pixels, np.clip(fpx, 0, 1))  # (float: kept unquantised)
    assert (imgs["no alpha"].pixels[..., 3] == 255).all()


def test_every_builtin_scene_validates_with_its_materials():
    """alpha_cards and the opaque scenes: the export validates and opaque scenes stay opaque."""
    for arg in ("alpha_cards", "alpha_cards:opaque=1", "cube_on_plane", "clusters:clusters=2,spheres=20",
                "city:blocks=1", "animated", "forest:trees=10,spheres=4,terrain=16,variants=1,frames=5"):
        s = load_scene(arg)
        if not arg.startswith("alpha_cards"):
            assert s.materials == [] and s.images == [], arg


# --------------------------------------------------------------------------------------------
# against Cycles
# --------------------------------------------------------------------------------------------
@pytest.mark.cycles
def test_alpha_cards_transparent_shadows_match_cycles():
    """The exported alpha (images, UVs, mapping, row order) casts the shadows Cycles casts: the
    numpy oracle's visibility from Cycles' own surface points equals Cycles' per light."""
    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.core.oracle.tracer import visibility_brute

    w, h = 160, 120
    bscene = open_scene("alpha_cards")
    bounces = bscene.cycles.transparent_max_bounces
    ref = render_reference(bscene, resolution=(w, h))
    assert bscene.cycles.transparent_max_bounces == bounces, "the scene is restored"
    s = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(w, h)).validate()
    pos = ref.position.reshape(-1, 3).astype(np.float64)
    for light in s.lights:
        theirs = ref.visibility[light.name].ravel()
        ok = ~np.isnan(theirs) & ~np.isnan(pos[:, 0])
        p = pos[ok]
        if light.type == "SUN":
            d, tmax = np.broadcast_to(-light.direction, p.shape).copy(), np.inf
        else:
            d = light.position - p
            tmax = np.linalg.norm(d, axis=1)
            d /= tmax[:, None]
            tmax = tmax - 1e-3
        ours = visibility_brute(s, p + 2e-3 * d, d, tmax)
        assert ok.sum() > 0.5 * w * h
        partial = (theirs[ok] > 0.05) & (theirs[ok] < 0.95)
        assert (theirs[ok] < 0.5).mean() > 0.1 and partial.mean() < 0.2, light.name
        mismatch = (np.abs(ours - theirs[ok]) > 0.5).mean()
        assert mismatch < 0.005, f"{light.name}: {mismatch:.3%} of the pixels disagree"


@pytest.mark.cycles
def test_diffuse_color_pass_is_the_exported_albedo():
    """render_diffuse_color on the ground of alpha_cards: the colour image as the export reads
    it (oracle albedo at the ground's UVs, which are its xy / 14 m + 0.5)."""
    from hybrid_shadow_addon.blender.cycles_reference import render_diffuse_color, render_reference
    from hybrid_shadow_addon.core.oracle.alpha import albedo

    w, h = 120, 90
    bscene = open_scene("alpha_cards")
    color = render_diffuse_color(bscene, (w, h))
    assert color.shape == (h, w, 3) and color.dtype == np.float32
    assert np.isnan(color[0]).all() and not np.isnan(color[-1]).any()  # row 0: the sky at the top
    spec = bpy.data.materials["Ground"].node_tree.nodes["Principled BSDF"].inputs["Specular IOR Level"]
    assert spec.default_value == pytest.approx(0.5) and bscene.render.engine != "CYCLES"  # restored
    pos = render_reference(bscene, [], resolution=(w, h)).position
    s = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(w, h)).validate()
    ground = (np.abs(pos[..., 2]) < 1e-4) & (np.abs(pos[..., :2]) < 6.9).all(axis=-1) & ~np.isnan(color[..., 0])
    assert ground.sum() > 0.3 * w * h
    uv = pos[ground][:, :2] / 14.0 + 0.5
    ours = albedo(s, np.full(len(uv), _row(s, "Ground")), uv)
    err = np.abs(ours - color[ground]).max(axis=1)
    assert np.percentile(err, 95) < 1e-3, np.percentile(err, [50, 95, 100])
    assert ours.std(axis=0).min() > 0.02  # the checker shows


# --------------------------------------------------------------------------------------------
# shader-node materials other than a Principled BSDF, and the export report
# --------------------------------------------------------------------------------------------
def _node_material(name, kind, **inputs):
    """A material whose Surface is one shader node ``kind`` with ``inputs`` set."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    node = nodes.new(kind)
    for k, v in inputs.items():
        node.inputs[k].default_value = v
    mat.node_tree.links.new(node.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat, node


def _on_quad(name, mat):
    me = _quad(name)
    me.materials.append(mat)
    add_object(name, me)


def test_bsdf_colours_glass_and_emission(scene):
    _on_quad("Clay", _node_material("Clay", "ShaderNodeBsdfDiffuse", Color=(0.7, 0.3, 0.2, 1))[0])
    _on_quad("Shiny", _node_material("Shiny", "ShaderNodeBsdfGlossy", Color=(0.1, 0.2, 0.9, 1))[0])
    _on_quad("Ball", _node_material("Glass", "ShaderNodeBsdfGlass", Color=(0.8, 0.9, 1.0, 1))[0])
    _on_quad("Panel", _node_material("Panel", "ShaderNodeEmission", Color=(1.0, 0.5, 0.25, 1), Strength=4.0)[0])
    s, warned = _export_warnings(export_scene)
    inst = s.instances
    np.testing.assert_allclose(inst.base_color[_row(s, "Clay")], (0.7, 0.3, 0.2, 1), rtol=1e-6)
    assert inst.specular[_row(s, "Clay")] == 0.0
    np.testing.assert_allclose(inst.base_color[_row(s, "Shiny")][:3], (0.1, 0.2, 0.9), rtol=1e-6)
    glass = _row(s, "Ball")
    assert inst.material_ids[glass] == -1 and inst.casts_shadow[glass]  # opaque to shadow rays
    np.testing.assert_allclose(inst.emission[_row(s, "Panel")], (4.0, 2.0, 1.0), rtol=1e-6)
    assert not inst.emission[_row(s, "Clay")].any()
    assert any("'Shiny'" in w and "read as Diffuse" in w for w in warned), warned
    assert any("'Glass'" in w and "opaque" in w for w in warned), warned
    assert any("'Panel'" in w and "lights nothing" in w for w in warned), warned
    assert not any("'Clay'" in w for w in warned), warned
    assert s.report == list(dict.fromkeys(warned)), (s.report, warned)


def test_transparent_bsdf_alone(scene):
    _on_quad("Veil", _node_material("Veil", "ShaderNodeBsdfTransparent")[0])
    _on_quad("Smoke", _node_material("Smoke", "ShaderNodeBsdfTransparent", Color=(0.25, 0.25, 0.25, 1))[0])
    s = export_scene()
    assert _material_of(s, "Veil").alpha == pytest.approx(0.0)  # the camera and shadow rays pass
    assert _material_of(s, "Smoke").alpha == pytest.approx(0.75, abs=1e-6)  # transmits a quarter


def _mix_transparent(name, fac=None, image=None, transparent_first=True, group=False, clip=None, color=(1, 1, 1, 1)):
    """Mix(Transparent, Diffuse) (or swapped), its factor ``fac`` or ``image``'s alpha (through a
    Math ``clip`` = (operation, threshold)), the mix inside a node group when ``group``."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, link = mat.node_tree.nodes, mat.node_tree.links.new
    nodes.remove(nodes["Principled BSDF"])
    tree = bpy.data.node_groups.new(name, "ShaderNodeTree") if group else mat.node_tree
    tn, tl = tree.nodes, tree.links.new
    mix = tn.new("ShaderNodeMixShader")
    clear = tn.new("ShaderNodeBsdfTransparent")
    clear.inputs["Color"].default_value = color
    diffuse = tn.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.1, 0.6, 0.1, 1)
    a, b = (clear, diffuse) if transparent_first else (diffuse, clear)
    tl(a.outputs[0], mix.inputs[1])
    tl(b.outputs[0], mix.inputs[2])
    fac_in, shader_out = mix.inputs["Fac"], mix.outputs[0]
    if group:
        tree.interface.new_socket("Fac", in_out="INPUT", socket_type="NodeSocketFloat")
        tree.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
        gin, gout = tn.new("NodeGroupInput"), tn.new("NodeGroupOutput")
        tl(gin.outputs["Fac"], mix.inputs["Fac"])
        tl(mix.outputs[0], gout.inputs["Shader"])
        gnode = nodes.new("ShaderNodeGroup")
        gnode.node_tree = tree
        fac_in, shader_out = gnode.inputs["Fac"], gnode.outputs["Shader"]
    link(shader_out, nodes["Material Output"].inputs["Surface"])
    if fac is not None:
        fac_in.default_value = fac
    if image is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        src = tex.outputs["Alpha"]
        if clip is not None:
            math_node = nodes.new("ShaderNodeMath")
            math_node.operation = clip[0]
            math_node.inputs[1].default_value = clip[1]
            link(src, math_node.inputs[0])
            src = math_node.outputs[0]
        link(src, fac_in)
    return mat


@pytest.mark.parametrize("group", [False, True])
def test_mix_transparent_constant(scene, group):
    _on_quad("Half", _mix_transparent("Half", fac=0.8, group=group))
    _on_quad("Swapped", _mix_transparent("Swapped", fac=0.8, transparent_first=False, group=group))
    s = export_scene()
    assert _material_of(s, "Half").alpha == pytest.approx(0.8, abs=1e-6)
    assert _material_of(s, "Swapped").alpha == pytest.approx(0.2, abs=1e-6)
    np.testing.assert_allclose(s.instances.base_color[_row(s, "Half")][:3], (0.1, 0.6, 0.1), rtol=1e-6)


@pytest.mark.parametrize("group", [False, True])
def test_mix_transparent_image(scene, group):
    img, px = _image("cut", seed=4)
    _on_quad("Card", _mix_transparent("Card", image=img, group=group))
    _on_quad("Inverse", _mix_transparent("Inverse", image=img, transparent_first=False, group=group))
    s = export_scene()
    card, inverse = _material_of(s, "Card"), _material_of(s, "Inverse")
    assert card.alpha_image >= 0 and inverse.alpha_image >= 0
    a = s.images[card.alpha_image].pixels[..., 3] / 255.0
    np.testing.assert_allclose(a, px[..., 3], atol=1 / 255 + 1e-6)
    inv = s.images[inverse.alpha_image].pixels[..., 3] / 255.0
    np.testing.assert_allclose(inv, 1.0 - px[..., 3], atol=1 / 255 + 1e-6)


@pytest.mark.parametrize("op, threshold, inverted", [("GREATER_THAN", 0.4, False), ("LESS_THAN", 0.4, True),
                                                     ("ROUND", 0.5, False)])
def test_mix_transparent_math_clip(scene, op, threshold, inverted):
    img, px = _image("cut", seed=5)
    _on_quad("Card", _mix_transparent("Card", image=img, clip=(op, threshold)))
    s = export_scene()
    m = _material_of(s, "Card")
    assert m.alpha_mode == "CLIP"
    a = s.images[m.alpha_image].pixels[..., 3] / 255.0
    if inverted:  # a < t reads as (1 - a) > 1 - t
        assert m.alpha_threshold == pytest.approx(1.0 - threshold)
        np.testing.assert_allclose(a, 1.0 - px[..., 3], atol=1 / 255 + 1e-6)
    else:
        assert m.alpha_threshold == pytest.approx(threshold)
        np.testing.assert_allclose(a, px[..., 3], atol=1 / 255 + 1e-6)


def test_report_names_subsurface_volume_and_curves(scene):
    mat = bpy.data.materials.new("Skin")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Subsurface Weight"].default_value = 0.5
    vol = mat.node_tree.nodes.new("ShaderNodeVolumePrincipled")
    mat.node_tree.links.new(vol.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Volume"])
    _on_quad("Face", mat)
    fur = bpy.data.hair_curves.new("Fur")
    fur.add_curves([3, 3])
    add_object("Fur", fur)
    s = export_scene()
    assert "material 'Skin': Subsurface read as Diffuse" in s.report, s.report
    assert "material 'Skin': volume ignored" in s.report, s.report
    assert any(w.startswith("Curves object 'Fur': 2 strands drawn as 5-sided tubes") for w in s.report), s.report
    assert len(s.report) == len(set(s.report))


def test_plain_scene_has_an_empty_report(scene):
    _on_quad("Plain", bpy.data.materials.new("Plain"))
    assert export_scene().report == []


def test_light_portal_is_not_a_light(scene):
    portal = bpy.data.lights.new("Portal", "AREA")
    if hasattr(portal, "is_portal"):
        portal.is_portal = True
    else:
        portal.cycles.is_portal = True
    add_object("Portal", portal)
    add_object("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    s = export_scene()
    assert [light.name for light in s.lights] == ["Lamp"]
    assert any("'Portal'" in w and "portal" in w for w in s.report), s.report
    assert [light.name for light in export_lights(bpy.context.evaluated_depsgraph_get())] == ["Lamp"]
