"""Per-light shadow visibility and the position pass from Cycles: the reference we measure against.

For each light: only that light renders, ``max_bounces = 0``, ``filter_width = 0.01`` (samples
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
pixel filter is narrow, not zero) make the ratio measure that face instead.

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
RECIPE_VERSION = 3  # bump when the reference recipe changes: invalidates the cached references


@dataclass
class CyclesReference:
    visibility: dict = field(default_factory=dict)  # light name -> (H, W) float32, NaN invalid
    position: np.ndarray = None  # (H, W, 3) float32 world position, NaN where no geometry
    render_ms: dict = field(default_factory=dict)  # light name -> ms for both renders
    unshadowed: dict = field(default_factory=dict)  # light name -> (H, W) Diffuse Direct without shadows


def _neighbour_max(a: np.ndarray) -> np.ndarray:
    """The largest value of each pixel's 3x3 neighbourhood (the edges repeated)."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return np.max([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0)


def _read_exr(path: str) -> dict:
    """All channels of a (multi-part, multi-layer) EXR as ``{name: (H, W[, C]) float32}``."""
    import OpenEXR

    out = {}
    with OpenEXR.File(path, separate_channels=False) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                out[name] = np.asarray(ch.pixels, dtype=np.float32)
    return out


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
    im = r.image_settings
    if hasattr(im, "media_type"):  # Blender 5.0
        saved.set(im, "media_type", "MULTI_LAYER_IMAGE")
    else:
        saved.set(im, "file_format", "OPEN_EXR_MULTILAYER")
    saved.set(im, "color_depth", "32")
    saved.set(im, "exr_codec", "ZIP")


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
                     progress=None, hard: bool = True) -> CyclesReference:
    """Render the Cycles visibility of each named light (default: every shadow-casting light
    visible in render) and the position pass. ``progress(done, total, label)`` is called
    between renders; ``hard``: see the module's docstring."""
    lights = [o for o in bscene.objects if o.type == "LIGHT" and not o.hide_render]
    if light_names is None:
        light_names = [o.name for o in lights if o.data.use_shadow]
    targets = [bscene.objects[n] for n in light_names]
    ref = CyclesReference()
    saved, per_light = _Saved(), _Saved()

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
                per_light.restore()
                lit = _find(passes[True], "DiffDir", "Diffuse Direct")[..., :3].mean(axis=-1)
                full = _find(passes[False], "DiffDir", "Diffuse Direct")[..., :3].mean(axis=-1)
                alpha = _find(passes[False], ".Combined", "Combined")[..., 3]
                valid = (full > UNSHADOWED_MIN) & (full >= UNSHADOWED_EDGE * _neighbour_max(full)) & (alpha >= 1.0 - 1e-6)
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
    return ref


def _diffuse_color(channels: dict) -> np.ndarray:
    try:
        return _find(channels, ".DiffCol", "DiffCol", "Diffuse Color")[..., :3]
    except KeyError:
        return np.stack([_find(channels, f"DiffCol.{c}", f"Diffuse Color.{c}") for c in "RGB"], axis=-1)


def render_diffuse_color(bscene, resolution=None, *, samples: int = 1, base_color: bool = True) -> np.ndarray:
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
    its materials are restored afterwards."""
    saved = _Saved()
    with tempfile.TemporaryDirectory(prefix="hs-cycles-") as tmp:
        path = os.path.join(tmp, "albedo.exr")
        try:
            _configure(bscene, saved, resolution, samples, path)
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
    color = _diffuse_color(channels).astype(np.float32, copy=True)
    color[_find(channels, ".Combined", "Combined")[..., 3] < 1.0 - 1e-6] = np.nan
    return color


class CyclesReferenceProvider:
    """The Cycles reference of ``bscene`` (a ``bpy.types.Scene``) for ``compare``: it renders
    ``bscene`` as it stands, so the core scenes it is asked about must be exported from it at
    its current frame. ``hard``: see :func:`render_reference`."""

    name = "Cycles"
    recipe_version = RECIPE_VERSION

    def __init__(self, bscene, *, hard: bool = True):
        self.bscene = bscene
        self.hard = hard

    @property
    def version(self) -> str:
        return bpy.app.version_string

    def light_names(self, scene) -> list:
        """The shadow-casting lights of ``scene`` that are light objects of ``bscene`` visible in
        render (Cycles renders one at a time by hiding the others)."""
        objs = self.bscene.objects
        return [l.name for l in scene.lights
                if l.use_shadow and l.name in objs and objs[l.name].type == "LIGHT" and not objs[l.name].hide_render]

    def visibility(self, scene, light: str, resolution, samples: int):
        """``(visibility, ms)`` of ``light`` alone (see :func:`render_reference`)."""
        if int(scene.frame) != int(self.bscene.frame_current):
            raise HybridShadowError(f"scene '{scene.name}' is at frame {scene.frame}, the Blender scene "
                                    f"'{self.bscene.name}' at {self.bscene.frame_current}")
        ref = render_reference(self.bscene, [light], resolution=tuple(resolution), samples=samples, hard=self.hard)
        return ref.visibility[light], ref.render_ms[light]
