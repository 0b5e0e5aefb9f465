"""Per-light shadow visibility and the position pass from Cycles: the reference we measure against.

For each light: only that light renders (the others hidden; light and shadow linking stay as
the scene has them), ``max_bounces = 0``, ``filter_width = 0.01`` (samples
at the pixel centre), no world light, film transparent; the Diffuse Direct pass with the light's
``use_shadow`` on and off; visibility = shadowed / unshadowed. By default lights are made hard
for the reference (sun angle, point/spot radius and area size 0), as our shadows are: the
reference then measures where shadows fall, not how soft Cycles makes them (``hard=False``
keeps the scene's light sizes: the soft reference of ``compare --soft``, whose ``samples``, all
at the pixel centre, sample the light's area; both renders of a light share the seed, so the
noise of the ratio is that of the visibility, not of the irradiance). Pixels without full geometry
coverage, or that the light does not reach even unshadowed (facing away, outside a spot cone),
are invalid (NaN), as are pixels at a silhouette whose unshadowed light is below
:data:`UNSHADOWED_EDGE` of the brightest of their 8 neighbours: their pixel centre lies on a
surface the light does not reach, and the few samples that land on the neighbouring face (the
pixel filter is narrow, not zero) make the ratio measure that face instead. So are pixels whose
centre surface the light cannot reach (:func:`_reaches`: Cycles' Position and Normal passes
against the light's shape, facing and cone): with many samples, a few of them land past a
cut-out's edge on a lit surface in front or behind, and the pixel would measure that one.

Objects flagged as analytic sphere primitives (``hybrid_sphere``) are rendered as the sphere we
trace for them, not as their mesh: for the reference each gets, for a moment, a fine UV sphere
(:data:`SPHERE_SEGMENTS`, one per mesh) over its mesh's bounding sphere (the centre of its box, the radius to
its furthest vertex, as :class:`~hybrid_shadow_addon.core.scene.Model` derives it), modifiers
off. The comparison then measures the shadows, not the flag's stand-in: a coarse UV sphere's
facets lie inside the sphere through its vertices by enough to show as mismatched pixels
(BENCHMARKS.md).
``mesh_spheres=True`` renders them as their meshes (what Cycles shows the artist).

Transparent bounces are raised to :data:`TRANSPARENT_BOUNCES` so that shadow rays cross stacks
of alpha cards (Cycles' shadows of an alpha < 1 surface are always transparent).
:func:`render_diffuse_color` renders the Diffuse Color pass (the albedo) with the same set-up.

The user's scene is restored afterwards, whatever happens. Works with bpy 4.5 and 5.0 (which
name and split the EXR layers differently).

:class:`CyclesReferenceProvider` offers this to the ``compare`` tool as its
:class:`~hybrid_shadow_addon.tools.reference.ReferenceProvider`.
"""
from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.errors import HybridShadowError

UNSHADOWED_MIN = 1e-4
#: a pixel with less than this share of the unshadowed light of its brightest neighbour is a
#: silhouette's mixed pixel (see the module's docstring): invalid
UNSHADOWED_EDGE = 0.01
#: transparent bounces of the reference renders: enough for stacks of alpha cards and fences
TRANSPARENT_BOUNCES = 64
#: segments and rings of the UV sphere that stands in for a sphere primitive in the reference: its
#: facets lie within 0.03 % of the radius of the sphere through its vertices (objects that share a
#: mesh share the stand-in, so that Cycles still instances it)
SPHERE_SEGMENTS = (128, 64)
RECIPE_VERSION = 4  # bump when the reference recipe changes: invalidates the cached references


@dataclass
class CyclesReference:
    visibility: dict = field(default_factory=dict)  # light name -> (H, W) float32, NaN invalid
    position: np.ndarray = None  # (H, W, 3) float32 world position, NaN where no geometry
    render_ms: dict = field(default_factory=dict)  # light name -> ms for both renders
    unshadowed: dict = field(default_factory=dict)  # light name -> (H, W) Diffuse Direct without shadows


def _reaches(light_ob, position: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(H, W) bool: the light can reach the surface at each pixel centre (``position``,
    ``normal``: Cycles' passes, the normal turned towards the camera): some point of the light
    lies above the surface's tangent plane, the surface lies in front of an area light's plane,
    and within a spot's cone (widened by the angle its radius subtends). Where it cannot, that
    surface's Diffuse Direct is 0 whatever the shadows, so any light the pixel shows came from
    the few samples of its footprint that landed on another surface."""
    mw = np.array(light_ob.matrix_world, np.float64)
    light = light_ob.data
    n = normal.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    z = mw[:3, 2] / np.linalg.norm(mw[:3, 2])  # the light shines along -z
    if light.type == "SUN":
        return n @ z > -np.sin(0.5 * float(light.angle)) - 1e-4
    centre = mw[:3, 3]
    d = centre - position.astype(np.float64)
    dist = np.maximum(np.linalg.norm(d, axis=-1), 1e-12)
    if light.type == "AREA":
        sx = float(light.size)
        sy = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else sx
        corners = [centre + 0.5 * (i * sx * mw[:3, 0] + j * sy * mw[:3, 1]) for i in (-1, 1) for j in (-1, 1)]
        height = np.max([((c - position) * n).sum(-1) for c in corners], axis=0)
        return (height > -1e-4 * dist) & (d @ z > -1e-4 * dist)
    r = float(light.shadow_soft_size)
    ok = (d * n).sum(-1) > -r - 1e-4 * dist
    if light.type == "SPOT":
        half = 0.5 * float(light.spot_size) + np.arcsin(np.minimum(r / dist, 1.0)) + 1e-3
        ok &= (d @ z) / dist > np.cos(np.minimum(half, np.pi))
    return ok


def _neighbour_max(a: np.ndarray) -> np.ndarray:
    """The largest value of each pixel's 3x3 neighbourhood (the edges repeated)."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return np.max([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0)


def _read_exr(path: str) -> dict:
    """All channels of a (multi-part, multi-layer) EXR as ``{name: (H, W[, C]) float32}``,
    through the OpenImageIO module Blender ships (:func:`..tools.exr.read_exr`)."""
    from ..tools.exr import read_exr

    return read_exr(path)


def _find(channels: dict, *suffixes) -> np.ndarray:
    for name, px in channels.items():
        if any(name.endswith(s) for s in suffixes):
            return px
    raise KeyError(f"none of {suffixes} in EXR channels {sorted(channels)}")


def _position(channels: dict) -> np.ndarray:
    try:
        return _find(channels, ".Position", "Position")[..., :3]
    except KeyError:
        return np.stack([_find(channels, f"Position.{c}") for c in "XYZ"], axis=-1)


def _normal(channels: dict) -> np.ndarray:
    try:
        return _find(channels, ".Normal", "Normal")[..., :3]
    except KeyError:
        return np.stack([_find(channels, f"Normal.{c}") for c in "XYZ"], axis=-1)


class _Saved:
    """Remember attributes and restore them in reverse order."""

    def __init__(self):
        self._items = []

    def set(self, obj, attr, value):
        self._items.append((obj, attr, getattr(obj, attr)))
        setattr(obj, attr, value)

    def restore(self):
        for obj, attr, value in reversed(self._items):
            try:
                setattr(obj, attr, value)
            except (AttributeError, TypeError, ReferenceError):
                pass
        self._items.clear()


def _configure(bscene, saved: _Saved, resolution, samples: int, filepath: str) -> None:
    r = bscene.render
    saved.set(r, "engine", "CYCLES")
    if resolution is not None:
        saved.set(r, "resolution_x", int(resolution[0]))
        saved.set(r, "resolution_y", int(resolution[1]))
        saved.set(r, "resolution_percentage", 100)
    saved.set(r, "film_transparent", True)
    saved.set(r, "filepath", filepath)
    saved.set(r, "use_compositing", False)
    saved.set(r, "use_sequencer", False)
    c = bscene.cycles
    saved.set(c, "device", "CPU")
    saved.set(c, "samples", int(samples))
    saved.set(c, "max_bounces", 0)
    # alpha cards: a shadow or camera ray crosses many cut-out surfaces (Cycles' default is 8)
    saved.set(c, "transparent_max_bounces", TRANSPARENT_BOUNCES)
    saved.set(c, "use_denoising", False)
    saved.set(c, "use_adaptive_sampling", False)
    saved.set(c, "filter_width", 0.01)
    saved.set(c, "seed", 0)
    saved.set(bscene, "world", None)
    vl = bscene.view_layers[0]
    saved.set(vl, "use_pass_diffuse_direct", True)
    saved.set(vl, "use_pass_position", True)
    saved.set(vl, "use_pass_normal", True)
    im = r.image_settings
    if hasattr(im, "media_type"):  # Blender 5.0
        saved.set(im, "media_type", "MULTI_LAYER_IMAGE")
    else:
        saved.set(im, "file_format", "OPEN_EXR_MULTILAYER")
    saved.set(im, "color_depth", "32")
    saved.set(im, "exr_codec", "ZIP")


def _sphere_of(ob) -> tuple:
    """(centre, radius) of the bounding sphere of ``ob``'s evaluated mesh, in object space."""
    ev, mesh = ob, None
    try:
        ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = ev.to_mesh()
    except (RuntimeError, ReferenceError):
        ev, mesh = None, ob.data
    try:
        co = np.empty(3 * len(mesh.vertices), np.float64)
        mesh.vertices.foreach_get("co", co)
    finally:
        if ev is not None:
            ev.to_mesh_clear()
    co = co.reshape(-1, 3)
    if not len(co):
        return np.zeros(3), 0.0
    c = (co.min(axis=0) + co.max(axis=0)) * 0.5
    return c, float(np.sqrt(((co - c) ** 2).sum(axis=1).max()))


def _spheres_as_traced(saved: _Saved, made: list) -> None:
    """Give every mesh object flagged as a sphere primitive the sphere we trace (see the module's
    docstring); the temporary meshes go into ``made`` (the caller removes them after restoring)."""
    import bmesh

    from .export.common import is_sphere_primitive

    shared = {}  # (the object's mesh, its sphere) -> the stand-in: instances stay instances
    for ob in list(bpy.data.objects):
        if ob.type != "MESH" or ob.library is not None or not is_sphere_primitive(ob):
            continue
        centre, radius = _sphere_of(ob)
        key = (ob.data.name_full, tuple(np.round(centre, 9)), round(radius, 9))
        mesh = shared.get(key)
        if mesh is None:
            bm = bmesh.new()
            try:
                bmesh.ops.create_uvsphere(bm, u_segments=SPHERE_SEGMENTS[0], v_segments=SPHERE_SEGMENTS[1],
                                          radius=max(radius, 1e-9))
                bmesh.ops.translate(bm, verts=bm.verts, vec=tuple(centre))
                mesh = shared[key] = bpy.data.meshes.new(f"{ob.data.name} (reference sphere)")
                made.append(mesh)
                bm.to_mesh(mesh)
            finally:
                bm.free()
            mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
            for mat in ob.data.materials:
                mesh.materials.append(mat)
        for mod in ob.modifiers:
            saved.set(mod, "show_render", False)
        saved.set(ob, "data", mesh)


def _remove_meshes(made: list) -> None:
    for mesh in made:
        try:
            bpy.data.meshes.remove(mesh)
        except ReferenceError:
            pass
    made.clear()


def _make_hard(light, saved: _Saved) -> None:
    """Zero the light's size: a point, a spot's apex, a sun's exact direction."""
    if light.type == "SUN":
        saved.set(light, "angle", 0.0)
    elif light.type in ("POINT", "SPOT"):
        saved.set(light, "shadow_soft_size", 0.0)
    elif light.type == "AREA":
        saved.set(light, "size", 1e-4)
        saved.set(light, "size_y", 1e-4)


def render_reference(bscene, light_names=None, *, resolution=None, samples: int = 1,
                     progress=None, hard: bool = True, mesh_spheres: bool = False) -> CyclesReference:
    """Render the Cycles visibility of each named light (default: every shadow-casting light
    visible in render) and the position pass. ``progress(done, total, label)`` is called
    between renders; ``hard`` and ``mesh_spheres``: see the module's docstring."""
    lights = [o for o in bscene.objects if o.type == "LIGHT" and not o.hide_render]
    if light_names is None:
        light_names = [o.name for o in lights if o.data.use_shadow]
    targets = [bscene.objects[n] for n in light_names]
    ref = CyclesReference()
    saved, per_light, made = _Saved(), _Saved(), []

    def render(path):
        bpy.ops.render.render(write_still=True, scene=bscene.name)
        return _read_exr(path)

    def keep_position(channels):
        if ref.position is None:
            pos = _position(channels).copy()
            pos[_find(channels, ".Combined", "Combined")[..., 3] < 1.0 - 1e-6] = np.nan
            ref.position = pos

    with tempfile.TemporaryDirectory(prefix="hs-cycles-") as tmp:
        path = os.path.join(tmp, "ref.exr")
        try:
            _configure(bscene, saved, resolution, samples, path)
            if not mesh_spheres:
                _spheres_as_traced(saved, made)
            total = 2 * len(targets)
            for i, target in enumerate(targets):
                for o in lights:
                    per_light.set(o, "hide_render", o is not target)
                if hard:
                    _make_hard(target.data, per_light)
                passes = {}
                t0 = time.perf_counter()
                for k, shadow in enumerate((True, False)):
                    per_light.set(target.data, "use_shadow", shadow)
                    passes[shadow] = render(path)
                    if progress:
                        progress(2 * i + k + 1, total, target.name)
                ref.render_ms[target.name] = (time.perf_counter() - t0) * 1e3
                facing = _reaches(target, _position(passes[False]), _normal(passes[False]))
                per_light.restore()
                lit = _find(passes[True], "DiffDir", "Diffuse Direct")[..., :3].mean(axis=-1)
                full = _find(passes[False], "DiffDir", "Diffuse Direct")[..., :3].mean(axis=-1)
                alpha = _find(passes[False], ".Combined", "Combined")[..., 3]
                valid = ((full > UNSHADOWED_MIN) & (full >= UNSHADOWED_EDGE * _neighbour_max(full))
                         & (alpha >= 1.0 - 1e-6) & facing)
                vis = np.full(full.shape, np.nan, np.float32)
                vis[valid] = np.clip(lit[valid] / full[valid], 0.0, 1.0)
                ref.visibility[target.name] = vis
                ref.unshadowed[target.name] = full
                keep_position(passes[False])
            if ref.position is None:  # no shadowed light: the positions all the same
                keep_position(render(path))
        finally:
            per_light.restore()
            saved.restore()
            _remove_meshes(made)
    return ref


def _diffuse_color(channels: dict) -> np.ndarray:
    try:
        return _find(channels, ".DiffCol", "DiffCol", "Diffuse Color")[..., :3]
    except KeyError:
        return np.stack([_find(channels, f"DiffCol.{c}", f"Diffuse Color.{c}") for c in "RGB"], axis=-1)


def render_diffuse_color(bscene, resolution=None, *, samples: int = 1, base_color: bool = True,
                         mesh_spheres: bool = False) -> np.ndarray:
    """Cycles' Diffuse Color pass of ``bscene``: (H, W, 3) float32 linear RGB, row 0 the top row
    of the image (as :func:`render_reference`'s arrays), NaN where the pixel centre does not see
    full geometry coverage (Combined alpha < 1: background, or partly transparent cards in front
    of nothing).

    The same set-up as the visibility renders (pixel-centre samples, ``samples`` of them, no
    bounces, no world, :data:`TRANSPARENT_BOUNCES`); ``resolution`` ``(width, height)`` as
    there (default: the scene's render size). The pass is the diffuse closure's weight, which a
    Principled BSDF's specular layer lowers (by a few %, view-dependent); ``base_color`` (default)
    sets every Principled BSDF's Specular IOR Level to 0 for the render, so that the pass is the
    base colour times its image (for metallic 0, no transmission, coat or sheen). The scene and
    its materials are restored afterwards. Sphere primitives as in :func:`render_reference`."""
    saved, made = _Saved(), []
    with tempfile.TemporaryDirectory(prefix="hs-cycles-") as tmp:
        path = os.path.join(tmp, "albedo.exr")
        try:
            _configure(bscene, saved, resolution, samples, path)
            if not mesh_spheres:
                _spheres_as_traced(saved, made)
            saved.set(bscene.view_layers[0], "use_pass_diffuse_color", True)
            if base_color:
                for mat in bpy.data.materials:
                    if mat.node_tree is None or mat.library is not None:
                        continue
                    for node in mat.node_tree.nodes:
                        sock = node.inputs.get("Specular IOR Level") if node.type == "BSDF_PRINCIPLED" else None
                        if sock is not None and not sock.is_linked:
                            saved.set(sock, "default_value", 0.0)
            bpy.ops.render.render(write_still=True, scene=bscene.name)
            channels = _read_exr(path)
        finally:
            saved.restore()
            _remove_meshes(made)
    color = _diffuse_color(channels).astype(np.float32, copy=True)
    color[_find(channels, ".Combined", "Combined")[..., 3] < 1.0 - 1e-6] = np.nan
    return color


class CyclesReferenceProvider:
    """The Cycles reference of ``bscene`` (a ``bpy.types.Scene``) for ``compare``: it renders
    ``bscene`` as it stands, so the core scenes it is asked about must be exported from it at
    its current frame. ``hard``: see :func:`render_reference`."""

    name = "Cycles"

    def __init__(self, bscene, *, hard: bool = True, mesh_spheres: bool = False):
        self.bscene = bscene
        self.hard = hard
        self.mesh_spheres = mesh_spheres

    @property
    def recipe_version(self):
        """:data:`RECIPE_VERSION`, marked when sphere primitives render as their meshes (a
        reference of a different scene, cached apart)."""
        return f"{RECIPE_VERSION}+mesh-spheres" if self.mesh_spheres else RECIPE_VERSION

    @property
    def version(self) -> str:
        return bpy.app.version_string

    def light_names(self, scene) -> list:
        """The shadow-casting lights of ``scene`` that are light objects of ``bscene`` visible in
        render (Cycles renders one at a time by hiding the others)."""
        objs = self.bscene.objects
        return [light.name for light in scene.lights
                if light.use_shadow and light.name in objs and objs[light.name].type == "LIGHT"
                and not objs[light.name].hide_render]

    def visibility(self, scene, light: str, resolution, samples: int):
        """``(visibility, ms)`` of ``light`` alone (see :func:`render_reference`)."""
        if int(scene.frame) != int(self.bscene.frame_current):
            raise HybridShadowError(f"scene '{scene.name}' is at frame {scene.frame}, the Blender scene "
                                    f"'{self.bscene.name}' at {self.bscene.frame_current}")
        ref = render_reference(self.bscene, [light], resolution=tuple(resolution), samples=samples, hard=self.hard,
                               mesh_spheres=self.mesh_spheres)
        return ref.visibility[light], ref.render_ms[light]
