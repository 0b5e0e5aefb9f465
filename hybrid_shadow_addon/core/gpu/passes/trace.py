"""What the ray-traced shadow pass's hard and soft visibility share: its options, its stats
record, one light's trace inputs and the trace program (``shaders/raytrace.glsl``) built from
defines and bound to a frame's inputs."""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from ..lights import light_cone, soft_shape
from ..targets import set_uniforms
from .conservative import bind_map
from .refine import check_method

PLANES_MIN_ASPECT = 1.5  # ellipse lights this elongated bound their packets by the pyramid too


@dataclass(frozen=True)
class RaytraceOptions:
    """Switches of the ray-traced pass that no artist setting holds (tests, benchmarks, tools).
    Set at construction or as a whole: ``rp.options = replace(rp.options, packets=False)``."""

    #: leave out the lights that reach no pixel (tests compare without); None: on a software
    #: rasteriser only, where a light's pass costs the walk's code per 8-pixel group whether its
    #: lanes need a ray or not. On a GPU such a light's pixels end at the shader's reach test,
    #: and the test's read-back would stall the frame.
    cull_lights: bool | None = None
    #: soft lights: a pixel's rays walk the scene together (else ray by ray)
    packets: bool = True
    #: soft lights on the compute path: a pixel's samples spread over lanes, ray by ray, instead
    #: of walking as packets. None: on a GPU (a packet's arrays live in slow local memory there);
    #: packets on a software rasteriser, where one walk for many rays pays
    soft_lanes: bool | None = None
    #: ray by ray: a penumbra's fringe pixel may stop after half its samples
    early_stop: bool = True
    #: tests: refined pixels whose loops hit llvmpipe's budget read HS_LOOP_SPENT
    loop_check: bool = False
    #: soft lights: a draw whose rays llvmpipe's loop budget cut short (every loop of an
    #: invocation ends after 65535 iterations in all; a walk cut short ends as if nothing were in
    #: the way) drops them: its sums add nothing, a refined mask keeps its probes' answer. None:
    #: on a software rasteriser, the only place with that budget
    loop_guard: bool | None = None
    #: build a hard light's grid at its first sight, in the frame (benchmarks, tests, tools),
    #: not once it pays back in the background (``passes/light_grid.py``)
    eager_light_grids: bool = False
    #: how the refinement traces its marked pixels (:data:`.refine.METHODS`)
    refine_method: str = "depth"

    def __post_init__(self):
        check_method(self.refine_method)


@dataclass
class RaytraceStats:
    """The ray-traced pass's stats of the last frame (``Frame.stats`` takes them as a dict).
    ``rays_traced`` counts the pixels the trace shaded (occlusion queries; on the compute path
    the texels queued for a ray: the answers known without one are not counted), ``pixels`` the
    pixels with geometry times the shadowed lights, ``pixels_reused`` the pixels with geometry
    (times lights) that a reusing light settled without a ray: from an earlier frame
    (:mod:`.reproject`), or known without one (facing away); with ``rays_traced`` they make up
    those lights' pixels. ``reuse_ways`` how many hard lights reused their history and how many
    were traced plainly where reusing did not pay (:class:`.reproject.ReuseChoice`),
    ``lights_culled`` the lights traced by no ray (:mod:`.light_cull`), ``trace_path`` the
    path the masks were traced on (``compute`` or ``fragment``). The three counts the GPU
    keeps (``rays_traced``, ``pixels``, ``pixels_reused``) are None in a frame that does not
    read them (``Pipeline.timing`` ``"frame"``)."""

    mask_resolution: list
    rays: int = 0
    rays_traced: int | None = 0
    pixels: int | None = 0
    pixels_reused: int | None = 0
    samples: int = 1
    accumulated_samples: int | None = None
    lights_culled: int = 0
    reuse_ways: dict = field(default_factory=dict)
    trace_path: str = "fragment"
    noise: dict = field(default_factory=dict)
    defines: list = field(default_factory=list)


@dataclass
class LightRay:
    """One shadowed light's trace inputs in a frame: its index and light, ``vec`` (the shader's
    ``u_light_vec``, bake space), ``soft`` (:func:`~..lights.soft_shape`, None: hard), the
    program ``defines``, its conservative map ``(texture, MapViews)`` and light grid (a
    :class:`~.light_grid.LightGridHandle`), each None where it has none."""

    index: int
    light: object
    local: bool
    vec: tuple
    soft: dict | None
    defines: dict
    cmap: tuple | None = None
    grid: object = None


def pyramid_bounds(soft: dict) -> bool:
    """Whether a soft light's packets are bounded by the pyramid over its rectangle as well as
    by their cone (``HS_PACKET_PLANES``, ``shaders/common/scene_packet.glsl``): rectangles, and
    ellipses at least PLANES_MIN_ASPECT times as long as wide (a rounder ellipse's cone already
    lies almost inside the pyramid: four plane tests per node would buy nothing)."""
    if soft["shape"] == 2:
        return True
    if soft["shape"] != 3:
        return False
    lu, lv = (float(np.linalg.norm(soft[k])) for k in ("u_light_u", "u_light_v"))
    return max(lu, lv) >= PLANES_MIN_ASPECT * min(lu, lv)


def light_seed(light, frame: int = 1) -> int:
    """The seed of a light's sample pattern in a frame of the animation: the same in every
    session, another one in each frame (each pixel's rotation of the sequence changes)."""
    return (zlib.crc32(light.name.encode("utf-8")) ^ ((int(frame) * 0x9E3779B1) & 0xFFFFFFFF)) & 0x7FFFFFFF


class TraceProgram:
    """The trace program of a set of defines (the bake's, the light kind's, the settings'),
    bound to the G-buffer, the baked scene and a light's grid, map and uniforms."""

    def __init__(self, gpu):
        self.programs = gpu.programs
        self.scene_textures = gpu.scene_textures
        self.linking = gpu.linking
        self.scene_frame = 1  # the animation frame being rendered (seeds the sample patterns)
        self.smooth = False  # the scene has smooth-shaded models: their terminator moves origins

    def defines(self, settings, local: bool, soft: dict | None = None) -> dict:
        d = dict(self.scene_textures.baked.defines)
        d.update(self.scene_textures.defines)
        d.update(self.linking.defines)
        d["HS_LIGHT_LOCAL" if local else "HS_LIGHT_SUN"] = 1
        if soft is not None:
            d["HS_SOFT"] = 1
            d["HS_SOFT_SHAPE"] = int(soft["shape"])
            if pyramid_bounds(soft):
                d["HS_PACKET_PLANES"] = 1
        if settings.max_distance > 0:
            d["HS_MAX_DISTANCE"] = 1
        if settings.interlace:
            d["HS_INTERLACE"] = 1
        if self.smooth:
            d["HS_TERMINATOR"] = 1
        return d

    def bind(self, defines, ray: LightRay, gbuffer, settings, scale: int, sample_base: int = 0,
             split: int = 0):
        """The program of ``defines`` bound to this frame's inputs and ``ray``'s light:
        ``(prog, vao, next free texture unit)``."""
        prog, vao = self.programs.fullscreen("raytrace", defines)
        unit = self._bind_inputs(prog, defines, ray, gbuffer, settings, scale, sample_base, split)
        return prog, vao, unit

    def bind_compute(self, defines, ray: LightRay, gbuffer, settings, scale: int, kernel: str,
                     sample_base: int = 0, split: int = 0):
        """The compute program of ``defines`` (``kernel`` ``"gen"``: the generating kernel over
        the mask's texels, ``"trace"``: the tracing kernel over the queue; :mod:`.queue`),
        bound as :meth:`bind` binds: ``(prog, next free texture unit)``."""
        mode = {"gen": "HS_QUEUE_GEN", "trace": "HS_QUEUE_TRACE"}[kernel]
        if kernel == "gen":  # (the lanes are the tracing kernel's)
            defines = {k: v for k, v in defines.items() if k != "HS_QUEUE_LANES"}
        prog = self.programs.compute("raytrace", {**defines, mode: 1})
        return prog, self._bind_inputs(prog, defines, ray, gbuffer, settings, scale, sample_base, split,
                                       walk=kernel == "trace")

    def _bind_inputs(self, prog, defines, ray, gbuffer, settings, scale, sample_base=0, split=0,
                     walk: bool = True) -> int:
        """Bind the G-buffer, the scene, the linking and (``walk``: a program that walks the
        scene) the light's grid and map to ``prog``, set its uniforms; the next free unit."""
        unit = gbuffer.bind(prog)
        unit = self.scene_textures.bind(prog, unit)
        unit = self.linking.bind(prog, unit)
        if walk and "HS_LIGHT_GRID" in defines:
            unit = ray.grid.bind(prog, unit)
        if walk and ray.cmap is not None:
            unit = bind_map(prog, unit, *ray.cmap, self.scene_textures.baked.origin)
        set_uniforms(prog, {"u_scale": int(scale), "u_full_size": (gbuffer.width, gbuffer.height)})
        set_uniforms(prog, self.uniforms(ray, gbuffer, settings, sample_base, split))
        return unit

    def uniforms(self, ray: LightRay, gbuffer, settings, sample_base: int = 0, split: int = 0) -> dict:
        """The light's uniforms (``sample_base``: the first sample of each pixel's sequence this
        draw traces; ``split``: the samples before it also sum apart)."""
        light = ray.light
        axis, cone = light_cone(light)
        u = {"u_light_vec": ray.vec, "u_light_axis": axis, "u_light_cone": cone,
             "u_cam_bake": tuple(float(v) for v in gbuffer.camera.cam_pos - self.scene_textures.baked.origin),
             "u_max_distance": float(settings.max_distance), **self.linking.light_uniforms(light)}
        soft = soft_shape(light, settings.hard)
        if soft is not None:
            u.update({k: v for k, v in soft.items() if k != "shape"})
            u.update({"u_samples": int(settings.samples), "u_sample_base": int(sample_base),
                      "u_split": int(split), "u_seed": light_seed(light, self.scene_frame)})
        return u
