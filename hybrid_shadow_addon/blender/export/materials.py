"""Materials read from their node graphs: a Principled BSDF's unlinked values, and the Image
Texture nodes feeding its Base Color and Alpha.

A Base Color and/or Alpha fed by an Image Texture node (directly, or through Mapping nodes fed by
a UV Map node or a Texture Coordinate's UV output; a Math "Greater Than" on the alpha, as Blender
4.2 writes for old Alpha Clip materials, is the CLIP mode) is read as a texture link; any other
link is listed as a problem and read as the socket's default value. A Normal Map or Bump node
feeding a BSDF's Normal is not read: :func:`mapped_normal` names it for the export report.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .nodes import as_float, as_rgb, constant, describe, resolve
from .surfaces import AlphaRead, constant_default, read_alpha, read_surface

_GREY = (0.8, 0.8, 0.8, 1.0)
_WHITE = (1.0, 1.0, 1.0, 1.0)
#: The identity (3, 3) homogeneous 2D affine of a UV lookup.
IDENTITY_UV = np.float64([[1, 0, 0], [0, 1, 0], [0, 0, 1]])


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



@dataclass
class TextureLink:
    """An Image Texture node feeding a Principled input: ``output`` ("Color" or "Alpha") of
    ``node``, looked up at UV map ``uv_map`` ("": the mesh's active render UV map) through the
    (3, 3) homogeneous 2D affine ``uv_affine`` (the Mapping nodes on the way)."""

    node: object
    output: str
    uv_map: str = ""
    uv_affine: np.ndarray = field(default_factory=lambda: IDENTITY_UV.copy())

    def same_mapping(self, other: TextureLink) -> bool:
        return self.uv_map == other.uv_map and np.allclose(self.uv_affine, other.uv_affine, atol=1e-7)


@dataclass
class MaterialReading:
    """What :func:`read_material` finds in a material (no images read yet).

    ``rgba``, ``specular``, ``roughness``: :func:`material_surface` (the unlinked values);
    ``color``/``alpha_texture``: the supported image links of Base Color / Alpha; ``alpha``: the
    constant alpha (1 when Alpha is an image); ``problems``: the links read as their defaults;
    ``normal_map``: :func:`mapped_normal` (the node that bends a BSDF's normal, "" for none);
    ``alpha_scale``/``alpha_offset``: the alpha image's value ``a`` reads as ``scale * a +
    offset`` (a Transparent mix's factor, a Less Than clip); ``emission``: linear RGB x strength
    of an Emission surface (None: none); ``notes``: the approximations made (the report's)."""

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
    normal_map: str = ""
    alpha_scale: float = 1.0
    alpha_offset: float = 0.0
    emission: tuple | None = None
    notes: list = field(default_factory=list)


def _link_source(socket, stack: tuple = ()):
    """``(node, output socket, stack)`` feeding input ``socket`` (:func:`.nodes.resolve`: through
    reroutes and node groups), None when unlinked (a muted link counts as none, as in Blender)."""
    src = resolve(socket, stack)
    return None if src.node is None else (src.node, src.socket, src.stack)


_describe = describe


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


def _uv_source(socket, label: str, problems: list, stack: tuple = ()):
    """``(uv_map, affine)`` of an Image Texture's Vector input, None (with a problem) when it is
    not a UV lookup through Mapping nodes."""
    affine = IDENTITY_UV.copy()
    src = _link_source(socket, stack)
    if src is None:
        return "", affine
    for _ in range(16):
        node, out, stack = src
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
        src = _link_source(node.inputs["Vector"], stack)
        if src is None:
            problems.append(f"{label} reads a constant vector through {_describe(node)}, not UVs")
            return None
    problems.append(f"{label} reads its UVs through too many Mapping nodes")
    return None


def image_link(socket, label: str, problems: list, outputs=("Color",), stack: tuple = ()):
    """The :class:`TextureLink` feeding ``socket`` (inside the groups ``stack``) when it is an
    Image Texture read at UVs; None when unlinked, or (with a problem) when it is anything else."""
    src = _link_source(socket, stack)
    if src is None:
        return None
    node, out, stack = src
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
    uv = _uv_source(node.inputs["Vector"], label, problems, stack)
    if uv is None:
        return None
    return TextureLink(node=node, output=out.identifier, uv_map=uv[0], uv_affine=uv[1])


#: Node types that bend the shading normal a BSDF is lit with.
NORMAL_BENDERS = ("NORMAL_MAP", "BUMP")


def mapped_normal(tree) -> str:
    """A description of the first Normal Map or Bump node (through reroutes, not muted) feeding
    the Normal input of a shader node of ``tree``, "" when none: Cycles lights that shader with
    the bent normal, which the export does not read."""
    for node in tree.nodes:
        normal = node.inputs.get("Normal")
        if node.mute or normal is None or not any(o.type == "SHADER" for o in node.outputs):
            continue
        src = _link_source(normal)
        if src is not None and src[0].type in NORMAL_BENDERS and not src[0].mute:
            return f"{_describe(src[0])} feeds the Normal of {_describe(node)}"
    return ""


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


def _body_values(node, stack) -> tuple:
    """``(rgb, specular, roughness)`` of the BSDF read as a material's surface: a Principled's
    unlinked values; another BSDF's Color, no specular for the diffuse ones."""
    color = node.inputs.get("Base Color") or node.inputs.get("Color")
    value = constant(color, stack)
    rgb = as_rgb(value if value is not None else constant_default(color))
    if node.type == "BSDF_PRINCIPLED":
        spec, rough = (constant(node.inputs[n], stack) for n in ("Specular IOR Level", "Roughness"))
        spec = float(node.inputs["Specular IOR Level"].default_value) if spec is None else as_float(spec)
        rough = float(node.inputs["Roughness"].default_value) if rough is None else as_float(rough)
    elif node.type in ("BSDF_GLOSSY", "BSDF_ANISOTROPIC", "BSDF_GLASS", "BSDF_REFRACTION"):
        sock = node.inputs.get("Roughness")
        spec, rough = 0.5, as_float(constant(sock, stack) or 0.0) if sock is not None else 0.5
    else:
        spec, rough = 0.0, 0.5
    return rgb, min(max(spec, 0.0), 1.0), min(max(rough, 0.0), 1.0)


def _apply_alpha(r: MaterialReading, a: AlphaRead) -> None:
    """Set a reading's alpha from :class:`AlphaRead` ``a`` (a clip sets the CLIP mode)."""
    if a.texture is None:
        r.alpha = min(max(float(a.value), 0.0), 1.0)
        return
    r.alpha_texture, r.alpha = a.texture, 1.0
    r.alpha_scale, r.alpha_offset = float(a.scale), float(a.offset)
    if a.clip is not None:
        r.alpha_mode, r.alpha_threshold = "CLIP", float(a.clip)


def read_material(material) -> MaterialReading | None:
    """Colour, alpha, emission and the blend settings of a material's surface (None for no
    material): :mod:`.surfaces` walks its shader graph. Unsupported links are listed in
    ``problems`` and read as their default value; approximations in ``notes``."""
    if material is None:
        return None
    rgba, spec, rough = material_surface(material)
    mode, threshold, transparent = blend_settings(material)
    r = MaterialReading(name=material.name, rgba=rgba, specular=spec, roughness=rough, alpha=float(rgba[3]),
                        alpha_mode=mode, alpha_threshold=threshold, transparent_shadow=transparent)
    if not (material.use_nodes and material.node_tree):
        return r
    r.normal_map = mapped_normal(material.node_tree)
    surface = read_surface(material, r.problems, image_link)
    r.notes, r.emission = surface.notes, surface.emission
    node, stack = surface.body, surface.stack
    if node is None and surface.transparent_rgb is None:
        node, stack = principled_node(material.node_tree), ()
    if node is None:
        if surface.transparent_rgb is not None:
            r.rgba = tuple(surface.transparent_rgb) + (1.0,)
        _apply_alpha(r, surface.alpha)
        r.rgba = tuple(r.rgba[:3]) + (r.alpha,)
        return r
    rgb, r.specular, r.roughness = _body_values(node, stack)
    color = node.inputs.get("Base Color") or node.inputs.get("Color")
    label = "Base Color" if node.type == "BSDF_PRINCIPLED" else f"{node.bl_label} Color"
    r.color = image_link(color, label, r.problems, stack=stack)
    alpha = surface.alpha
    if node.type == "BSDF_PRINCIPLED" and alpha.texture is None and alpha.value >= 1.0:
        alpha = read_alpha(node.inputs["Alpha"], stack, "Alpha", r.problems, image_link)
    _apply_alpha(r, alpha)
    r.rgba = rgb + (r.alpha if r.alpha_texture is None else 1.0,)
    return r
