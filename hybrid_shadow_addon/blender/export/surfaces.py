"""What a material's Surface shows, read from its shader graph as Cycles evaluates it: the BSDF
whose colour is the albedo, the share a Transparent BSDF lets through (a constant, or an image
through a Mix Shader's factor, with Math-node clips), an Emission's colour, and notes for what
is approximated.

Rules (each approximation is a note in the export report):

- Principled, Diffuse: read as they are (Diffuse: no specular).
- Transparent BSDF alone: alpha ``1 - luminance(colour)`` (white: the camera and the shadow rays
  pass; a colour's shadow is its luminance).
- Mix Shader with a Transparent BSDF on one side: alpha from the factor (a constant, an Image
  Texture, or a Math Greater Than / Less Than / Round of one: a CLIP threshold); the other side
  is read as the surface.
- Emission: drawn with colour x strength, lit by nothing; it casts shadows (its light on the
  scene is not emitted: "lights nothing").
- Glass, Refraction, a Principled with Transmission: drawn opaque with their colour; their shadow
  is opaque (Cycles' shadow rays are blocked by refraction).
- Glossy, Sheen, Toon, Translucent, Subsurface and other BSDFs with a Color: read as Diffuse of
  that colour; a Mix or Add of two such: the heavier side (Add: the first).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .nodes import as_float, as_rgb, constant, describe, resolve

#: BSDFs read as they are
EXACT = ("BSDF_PRINCIPLED", "BSDF_DIFFUSE")
#: BSDFs whose shadow rays stop (refraction) and that are drawn opaque with their colour
REFRACTIVE = ("BSDF_GLASS", "BSDF_REFRACTION")


@dataclass
class AlphaRead:
    """What an alpha (or a Transparent mix's factor) reads: a constant ``value``, or the Image
    Texture output ``texture`` (:class:`..materials.TextureLink`) mapped by ``scale * a +
    offset``; ``clip``: the threshold of a Math-node clip (None: none)."""

    value: float = 1.0
    texture: object = None
    scale: float = 1.0
    offset: float = 0.0
    clip: float | None = None


@dataclass
class SurfaceRead:
    """A material's surface: ``body`` (the BSDF read for colour, specular and roughness, None:
    none) in the groups ``stack``; ``alpha`` (:class:`AlphaRead`: 1 minus what a Transparent BSDF
    lets through); ``emission`` (linear RGB x strength, None: not an emitter); ``notes``: the
    approximations made."""

    body: object = None
    stack: tuple = ()
    alpha: AlphaRead = field(default_factory=AlphaRead)
    transparent_rgb: tuple | None = None
    emission: tuple | None = None
    notes: list = field(default_factory=list)


def _color_input(node):
    return node.inputs.get("Base Color") or node.inputs.get("Color")


def read_alpha(socket, stack: tuple, label: str, problems: list, link_image) -> AlphaRead:
    """The alpha an input reads: a constant, an Image Texture's Alpha or Color output, or a Math
    Greater Than / Less Than (constant threshold) or Round of either (a clip). ``link_image``:
    :func:`..materials.image_link`."""
    value = constant(socket, stack)
    if value is not None:
        return AlphaRead(value=as_float(value))
    src = resolve(socket, stack)
    node = src.node
    if node.type == "MATH" and not node.mute and node.operation in ("GREATER_THAN", "LESS_THAN", "ROUND"):
        if node.operation == "ROUND":
            threshold = 0.5
        else:
            t = constant(node.inputs[1], src.stack)
            if t is None:
                problems.append(f"{label} is clipped by {describe(node)} at a threshold that is not a constant")
                return AlphaRead()
            threshold = as_float(t)
        inner = read_alpha(node.inputs[0], src.stack, label, problems, link_image)
        if inner.clip is not None:
            problems.append(f"{label} is clipped twice ({describe(node)})")
            return AlphaRead()
        less = node.operation == "LESS_THAN"
        if inner.texture is None:
            above = inner.value > threshold if not less else inner.value < threshold
            if node.operation == "ROUND":
                above = inner.value >= threshold
            return AlphaRead(value=float(above))
        if less:  # a < t is 1 - a > 1 - t
            return AlphaRead(texture=inner.texture, scale=-inner.scale, offset=1.0 - inner.offset,
                             clip=1.0 - threshold)
        return AlphaRead(texture=inner.texture, scale=inner.scale, offset=inner.offset, clip=threshold)
    tex = link_image(socket, label, problems, outputs=("Alpha", "Color"), stack=stack)
    return AlphaRead(value=as_float(constant_default(socket))) if tex is None else AlphaRead(texture=tex)


def constant_default(socket):
    """An input's own default value (what Blender reads in place of an unsupported link)."""
    value = socket.default_value
    try:
        return tuple(float(v) for v in value)
    except TypeError:
        return float(value)


class SurfaceReader:
    """Walks a material's Surface link (one instance per material)."""

    def __init__(self, material, problems: list, link_image):
        self.material = material
        self.problems = problems
        self.link_image = link_image
        self.read = SurfaceRead()

    def run(self) -> SurfaceRead:
        tree = self.material.node_tree
        out = tree.get_output_node("CYCLES") or tree.get_output_node("ALL")
        if out is None:
            self.read.notes.append("no Material Output: read from its viewport display settings")
            return self.read
        for name, note in (("Volume", "volume ignored"), ("Displacement", "displacement ignored")):
            sock = out.inputs.get(name)
            if sock is not None and resolve(sock).node is not None:
                self.read.notes.append(note)
        src = resolve(out.inputs["Surface"])
        if src.node is None:
            self.read.notes.append("no Surface shader (Cycles draws it black): read from its viewport settings")
            return self.read
        self._visit(src.node, src.stack)
        return self.read

    def _visit(self, node, stack) -> None:
        kind = node.type
        r = self.read
        if node.mute:
            r.notes.append(f"muted shader {describe(node)}: read from its viewport settings")
        elif kind == "MIX_SHADER":
            self._mix(node, stack)
        elif kind == "ADD_SHADER":
            sides = [resolve(node.inputs[k], stack) for k in (1, 2)]
            sides = [s for s in sides if s.node is not None]
            if sides:
                keep = next((s for s in sides if s.node.type != "EMISSION"), sides[0])
                r.notes.append(f"Add Shader {describe(node)} read as {describe(keep.node)} alone")
                self._visit(keep.node, keep.stack)
        elif kind == "BSDF_TRANSPARENT":
            rgb = self._rgb(node.inputs["Color"], stack, "Transparent BSDF Color")
            r.transparent_rgb = rgb
            r.alpha = AlphaRead(value=1.0 - as_float(rgb))
            if max(rgb) - min(rgb) > 1e-3:
                r.notes.append(f"the Transparent BSDF's colour {_fmt(rgb)} tints Cycles' shadow; its "
                               f"luminance is the shadow's share")
        elif kind == "EMISSION":
            rgb = self._rgb(node.inputs["Color"], stack, "Emission Color")
            strength = constant(node.inputs["Strength"], stack)
            if strength is None:
                self.problems.append("Emission Strength is linked")
                strength = float(node.inputs["Strength"].default_value)
            r.body, r.stack = node, stack
            r.emission = tuple(c * as_float(strength) for c in rgb)
            r.notes.append("emissive: drawn with its colour x strength, lights nothing")
        elif kind == "HOLDOUT":
            r.notes.append(f"holdout shader {describe(node)}: drawn as an opaque surface")
        elif kind in EXACT or kind in REFRACTIVE or _color_input(node) is not None:
            r.body, r.stack = node, stack
            if kind == "BSDF_PRINCIPLED":
                self._principled(node, stack)
            elif kind in REFRACTIVE:
                r.notes.append(f"{node.bl_label} drawn opaque with its colour (its shadow is opaque, as "
                               f"Cycles' shadow rays are blocked by refraction)")
            elif kind not in EXACT:
                r.notes.append(f"{node.bl_label} read as Diffuse of its colour")
        else:
            r.notes.append(f"shader {describe(node)} not understood: read from its viewport settings")

    def _mix(self, node, stack) -> None:
        r = self.read
        sides = [resolve(node.inputs[k], stack) for k in (1, 2)]
        clear = [s.node is not None and s.node.type == "BSDF_TRANSPARENT" and not s.node.mute for s in sides]
        fac = constant(node.inputs["Fac"], stack)
        if clear[0] != clear[1]:
            t = 0 if clear[0] else 1
            body = sides[1 - t]
            rgb = self._rgb(sides[t].node.inputs["Color"], sides[t].stack, "Transparent BSDF Color")
            lum = as_float(rgb)
            if body.node is not None:
                self._visit(body.node, body.stack)
            if r.alpha.texture is not None or r.alpha.value < 1.0 or r.transparent_rgb is not None:
                r.notes.append(f"Mix Shader {describe(node)}: the transparency inside its other shader is not read")
            r.transparent_rgb = rgb
            f = read_alpha(node.inputs["Fac"], stack, "Mix Shader Fac", self.problems, self.link_image)
            # the transparent share: lum * (1 - fac) on input 1, lum * fac on input 2
            sign = 1.0 if t == 0 else -1.0
            if f.texture is None:
                share = lum * ((1.0 - f.value) if t == 0 else f.value)
                r.alpha = AlphaRead(value=1.0 - share)
            elif f.clip is not None:
                if lum < 0.999:
                    r.notes.append(f"Mix Shader {describe(node)}: a clipped cut-out's Transparent colour "
                                   f"{_fmt(rgb)} read as white")
                if t == 0:
                    r.alpha = f
                else:
                    r.alpha = AlphaRead(texture=f.texture, scale=-f.scale, offset=1.0 - f.offset, clip=1.0 - f.clip)
            else:  # alpha = 1 - lum + lum * a (input 1), 1 - lum * a (input 2)
                r.alpha = AlphaRead(texture=f.texture, scale=sign * lum * f.scale,
                                    offset=(1.0 - lum if t == 0 else 1.0) + sign * lum * f.offset)
            if max(rgb) - min(rgb) > 1e-3:
                r.notes.append(f"the Transparent BSDF's colour {_fmt(rgb)} tints Cycles' shadow; its "
                               f"luminance is the shadow's share")
            return
        if all(clear):
            rgbs = [self._rgb(s.node.inputs["Color"], s.stack, "Transparent BSDF Color") for s in sides]
            f = 0.5 if fac is None else as_float(fac)
            rgb = tuple((1 - f) * a + f * b for a, b in zip(*rgbs))
            r.transparent_rgb = rgb
            r.alpha = AlphaRead(value=1.0 - as_float(rgb))
            return
        present = [s for s in sides if s.node is not None]
        if not present:
            return
        keep = present[0]
        if len(present) == 2:
            f = 0.5 if fac is None else as_float(fac)
            keep = present[1] if f > 0.5 else present[0]
            how = "its factor is linked" if fac is None else f"factor {f:g}"
            r.notes.append(f"Mix Shader {describe(node)} ({how}) read as {describe(keep.node)} alone")
        self._visit(keep.node, keep.stack)

    def _principled(self, node, stack) -> None:
        r = self.read
        for name, note in (("Subsurface Weight", "Subsurface read as Diffuse"),
                           ("Transmission Weight", "Transmission drawn opaque (its shadow is opaque, as Cycles')")):
            sock = node.inputs.get(name)
            v = constant(sock, stack) if sock is not None else 0.0
            if v is None or as_float(v) > 0.0:
                r.notes.append(note)
        strength = node.inputs.get("Emission Strength")
        color = node.inputs.get("Emission Color")
        if strength is not None and color is not None:
            s, c = constant(strength, stack), constant(color, stack)
            if s is None or c is None or (as_float(s) > 0.0 and max(as_rgb(c)) > 0.0):
                r.notes.append("Principled emission not drawn (lights nothing)")

    def _rgb(self, socket, stack, label) -> tuple:
        value = constant(socket, stack)
        if value is None:
            self.problems.append(f"{label} is linked")
            return as_rgb(socket.default_value)
        return as_rgb(value)


def _fmt(rgb) -> str:
    return "(" + ", ".join(f"{c:.3g}" for c in rgb) + ")"


def read_surface(material, problems: list, link_image) -> SurfaceRead:
    """:class:`SurfaceRead` of a node material (the Cycles output's Surface)."""
    return SurfaceReader(material, problems, link_image).run()
