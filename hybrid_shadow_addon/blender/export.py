"""Export an evaluated depsgraph to the bpy-free scene model.

:func:`export_depsgraph` reads what Blender renders: modifiers applied, every instance (linked
duplicates, collection instances, particles, geometry-nodes instances) placed as an instance of
one shared :class:`~hybrid_shadow_addon.core.scene.Model` per evaluated mesh datablock.

Two paths feed the instances, and each instance goes through exactly one of them:

- ``depsgraph.object_instances`` for everything, one Python step per instance;
- geometry-nodes instances of a mesh object whose instance tree holds only meshes and objects
  are read from its evaluated :class:`bpy.types.GeometrySet` with ``foreach_get`` (100k
  instances in milliseconds); that object's duplis are then skipped in the iterator.

Blender 4.5 yields the evaluated mesh of curve, text, surface and metaball objects as a separate
``MESH`` instance of the object, so only ``MESH`` instances carry geometry; ``to_mesh()`` is used
only for a non-mesh object whose evaluated geometry has no mesh component.

A ``RENDER`` depsgraph (a render engine's) already holds exactly the renderable objects. A
``VIEWPORT`` depsgraph (``Context.evaluated_depsgraph_get()``) also holds objects hidden from
render; they are dropped here (``hide_render`` of the object or of all its collections, checked
on top-level objects and instancers), but objects hidden in the viewport are simply absent from
it, and modifiers use their viewport settings.

Material slots: a mesh whose loop triangles use one slot (``material_index``, clamped to the
slots as Blender renders) is one model, its instances that slot's material (no slots: none).
A mesh whose triangles use several slots becomes one model per used slot (that slot's
triangles, their own vertices, normals and, for a textured material, UVs), and each instance
showing it one instance per used slot with that slot's material (the evaluated object's
``material_slots[k].material``, so object- and data-linked slots both work; a realised
geometry-nodes mesh: ``mesh.materials[k]``), the same matrix and shadow flag. Names (stable
from frame to frame, as the scene sync and the viewport match instances by name):

- instances: the lowest used slot keeps the instance's name (``"Tree"``,
  ``"Forest/Tree[12]"``), every other used slot ``k`` is ``"<name> [slot k]"``
  (``"Tree [slot 1]"``, ``"Forest/Tree[12] [slot 1]"``); :func:`slot_owner` strips it;
- models: a mesh split by slot is ``"<mesh> [slot k]"`` for every used slot ``k``, 0
  included; an unsplit mesh keeps the mesh's name, unless the one slot its triangles use is
  not slot 0 (``"<mesh> [slot k]"`` again). A model named without the suffix thus always shows
  slot 0, which the viewport's single-model rebuild relies on.

A single-slot mesh therefore exports exactly as before the split.

Materials (:func:`read_material`): per instance its slot's material. A Principled BSDF
whose Base Color and/or Alpha come from an Image Texture node (directly, or through Mapping nodes
fed by a UV Map node or a Texture Coordinate's UV output; a Math "Greater Than" on the alpha, as
Blender 4.2 writes for old Alpha Clip materials, is the CLIP mode), or whose unlinked Alpha is
below 1, becomes a :class:`~hybrid_shadow_addon.core.scene.Material`; any other node set-up
falls back to the sockets' default values with one :class:`ExportWarning` per material. Plain
materials stay ``material_ids = -1``, so an opaque scene has no materials, images or UVs. Only
meshes shown with a textured material get ``Model.uvs``.
"""
from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.errors import SceneError
from ..core.scene import Camera, Image, Instances, Light, Material, Model, Scene, affine_inverse

#: Object types whose evaluated geometry can be a mesh.
GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
#: Custom object property marking an analytic sphere primitive.
SPHERE_PROPERTY = "hybrid_sphere"

_GREY = (0.8, 0.8, 0.8, 1.0)
_WHITE = (1.0, 1.0, 1.0, 1.0)
_IDENTITY_UV = np.float64([[1, 0, 0], [0, 1, 0], [0, 0, 1]])


class ExportWarning(UserWarning):
    """Part of the scene the export cannot read as Blender renders it (a material's node set-up,
    an image without pixels, a textured mesh without UVs): it falls back and says so, once per
    material, image or mesh."""


def _warn(message: str) -> None:
    warnings.warn(message, ExportWarning, stacklevel=3)


def export_depsgraph(depsgraph, *, resolution=None, render_visibility: bool | None = None) -> Scene:
    """The scene of an evaluated depsgraph at its current frame.

    ``render_visibility``: drop what is hidden from render (default: for a viewport depsgraph,
    so that it exports what F12 renders); False keeps what the viewport shows, as Cycles' and
    EEVEE's rendered viewports do.

    ``resolution``: ``(width, height)`` overriding the render settings (default: resolution x/y
    times the percentage). Raises :class:`SceneError` naming the object for a NaN or infinite
    transform (``Scene.check_transforms``); the remaining checks are ``Scene.validate``'s.
    """
    return _Exporter(depsgraph, render_visibility).run(resolution)


# --------------------------------------------------------------------------------------------
# Helpers reading bpy data
# --------------------------------------------------------------------------------------------
def _matrix(m) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 numpy array (rows as in Blender)."""
    return np.array([tuple(row) for row in m], np.float64)


def _matrices(ms: list) -> np.ndarray:
    """A list of mathutils 4x4 matrices as an (N, 4, 4) float64 array."""
    flat = itertools.chain.from_iterable(itertools.chain.from_iterable(ms))
    return np.fromiter(flat, np.float64, count=16 * len(ms)).reshape(-1, 4, 4)


def smooth_normals(mesh) -> np.ndarray | None:
    """(T, 3, 3) float32 shading normals of each loop triangle's corners (Blender's corner
    normals: smooth faces, sharp edges and custom normals included), or None when every face is
    flat (the face normals then suffice)."""
    n_poly = len(mesh.polygons)
    if not n_poly or not len(mesh.loop_triangles):
        return None
    smooth = np.empty(n_poly, bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    if not smooth.any():
        return None
    corner = np.empty(len(mesh.loops) * 3, np.float32)
    mesh.corner_normals.foreach_get("vector", corner)
    loops = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return corner.reshape(-1, 3)[loops].reshape(-1, 3, 3)


_SLOT_SUFFIX = " [slot "


def slot_name(name: str, slot: int) -> str:
    """The name of the instance or model holding slot ``slot`` of ``name``'s mesh."""
    return f"{name}{_SLOT_SUFFIX}{slot}]"


def slot_owner(name: str) -> str:
    """The instance name without a ``" [slot k]"`` suffix (:func:`slot_name`'s inverse)."""
    i = name.rfind(_SLOT_SUFFIX)
    if i >= 0 and name.endswith("]") and name[i + len(_SLOT_SUFFIX):-1].isdigit():
        return name[:i]
    return name


def slot_triangles(mesh, n_slots: int) -> list | None:
    """``[(slot, loop triangle indices)]`` of a mesh with ``n_slots`` material slots: its
    triangles grouped by ``material_index`` (clamped to ``[0, n_slots - 1]``, as Blender renders
    an out-of-range index), one entry per used slot, ascending. None when there are fewer than
    two slots (every triangle shows slot 0) or no triangles."""
    n = len(mesh.loop_triangles)
    if n_slots < 2 or not n:
        return None
    index = np.empty(n, np.int32)
    mesh.loop_triangles.foreach_get("material_index", index)
    np.clip(index, 0, n_slots - 1, out=index)
    counts = np.bincount(index, minlength=n_slots)
    used = np.flatnonzero(counts)
    if len(used) == 1:
        return [(int(used[0]), None)]
    order = np.argsort(index, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    return [(int(k), order[bounds[k]:bounds[k + 1]]) for k in used]


def used_slots(mesh, n_slots: int) -> list:
    """The material slots a mesh's triangles use (``[0]`` with fewer than two slots)."""
    groups = slot_triangles(mesh, n_slots)
    return [0] if groups is None else [k for k, _ in groups]


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float32 and loop triangles (T, 3) uint32 of a mesh, via ``foreach_get``."""
    verts = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", verts)
    tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", tris)
    return verts.reshape(-1, 3), tris.view(np.uint32).reshape(-1, 3)


def principled_node(tree):
    """The Principled BSDF feeding the material output, else the tree's first one, else None."""
    out = tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BSDF_PRINCIPLED":
            return node
    return next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None)


def material_surface(material, object_color=_WHITE) -> tuple:
    """``(rgba, specular, roughness)`` of a material (its Principled BSDF's unlinked input values,
    else its viewport settings). Without a material: the object's colour when it is not the
    default white, else Blender's 0.8 grey; specular and roughness 0.5."""
    if material is None:
        rgba = tuple(object_color) if tuple(object_color) != _WHITE else _GREY
        return rgba, 0.5, 0.5
    node = principled_node(material.node_tree) if material.use_nodes and material.node_tree else None
    if node is not None:
        rgb = tuple(node.inputs["Base Color"].default_value)[:3]
        rgba = rgb + (float(node.inputs["Alpha"].default_value),)
        spec = float(node.inputs["Specular IOR Level"].default_value)
        rough = float(node.inputs["Roughness"].default_value)
    else:
        rgba = tuple(material.diffuse_color)
        spec, rough = float(material.specular_intensity), float(material.roughness)
    return rgba, min(max(spec, 0.0), 1.0), min(max(rough, 0.0), 1.0)


# --------------------------------------------------------------------------------------------
# Textured and alpha materials
# --------------------------------------------------------------------------------------------
@dataclass
class TextureLink:
    """An Image Texture node feeding a Principled input: ``output`` ("Color" or "Alpha") of
    ``node``, looked up at UV map ``uv_map`` ("": the mesh's active render UV map) through the
    (3, 3) homogeneous 2D affine ``uv_affine`` (the Mapping nodes on the way)."""

    node: object
    output: str
    uv_map: str = ""
    uv_affine: np.ndarray = field(default_factory=lambda: _IDENTITY_UV.copy())

    def same_mapping(self, other: "TextureLink") -> bool:
        return self.uv_map == other.uv_map and np.allclose(self.uv_affine, other.uv_affine, atol=1e-7)


@dataclass
class MaterialReading:
    """What :func:`read_material` finds in a material (no images read yet).

    ``rgba``, ``specular``, ``roughness``: :func:`material_surface` (the unlinked values);
    ``color``/``alpha_texture``: the supported image links of Base Color / Alpha; ``alpha``: the
    constant alpha (1 when Alpha is an image); ``problems``: the links read as their defaults."""

    name: str
    rgba: tuple
    specular: float
    roughness: float
    color: TextureLink | None = None
    alpha_texture: TextureLink | None = None
    alpha: float = 1.0
    alpha_mode: str = "BLEND"
    alpha_threshold: float = 0.5
    transparent_shadow: bool = True
    problems: list = field(default_factory=list)


def _link_source(socket):
    """``(node, output socket)`` feeding input ``socket`` (through reroutes), None when unlinked
    (a muted link counts as none, as in Blender)."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if link.is_muted:
            return None
        node = link.from_node
        if node.type == "REROUTE":
            socket, seen = node.inputs[0], seen + 1
            continue
        return node, link.from_socket
    return None


def _describe(node) -> str:
    return f"'{node.name}' ({node.bl_idname})"


def _euler_matrix(rx: float, ry: float, rz: float) -> np.ndarray:
    """Blender's XYZ Euler rotation matrix (Rz @ Ry @ Rx)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return z @ y @ x


def mapping_affine(node) -> np.ndarray | None:
    """(3, 3) homogeneous 2D affine of a Mapping node applied to a UV vector (z = 0), as Blender
    computes it (POINT: ``R (S v) + L``; VECTOR: ``R (S v)``; TEXTURE: ``R^T (v - L) / S``, 0
    where S is 0); None for a NORMAL mapping or linked Location/Rotation/Scale inputs. Exact for
    a flat image lookup: only x and y of the result are read, and z of a UV is 0."""
    kind = node.vector_type
    if kind not in ("POINT", "VECTOR", "TEXTURE"):
        return None
    if any(node.inputs[n].is_linked for n in ("Location", "Rotation", "Scale")):
        return None
    loc = np.array(node.inputs["Location"].default_value[:3], np.float64)
    rot = _euler_matrix(*node.inputs["Rotation"].default_value[:3])
    scale = np.array(node.inputs["Scale"].default_value[:3], np.float64)
    if kind == "TEXTURE":
        inv = np.divide(1.0, scale, out=np.zeros(3), where=scale != 0)
        m3 = inv[:, None] * rot.T
        off = -m3 @ loc
    else:
        m3 = rot * scale[None, :]
        off = loc if kind == "POINT" else np.zeros(3)
    out = np.eye(3)
    out[:2, :2] = m3[:2, :2]
    out[:2, 2] = off[:2]
    return out


def _uv_source(socket, label: str, problems: list):
    """``(uv_map, affine)`` of an Image Texture's Vector input, None (with a problem) when it is
    not a UV lookup through Mapping nodes."""
    affine = _IDENTITY_UV.copy()
    src = _link_source(socket)
    if src is None:
        return "", affine
    for _ in range(16):
        node, out = src
        if node.mute:
            problems.append(f"{label} reads its UVs through the muted node {_describe(node)}")
            return None
        if node.type in ("UVMAP", "TEX_COORD") and getattr(node, "from_instancer", False):
            problems.append(f"{label} reads the instancer's UVs ({_describe(node)}, From Instancer)")
            return None
        if node.type == "UVMAP":
            return node.uv_map, affine
        if node.type == "TEX_COORD" and out.identifier == "UV":
            return "", affine
        if node.type != "MAPPING":
            problems.append(f"{label} reads its UVs from the unsupported node {_describe(node)}")
            return None
        m = mapping_affine(node)
        if m is None:
            problems.append(f"{label} reads its UVs through the Mapping node {_describe(node)} "
                            f"({node.vector_type.lower()}, or with linked inputs), which the export does not read")
            return None
        affine = affine @ m  # the node nearest the image is applied last
        src = _link_source(node.inputs["Vector"])
        if src is None:
            problems.append(f"{label} reads a constant vector through {_describe(node)}, not UVs")
            return None
    problems.append(f"{label} reads its UVs through too many Mapping nodes")
    return None


def _image_link(socket, label: str, problems: list, outputs=("Color",)):
    """The :class:`TextureLink` feeding ``socket`` when it is an Image Texture read at UVs; None
    when unlinked, or (with a problem) when it is anything else."""
    src = _link_source(socket)
    if src is None:
        return None
    node, out = src
    if node.type != "TEX_IMAGE" or node.mute:
        what = "the muted node" if node.mute else "the unsupported node"
        problems.append(f"{label} is linked from {what} {_describe(node)}")
        return None
    image = node.image
    if image is None:
        problems.append(f"{label} is linked from the Image Texture {_describe(node)} without an image")
        return None
    if node.projection != "FLAT":
        problems.append(f"{label} is linked from the Image Texture {_describe(node)} with "
                        f"{node.projection.lower()} projection (flat only)")
        return None
    if image.source not in ("FILE", "GENERATED"):
        problems.append(f"{label} is linked from the Image Texture {_describe(node)} whose image "
                        f"'{image.name}' is a {image.source.lower()} (single images only)")
        return None
    if out.identifier not in outputs:
        problems.append(f"{label} is linked from the {out.name} output of {_describe(node)}")
        return None
    uv = _uv_source(node.inputs["Vector"], label, problems)
    if uv is None:
        return None
    return TextureLink(node=node, output=out.identifier, uv_map=uv[0], uv_affine=uv[1])


def blend_settings(material) -> tuple:
    """``(alpha_mode, alpha_threshold, transparent_shadow)`` from a material's settings: "CLIP"
    for the Alpha Clip blend method (before Blender 4.2, which turns it into a Math node on the
    alpha, see :func:`read_material`), else "BLEND" (Cycles' semantics); transparent shadows
    from ``use_transparent_shadow`` (4.2+) or ``shadow_method`` (older: OPAQUE is off). Read with
    ``getattr``: Blender 5 drops some of these."""
    mode = "CLIP" if getattr(material, "blend_method", None) == "CLIP" else "BLEND"
    threshold = float(getattr(material, "alpha_threshold", 0.5))
    transparent = getattr(material, "use_transparent_shadow", None)
    if transparent is None:
        transparent = getattr(material, "shadow_method", "HASHED") != "OPAQUE"
    return mode, threshold, bool(transparent)


def read_material(material) -> MaterialReading | None:
    """Base Color, Alpha and the blend settings of a material's Principled BSDF (None for no
    material). Unsupported links are listed in ``problems`` and read as their default value."""
    if material is None:
        return None
    rgba, spec, rough = material_surface(material)
    mode, threshold, transparent = blend_settings(material)
    r = MaterialReading(name=material.name, rgba=rgba, specular=spec, roughness=rough, alpha=float(rgba[3]),
                        alpha_mode=mode, alpha_threshold=threshold, transparent_shadow=transparent)
    node = principled_node(material.node_tree) if material.use_nodes and material.node_tree else None
    if node is None:
        return r
    r.color = _image_link(node.inputs["Base Color"], "Base Color", r.problems)
    alpha_in = node.inputs["Alpha"]
    src = _link_source(alpha_in)
    if src is not None and src[0].type == "MATH" and src[0].operation == "GREATER_THAN" and not src[0].mute \
            and not src[0].inputs[1].is_linked:
        math = src[0]  # Blender 4.2's Alpha Clip: alpha > threshold
        r.alpha_mode, r.alpha_threshold = "CLIP", float(math.inputs[1].default_value)
        alpha_in = math.inputs[0]
        if not alpha_in.is_linked:
            r.alpha = float(float(alpha_in.default_value) > r.alpha_threshold)
            return r
    r.alpha_texture = _image_link(alpha_in, "Alpha", r.problems, outputs=("Alpha", "Color"))
    if r.alpha_texture is not None:
        r.alpha = 1.0
    return r


def _is_srgb(image) -> bool:
    """Whether the stored (byte) colour values are sRGB-encoded. Float images are kept in scene
    linear by Blender whatever their file's colour space."""
    cs = image.colorspace_settings
    if image.is_float or getattr(cs, "is_data", False):
        return False
    name = cs.name.lower()
    return name.startswith("srgb") and "linear" not in name


def image_pixels(image) -> tuple | None:
    """``(pixels (H, W, C) uint8, srgb)`` of an image as stored (row 0 at the bottom), via
    ``pixels.foreach_get``; None when it has no pixels (a missing file)."""
    try:
        w, h = (int(x) for x in image.size)
        ch = int(image.channels)
        if w < 1 or h < 1 or ch not in (1, 3, 4):
            return None
        buf = np.empty(w * h * ch, np.float32)
        image.pixels.foreach_get(buf)
    except (RuntimeError, ReferenceError, ValueError, TypeError):
        return None
    buf = np.fmin(np.fmax(buf, 0.0), 1.0)  # NaN -> 0
    px = (buf * 255.0 + 0.5).astype(np.uint8).reshape(h, w, ch)
    if ch == 4 and getattr(image, "alpha_mode", "STRAIGHT") == "NONE":
        px[..., 3] = 255
    return px, _is_srgb(image)


def mesh_uv_layer(mesh, name: str = ""):
    """The UV layer named ``name``, or ("") the active render one (else the active, else the
    first); None when the mesh has no such layer."""
    layers = mesh.uv_layers
    if not len(layers):
        return None
    if name:
        return layers.get(name)
    return next((l for l in layers if l.active_render), None) or layers.active or layers[0]


def mesh_uvs(mesh, layer) -> np.ndarray:
    """(T, 3, 2) float32 UVs of each loop triangle's corners from ``layer``, via ``foreach_get``."""
    buf = np.empty(len(mesh.loops) * 2, np.float32)
    if hasattr(layer, "uv"):
        layer.uv.foreach_get("vector", buf)
    else:
        layer.data.foreach_get("uv", buf)
    loops = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return buf.reshape(-1, 2)[loops].reshape(-1, 3, 2)


def world_background(world):
    """The Background node the world's output uses (else the tree's first), or None."""
    if world is None or not world.use_nodes or not world.node_tree:
        return None
    out = world.node_tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BACKGROUND":
            return node
    return next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)


def world_color(world) -> np.ndarray:
    """Linear RGB of the world: its Background node's colour × strength, else ``world.color``."""
    if world is None:
        return np.zeros(3, np.float32)
    bg = world_background(world)
    if bg is not None:
        rgb = np.array(bg.inputs["Color"].default_value[:3], np.float32)
        return rgb * np.float32(bg.inputs["Strength"].default_value)
    return np.array(world.color[:3], np.float32)


def is_sphere_primitive(ob) -> bool:
    """The object's "Sphere Primitive" setting: the add-on's property when registered, else the
    ``hybrid_sphere`` custom property (scene scripts set that one)."""
    value = getattr(ob, SPHERE_PROPERTY, None)
    if value is None:
        value = ob.get(SPHERE_PROPERTY, False)
    return bool(value)


def render_resolution(scene) -> tuple[int, int]:
    """The render size in pixels, as Blender computes it (integer percentage scaling)."""
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100,
            r.resolution_y * r.resolution_percentage // 100)


def export_lights(depsgraph, render_visibility: bool | None = None) -> list:
    """The lights of a depsgraph that ``export_depsgraph`` would list, without reading any
    geometry."""
    ex = _Exporter(depsgraph, render_visibility)
    lights = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type != "LIGHT":
            continue
        if inst.is_instance:
            parent = inst.parent
            if not ex._renderable(parent.original):
                continue
            name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
        else:
            if not ex._renderable(ob.original):
                continue
            name = ob.name
        lights.append(export_light(ob, _matrix(inst.matrix_world), name))
    return lights


def light_color(d) -> tuple:
    """Linear RGB of a light datablock: its colour, times its blackbody colour when Blender has
    ``use_temperature`` (4.5+) and it is on (as Cycles and EEVEE multiply them)."""
    rgb = np.array(d.color[:3], np.float64)
    if getattr(d, "use_temperature", False):
        rgb = rgb * np.array(d.temperature_color[:3], np.float64)
    return tuple(float(c) for c in rgb)


def light_power(d) -> float:
    """Power (W) or sun strength (W/m²) as Cycles emits it: ``energy * 2^exposure`` (Blender
    4.0+), and for an area light whose ``normalize`` is off (4.2+), times its area (the power is
    then per square metre)."""
    power = float(d.energy) * 2.0 ** float(getattr(d, "exposure", 0.0))
    if d.type == "AREA" and not getattr(d, "normalize", True):
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        area = float(d.size) * float(size_y) * (np.pi / 4 if d.shape in ("DISK", "ELLIPSE") else 1.0)
        power *= area
    return power


def export_light(ob, matrix: np.ndarray, name: str) -> Light:
    """A light object (evaluated) at world ``matrix``. An area light's ``size_y`` is its actual
    extent: ``size`` for square and disk shapes."""
    d = ob.data
    kw = dict(name=name, type=d.type, color=light_color(d), power=light_power(d), matrix=matrix,
              use_shadow=bool(d.use_shadow))
    if d.type == "SUN":
        kw["angle"] = float(d.angle)
    elif d.type in ("POINT", "SPOT"):
        kw["radius"] = float(d.shadow_soft_size)
    if d.type == "SPOT":
        kw.update(spot_size=float(d.spot_size), spot_blend=float(d.spot_blend))
    elif d.type == "AREA":
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        kw.update(size=float(d.size), size_y=float(size_y), area_shape=d.shape,
                  spread=float(getattr(d, "spread", np.pi)))
    return Light(**kw)


def export_camera(depsgraph) -> Camera | None:
    """The scene camera (evaluated at the depsgraph's frame), or None when the scene has none."""
    ob = depsgraph.scene.camera
    if ob is None:
        return None
    ob = ob.evaluated_get(depsgraph)
    if ob.type != "CAMERA":
        raise SceneError(f"the scene camera '{ob.name}' is a {ob.type.lower()} object, not a camera")
    d = ob.data
    return Camera(name=ob.name, matrix=_matrix(ob.matrix_world), type=d.type, lens=d.lens,
                  sensor_width=d.sensor_width, sensor_height=d.sensor_height,
                  sensor_fit=d.sensor_fit, ortho_scale=d.ortho_scale, shift_x=d.shift_x,
                  shift_y=d.shift_y, clip_start=d.clip_start, clip_end=d.clip_end)


# --------------------------------------------------------------------------------------------
# The exporter
# --------------------------------------------------------------------------------------------
class _Exporter:
    def __init__(self, depsgraph, render_visibility: bool | None = None):
        self.dg = depsgraph
        self.check_render_visibility = (depsgraph.mode != "RENDER" if render_visibility is None
                                        else bool(render_visibility) and depsgraph.mode != "RENDER")
        self.models: list[Model] = []
        # geometry key -> [(material slot, model id)]: one model per used slot ([] without triangles)
        self.models_of: dict = {}
        self.model_tris: dict = {}  # model id of a slot model -> the mesh's loop triangles it holds
        # (casts_shadow, sphere, rgba, specular, roughness, material id, fallback rgba)
        self.attrs: list[tuple] = []
        self.attr_of: dict = {}
        self.dropped_of: dict = {}  # attrs row -> the same row without its material
        self.surface_of: dict = {}  # material pointer -> (rgba, specular, roughness, material id, fallback rgba)
        self.materials: list[Material] = []
        self.material_uv: list[str] = []  # UV map name of each material ("": active render)
        self.images: list[Image] = []
        self.image_of: dict = {}  # (image pointer, extension, interpolation) -> image id or -1
        self.pixels_of: dict = {}  # image pointer -> image_pixels()
        self.uv_of: dict = {}  # (model id, UV map name) -> bool (the model has those UVs)
        self.renderable_of: dict = {}  # original object pointer -> bool
        self.hidden_collections = None
        # one row per instance found by the iterator
        self.names: list[str] = []
        self.model_ids: list[int] = []
        self.matrices: list = []
        self.attr_ids: list[int] = []
        self.parts: list[Instances] = []  # vectorised geometry-nodes instances
        self.lights: list[Light] = []
        self.keep: list = []  # GeometrySets own the meshes they reference: alive while exporting

    # -- entry --------------------------------------------------------------------------------
    def run(self, resolution) -> Scene:
        scene = self.dg.scene_eval
        self._walk()
        instances = Instances.concatenate([self._iterated_instances()] + self.parts)
        camera = export_camera(self.dg)
        result = Scene(name=scene.name, models=self.models, instances=instances,
                       lights=self.lights, camera=camera, world_color=world_color(scene.world),
                       resolution=render_resolution(scene) if resolution is None else resolution,
                       frame=scene.frame_current, materials=self.materials, images=self.images)
        return result.check_transforms()

    def _walk(self) -> None:
        vectorised = set()  # evaluated instancers whose instances came from their GeometrySet
        iterated = set()  # evaluated instancers with duplis taken from the iterator
        for inst in self.dg.object_instances:
            if inst.is_instance:
                parent = inst.parent
                pptr = parent.as_pointer()
                if pptr in vectorised:
                    continue
                iterated.add(pptr)
                ob = inst.object
                if not self._renderable(parent.original):
                    continue
                name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
            else:
                ob = inst.object
                if not self._renderable(ob.original):
                    continue
                name = ob.name
                if (ob.type == "MESH" and ob.as_pointer() not in iterated
                        and any(m.type == "NODES" for m in ob.modifiers)
                        and self._vectorise(ob)):
                    vectorised.add(ob.as_pointer())
            kind = ob.type
            if kind == "MESH":
                self._add_mesh_instance(ob, ob.data, ob.data.as_pointer(), inst.matrix_world, name)
            elif kind == "LIGHT":
                self.lights.append(export_light(ob, _matrix(inst.matrix_world), name))
            elif kind in GEOMETRY_TYPES and bpy.types.GeometrySet.from_evaluated_object(ob).mesh is None:
                self._add_converted_instance(ob, inst.matrix_world, name)

    # -- visibility ---------------------------------------------------------------------------
    def _renderable(self, ob) -> bool:
        """For a viewport depsgraph: the original object is not hidden from render, itself or
        through all of its collections."""
        if not self.check_render_visibility:
            return True
        key = ob.as_pointer()
        ok = self.renderable_of.get(key)
        if ok is None:
            if self.hidden_collections is None:
                self.hidden_collections = set()
                for coll in self.dg.scene.collection.children_recursive:
                    if coll.hide_render:
                        self.hidden_collections.add(coll.as_pointer())
                        self.hidden_collections.update(c.as_pointer() for c in coll.children_recursive)
            colls = [c.as_pointer() for c in ob.users_collection]
            ok = not ob.hide_render and not (colls and all(c in self.hidden_collections for c in colls))
            self.renderable_of[key] = ok
        return ok

    # -- models and per-instance attributes ---------------------------------------------------
    def _models(self, key, mesh, name: str, n_slots: int) -> list:
        """``[(slot, model id)]`` of the geometry ``key`` (read from ``mesh`` the first time): one
        model named ``name`` when its triangles use one of its ``n_slots`` slots, else one per
        used slot (:func:`slot_triangles`) with the vertices its triangles use; [] without
        triangles. Model names: see the module docstring."""
        got = self.models_of.get(key)
        if got is not None:
            return got
        verts, tris = mesh_arrays(mesh)
        got = []
        if len(tris):
            normals = smooth_normals(mesh)
            groups = slot_triangles(mesh, n_slots) or [(0, None)]
            for k, idx in groups:
                label = name if k == 0 and idx is None else slot_name(name, k)
                if idx is None:
                    model = Model(name=label, vertices=verts, triangles=tris, normals=normals)
                else:
                    sub = tris[idx]
                    keep = np.zeros(len(verts), bool)
                    keep[sub] = True
                    remap = np.cumsum(keep, dtype=np.int64) - 1
                    model = Model(name=label, vertices=verts[keep], triangles=remap[sub].astype(np.uint32),
                                  normals=None if normals is None else normals[idx])
                    self.model_tris[len(self.models)] = idx
                got.append((k, len(self.models)))
                self.models.append(model)
        self.models_of[key] = got
        return got

    def _attributes(self, ob, material) -> int:
        """Row in ``self.attrs`` for an (evaluated) object showing ``material``."""
        key = (ob.original.as_pointer(), None if material is None else material.as_pointer())
        aid = self.attr_of.get(key)
        if aid is None:
            skey = key[1]
            surface = self.surface_of.get(skey) if skey is not None else None
            if surface is None:
                if material is None:
                    rgba, spec, rough = material_surface(None, ob.color)
                    surface = (rgba, spec, rough, -1, rgba)
                else:
                    surface = self._material(material)
                    self.surface_of[skey] = surface
            aid = len(self.attrs)
            self.attrs.append((bool(ob.visible_shadow), is_sphere_primitive(ob)) + surface)
            self.attr_of[key] = aid
        return aid

    def _material(self, material) -> tuple:
        """``(rgba, specular, roughness, material id, fallback rgba)`` of a Blender material: a
        new entry of ``self.materials`` when it is textured or its alpha is below 1 (id -1
        otherwise); the fallback colour is the unlinked Base Color and Alpha (the material
        without its textures). Warns once for what it reads as defaults."""
        r = read_material(material)
        problems = r.problems
        fallback = tuple(r.rgba)
        color_img = self._image_index(r.color, problems, "Base Color") if r.color is not None else -1
        alpha_img = self._image_index(r.alpha_texture, problems, "Alpha") if r.alpha_texture is not None else -1
        alpha = r.alpha if alpha_img >= 0 or r.alpha_texture is None else float(fallback[3])
        if color_img >= 0 and alpha_img >= 0 and not r.color.same_mapping(r.alpha_texture):
            problems.append("Base Color and Alpha use different UV maps or mappings; the colour image "
                            "is dropped")
            color_img = -1
        link = r.alpha_texture if alpha_img >= 0 else r.color if color_img >= 0 else None
        rgb = (1.0, 1.0, 1.0) if color_img >= 0 else tuple(fallback[:3])
        if problems:
            _warn(f"material '{material.name}': {'; '.join(problems)}: the export uses the default "
                  f"value{'s' if len(problems) > 1 else ''} instead")
        mid = -1
        if color_img >= 0 or alpha_img >= 0 or alpha < 1.0:
            mid = len(self.materials)
            self.materials.append(Material(
                name=material.name, color_image=color_img, alpha=min(max(alpha, 0.0), 1.0), alpha_image=alpha_img,
                alpha_channel="LUMA" if alpha_img >= 0 and r.alpha_texture.output == "Color" else "A",
                uv_transform=(_IDENTITY_UV if link is None else link.uv_affine)[:2],
                alpha_mode=r.alpha_mode, alpha_threshold=r.alpha_threshold,
                transparent_shadow=r.transparent_shadow))
            self.material_uv.append("" if link is None else link.uv_map)
        return rgb + (alpha,), r.specular, r.roughness, mid, fallback

    def _image_index(self, link: TextureLink, problems: list, label: str) -> int:
        """Index in ``self.images`` of the image an Image Texture node reads (one per image,
        extension and interpolation; the pixels read once per image); -1 (with a problem) when
        it has no pixels."""
        node = link.node
        image = node.image
        interp = node.interpolation if node.interpolation in ("Linear", "Closest") else "Linear"
        key = (image.as_pointer(), node.extension, interp)
        idx = self.image_of.get(key)
        if idx is None:
            ptr = image.as_pointer()
            if ptr not in self.pixels_of:
                self.pixels_of[ptr] = image_pixels(image)
            px = self.pixels_of[ptr]
            idx = -1
            if px is not None:
                idx = len(self.images)
                self.images.append(Image(name=image.name, pixels=px[0], srgb=px[1], extension=node.extension,
                                         interpolation=interp))
            self.image_of[key] = idx
        if idx < 0:
            problems.append(f"{label} reads the image '{image.name}', whose pixels cannot be read "
                            f"(missing file?)")
        return idx

    def _checked(self, aid: int, mid: int, mesh, name: str) -> int:
        """``aid``, or the same attributes without the material when it is textured and the
        model's mesh has no UVs for it (warned once per mesh and UV map). Gives the model its
        UVs when a textured material shows it."""
        k = self.attrs[aid][5]
        if k < 0 or not self.materials[k].textured:
            return aid
        uv_map = self.material_uv[k]
        key = (mid, uv_map)
        ok = self.uv_of.get(key)
        if ok is None:
            model = self.models[mid]
            layer = mesh_uv_layer(mesh, uv_map)
            if layer is None:
                ok = False
                _warn(f"object '{name}': its material '{self.materials[k].name}' is textured but its mesh "
                      f"'{model.name}' has no UV map" + (f" named '{uv_map}'" if uv_map else "")
                      + ": exported without the material")
            elif model.uvs is None:
                uvs = mesh_uvs(mesh, layer)
                idx = self.model_tris.get(mid)
                model.uvs = uvs if idx is None else uvs[idx]
                self.uv_of[(mid, layer.name)] = ok = True
            else:
                ok = True
                if (mid, layer.name) not in self.uv_of:
                    _warn(f"object '{name}': its material '{self.materials[k].name}' reads UV map "
                          f"'{layer.name}' of mesh '{model.name}', which is already exported with "
                          f"another UV map: using that one")
            self.uv_of[key] = ok
        if ok:
            return aid
        dropped = self.dropped_of.get(aid)
        if dropped is None:
            shadow, sphere, _, spec, rough, _, fallback = self.attrs[aid]
            dropped = self.dropped_of[aid] = len(self.attrs)
            self.attrs.append((shadow, sphere, fallback, spec, rough, -1, fallback))
        return dropped

    @staticmethod
    def _slot_material(slots, k: int):
        """The material of slot ``k`` (a ``material_slots`` or ``materials`` collection), None
        without slots."""
        if not len(slots):
            return None
        m = slots[k]
        return m.material if isinstance(m, bpy.types.MaterialSlot) else m

    def _needs_uvs(self, aid: int, mid: int) -> bool:
        """Whether the material of attributes ``aid`` is textured and model ``mid``'s UVs for it
        are not read (nor found missing) yet."""
        k = self.attrs[aid][5]
        return k >= 0 and self.materials[k].textured and (mid, self.material_uv[k]) not in self.uv_of

    @staticmethod
    def _model_name(ob, mesh) -> str:
        """The mesh's name, or the object's when the mesh is a modifier or conversion result."""
        return mesh.name if mesh.name == getattr(ob.original.data, "name", None) else ob.original.name

    def _add_mesh_instance(self, ob, mesh, key, matrix, name) -> None:
        slots = ob.material_slots
        models = self._models(key, mesh, self._model_name(ob, mesh), len(slots))
        if models:
            self._add_rows(ob, slots, models, matrix.copy(), name, mesh)

    def _add_rows(self, ob, slots, models, matrix, name, mesh) -> None:
        """One iterated instance per ``(slot, model id)`` of ``models`` (named as the module
        docstring says), each with its slot's material; ``mesh``: where UVs are read (None: they
        are read already)."""
        for j, (k, mid) in enumerate(models):
            self.names.append(name if j == 0 else slot_name(name, k))
            self.model_ids.append(mid)
            self.matrices.append(matrix)
            aid = self._attributes(ob, self._slot_material(slots, k))
            self.attr_ids.append(self._checked(aid, mid, mesh, name))

    def _add_converted_instance(self, ob, matrix, name) -> None:
        """A non-mesh object without a mesh component: its ``to_mesh()`` triangles, if any."""
        key = ("to_mesh", ob.original.as_pointer())
        slots = ob.material_slots
        models = self.models_of.get(key)
        if models is None or any(self._needs_uvs(self._attributes(ob, self._slot_material(slots, k)), mid)
                                 for k, mid in models):
            mesh = ob.to_mesh()
            try:
                models = self._models(key, mesh, ob.original.name, len(slots))
                self._add_rows(ob, slots, models, matrix.copy(), name, mesh)
            finally:
                ob.to_mesh_clear()
        else:  # UVs already read (or found missing)
            self._add_rows(ob, slots, models, matrix.copy(), name, None)

    def _iterated_instances(self) -> Instances:
        if not self.names:
            return Instances()
        attrs = [self.attrs[i] for i in self.attr_ids]
        return Instances(
            names=self.names,
            model_ids=np.array(self.model_ids, np.int32),
            matrices=(m := _matrices(self.matrices)),
            inverse=affine_inverse(m),
            casts_shadow=np.array([a[0] for a in attrs], bool),
            sphere=np.array([a[1] for a in attrs], bool),
            base_color=np.array([a[2] for a in attrs], np.float32),
            specular=np.array([a[3] for a in attrs], np.float32),
            roughness=np.array([a[4] for a in attrs], np.float32),
            material_ids=np.array([a[5] for a in attrs], np.int32),
        )

    # -- geometry-nodes instances, vectorised -------------------------------------------------
    def _vectorise(self, ob) -> bool:
        """Read the geometry-nodes instances of mesh object ``ob`` from its GeometrySet into
        ``self.parts``. False (nothing added) when its instance tree holds anything but meshes
        and plain mesh objects (collections, curves, ...): the iterator then takes them."""
        groups = _flatten(bpy.types.GeometrySet.from_evaluated_object(ob), self.dg, self.keep)
        if groups is None:
            return False
        world = _matrix(ob.matrix_world)
        for source, mesh, label, local, index in groups:
            matrices = np.matmul(world, local)
            inverse = None
            prefix = f"{ob.name}/{label}"
            if source is None:  # realised geometry made by ob's node tree
                owner, slots = ob, mesh.materials
                models = self._models(mesh.as_pointer(), mesh, prefix, len(slots))
            else:  # an object instanced as a whole
                owner, slots = source, source.material_slots
                models = self._models(mesh.as_pointer(), mesh, self._model_name(source, mesh), len(slots))
            n = len(index)
            for j, (k, mid) in enumerate(models):
                aid = self._attributes(owner, self._slot_material(slots, k))
                aid = self._checked(aid, mid, mesh, source.name if source is not None else prefix)
                shadow, sphere, rgba, spec, rough, material_id, _ = self.attrs[aid]
                if inverse is None:
                    inverse = affine_inverse(matrices)
                suffix = "" if j == 0 else f"{_SLOT_SUFFIX}{k}]"
                self.parts.append(Instances(
                    names=[f"{prefix}[{i}]{suffix}" for i in index.tolist()],
                    model_ids=np.full(n, mid, np.int32),
                    matrices=matrices,
                    inverse=inverse,
                    casts_shadow=np.full(n, shadow),
                    sphere=np.full(n, sphere),
                    base_color=np.tile(np.float32(rgba), (n, 1)),
                    specular=np.full(n, spec, np.float32),
                    roughness=np.full(n, rough, np.float32),
                    material_ids=np.full(n, material_id, np.int32),
                ))
        return True


def _flatten(gs, depsgraph, keep: list):
    """The instances of a GeometrySet, flattened: a list of ``(source_object or None, mesh,
    label, local matrices (k, 4, 4), top-level instance indices (k,))``, or None when the tree
    holds something this path does not read (collections, non-mesh objects, instances of
    objects that have instances themselves). The GeometrySets owning the meshes go to ``keep``."""
    keep.append(gs)
    pc = gs.instances_pointcloud()
    if pc is None:
        return []
    attrs = pc.attributes
    if "instance_transform" not in attrs or ".reference_index" not in attrs:
        return None
    n = len(pc.points)
    raw = np.empty(n * 16, np.float32)
    attrs["instance_transform"].data.foreach_get("value", raw)
    local = raw.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)  # stored column-major
    ref = np.empty(n, np.int32)
    attrs[".reference_index"].data.foreach_get("value", ref)
    refs = gs.instance_references()
    order = np.argsort(ref, kind="stable")
    bounds = np.searchsorted(ref[order], np.arange(len(refs) + 1))
    out = []
    for k, r in enumerate(refs):
        index = order[bounds[k]:bounds[k + 1]]
        if not len(index) or r is None:
            continue
        m = local[index]
        if isinstance(r, bpy.types.Object):
            ob = r if r.is_evaluated else r.evaluated_get(depsgraph)
            if ob.type != "MESH" or bpy.types.GeometrySet.from_evaluated_object(ob).instances_pointcloud() is not None:
                return None
            out.append((ob, ob.data, ob.name, m, index))
        elif isinstance(r, bpy.types.GeometrySet):
            if r.curves is not None or r.pointcloud is not None or r.volume is not None or r.grease_pencil is not None:
                return None
            if r.mesh is not None:
                out.append((None, r.mesh, r.name or r.mesh.name, m, index))
            sub = _flatten(r, depsgraph, keep)
            if sub is None:
                return None
            for source, mesh, label, sub_m, _ in sub:
                placed = np.matmul(m[:, None], sub_m[None]).reshape(-1, 4, 4)
                out.append((source, mesh, label, placed, np.repeat(index, len(sub_m))))
        else:
            return None
    return out
