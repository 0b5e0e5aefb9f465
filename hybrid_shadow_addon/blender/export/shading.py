"""The shading of each exported instance: its shadow and sphere flags, colour, specular and
roughness, and (textured or alpha materials) a scene material with its images, each material and
image read once per export."""
from __future__ import annotations

import numpy as np

from ...core.bake.materials import srgb_decode
from ...core.scene import LUMA, Image, Material
from .common import is_sphere_primitive, terminator_offset, warn_export
from .images import image_pixels
from .materials import IDENTITY_UV, TextureLink, material_surface, read_material
from .meshes import ModelTable, mesh_uv_layer, mesh_uvs

#: The scene model's interpolation of an Image Texture node's (Cycles reads Smart as Cubic).
INTERPOLATIONS = {"Linear": "Linear", "Closest": "Closest", "Cubic": "Cubic", "Smart": "Cubic"}
#: The export report's line for a material whose BSDF normal a Normal Map or Bump node bends.
NORMAL_MAP_NOT_READ = "normal map not read (facing decided by the mesh's own normals)"


class ShadingTable:
    """Rows of per-instance attributes ``(casts_shadow, sphere, rgba, specular, roughness,
    material id, fallback rgba, shadow terminator geometry offset)``, one per object and
    material, with the scene's materials and images. A textured material gives the models it
    shows their UVs (from ``models``).

    Plain materials stay ``material id = -1``, so an opaque scene has no materials, images or
    UVs."""

    def __init__(self, models: ModelTable):
        self.model_table = models
        self.attrs: list[tuple] = []
        self.attr_of: dict = {}  # (object pointer, material pointer) -> attrs row
        self.dropped_of: dict = {}  # attrs row -> the same row without its material
        self.surface_of: dict = {}  # material pointer -> (rgba, specular, roughness, material id, fallback rgba)
        self.materials: list[Material] = []
        self.material_uv: list[str] = []  # UV map name of each material ("": active render)
        self.images: list[Image] = []
        self.image_of: dict = {}  # (image pointer, extension, interpolation) -> image id or -1
        self.pixels_of: dict = {}  # image pointer -> image_pixels()
        self.uv_of: dict = {}  # (model id, UV map name) -> bool (the model has those UVs)
        self.emission_of: dict = {}  # material pointer -> linear RGB x strength of an emitter

    def emission(self, ob, material) -> tuple:
        """Linear RGB x strength an object showing ``material`` emits towards the camera."""
        if material is None:
            return (0.0, 0.0, 0.0)
        key = material.as_pointer()
        if key not in self.surface_of:
            self.attributes(ob, material)
        return self.emission_of.get(key, (0.0, 0.0, 0.0))

    def attributes(self, ob, material) -> int:
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
            self.attrs.append((bool(ob.visible_shadow), is_sphere_primitive(ob)) + surface
                              + (terminator_offset(ob),))
            self.attr_of[key] = aid
        return aid

    def _material(self, material) -> tuple:
        """``(rgba, specular, roughness, material id, fallback rgba)`` of a Blender material: a
        new entry of ``self.materials`` when it is textured or its alpha is below 1 (id -1
        otherwise); the fallback colour is the unlinked Base Color and Alpha (the material
        without its textures). Warns once for what it reads as defaults, and once for a normal
        map it does not read."""
        r = read_material(material)
        problems = r.problems
        fallback = tuple(r.rgba)
        if r.emission is not None:
            self.emission_of[material.as_pointer()] = tuple(float(c) for c in r.emission)
        color_img = self._image_index(r.color, problems, "Base Color") if r.color is not None else -1
        alpha_img = -1
        if r.alpha_texture is not None:
            alpha_img = self._image_index(r.alpha_texture, problems, "Alpha", (r.alpha_scale, r.alpha_offset))
        alpha = r.alpha if alpha_img >= 0 or r.alpha_texture is None else float(fallback[3])
        if color_img >= 0 and alpha_img >= 0 and not r.color.same_mapping(r.alpha_texture):
            problems.append("Base Color and Alpha use different UV maps or mappings; the colour image "
                            "is dropped")
            color_img = -1
        link = r.alpha_texture if alpha_img >= 0 else r.color if color_img >= 0 else None
        rgb = (1.0, 1.0, 1.0) if color_img >= 0 else tuple(fallback[:3])
        for note in r.notes:
            warn_export(f"material '{material.name}': {note}")
        if r.normal_map:
            warn_export(f"material '{material.name}': {NORMAL_MAP_NOT_READ}: {r.normal_map}")
        if problems:
            warn_export(f"material '{material.name}': {'; '.join(problems)}: the export uses the default "
                        f"value{'s' if len(problems) > 1 else ''} instead")
        mid = -1
        if color_img >= 0 or alpha_img >= 0 or alpha < 1.0:
            mid = len(self.materials)
            self.materials.append(Material(
                name=material.name, color_image=color_img, alpha=min(max(alpha, 0.0), 1.0), alpha_image=alpha_img,
                alpha_channel="LUMA" if alpha_img >= 0 and r.alpha_texture.output == "Color"
                and (r.alpha_scale, r.alpha_offset) == (1.0, 0.0) else "A",
                uv_transform=(IDENTITY_UV if link is None else link.uv_affine)[:2],
                alpha_mode=r.alpha_mode, alpha_threshold=r.alpha_threshold,
                transparent_shadow=r.transparent_shadow))
            self.material_uv.append("" if link is None else link.uv_map)
        return rgb + (alpha,), r.specular, r.roughness, mid, fallback

    def _image_index(self, link: TextureLink, problems: list, label: str, affine=(1.0, 0.0)) -> int:
        """Index in ``self.images`` of the image an Image Texture node reads (one per image,
        extension and interpolation; the pixels read once per image); -1 (with a problem) when
        it has no pixels. ``affine`` ``(scale, offset)`` other than ``(1, 0)``: an alpha image
        whose Alpha (or Color luminance) is mapped so (:func:`mapped_alpha`)."""
        node = link.node
        image = node.image
        interp = INTERPOLATIONS.get(node.interpolation, "Linear")
        affine = (float(affine[0]), float(affine[1]))
        mapped = affine != (1.0, 0.0)
        key = (image.as_pointer(), node.extension, interp) + ((link.output,) + affine if mapped else ())
        idx = self.image_of.get(key)
        if idx is None:
            ptr = image.as_pointer()
            if ptr not in self.pixels_of:
                self.pixels_of[ptr] = image_pixels(image)
            px = self.pixels_of[ptr]
            idx = -1
            if px is not None:
                idx = len(self.images)
                pixels, srgb = px
                if mapped:
                    pixels, srgb = mapped_alpha(pixels, srgb, link.output, *affine), False
                self.images.append(Image(name=image.name, pixels=pixels, srgb=srgb, extension=node.extension,
                                         interpolation=interp))
            self.image_of[key] = idx
        if idx < 0:
            problems.append(f"{label} reads the image '{image.name}', whose pixels cannot be read "
                            f"(missing file?)")
        return idx

    def checked(self, aid: int, mid: int, mesh, name: str) -> int:
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
            model = self.model_table.models[mid]
            layer = mesh_uv_layer(mesh, uv_map) if mesh is not None else None
            if layer is None:
                ok = False
                warn_export(f"object '{name}': its material '{self.materials[k].name}' is textured but its mesh "
                            f"'{model.name}' has no UV map" + (f" named '{uv_map}'" if uv_map else "")
                            + ": exported without the material")
            elif model.uvs is None:
                uvs = mesh_uvs(mesh, layer)
                idx = self.model_table.model_tris.get(mid)
                model.uvs = uvs if idx is None else uvs[idx]
                self.uv_of[(mid, layer.name)] = ok = True
            else:
                ok = True
                if (mid, layer.name) not in self.uv_of:
                    warn_export(f"object '{name}': its material '{self.materials[k].name}' reads UV map "
                                f"'{layer.name}' of mesh '{model.name}', which is already exported with "
                                f"another UV map: using that one")
            self.uv_of[key] = ok
        if ok:
            return aid
        dropped = self.dropped_of.get(aid)
        if dropped is None:
            shadow, sphere, _, spec, rough, _, fallback, terminator = self.attrs[aid]
            dropped = self.dropped_of[aid] = len(self.attrs)
            self.attrs.append((shadow, sphere, fallback, spec, rough, -1, fallback, terminator))
        return dropped

    def needs_uvs(self, aid: int, mid: int) -> bool:
        """Whether the material of attributes ``aid`` is textured and model ``mid``'s UVs for it
        are not read (nor found missing) yet."""
        k = self.attrs[aid][5]
        return k >= 0 and self.materials[k].textured and (mid, self.material_uv[k]) not in self.uv_of


def mapped_alpha(pixels: np.ndarray, srgb: bool, output: str, scale: float, offset: float) -> np.ndarray:
    """(H, W, 4) uint8 image whose alpha is ``scale * a + offset`` (clamped to 0..1) of the
    stored image's Alpha (``output`` "Alpha") or Color luminance ("Color", decoded from sRGB when
    stored so): the image a Transparent mix's factor or a Less Than clip reads, for the alpha
    rule that reads an image's alpha as it is. Exact up to 8 bits: the map is affine, so it
    commutes with the lookup's filter."""
    px = pixels.astype(np.float64) / 255.0
    if px.shape[2] < 3:
        px = np.repeat(px[..., :1], 3, axis=2)
    if output == "Color":
        rgb = srgb_decode(px[..., :3]) if srgb else px[..., :3]
        a = rgb @ np.float64(LUMA)
    else:
        a = px[..., 3] if px.shape[2] == 4 else np.ones(px.shape[:2])
    out = np.zeros(px.shape[:2] + (4,), np.uint8)
    out[..., :3] = 255
    out[..., 3] = np.round(np.clip(scale * a + offset, 0.0, 1.0) * 255.0).astype(np.uint8)
    return out
