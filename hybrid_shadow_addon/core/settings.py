"""Render settings: the one value object the CLI, Blender properties and benchmarks all build."""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, field, fields, replace

from .bake.structures import DEFAULT_STRUCTURE
from .bake.structures import STRUCTURES as STRUCTURE_CLASSES

QUALITY_SCALE = {"high": 1, "medium": 2, "low": 4}  # mask resolution = full / scale


@dataclass(frozen=True)
class Choice:
    """One value of a setting with choices: what the Blender property and the command line show."""

    value: str | int
    label: str
    help: str
    icon: str = "NONE"


def setting(default, label: str, help: str, *, choices: tuple = (), low=None, high=None, soft_max=None,
            optional: bool = False, blender: dict | None = None, cli: str | None = "", metavar: str | None = None):
    """A :class:`Settings` field and its one declaration: ``label`` and ``help`` (what an artist
    reads in Blender and on the command line), ``choices`` (:class:`Choice`) or the range ``low``
    .. ``high`` its value is checked against (``soft_max``: the UI slider's end), ``optional``:
    None allowed (all). ``blender``: the scene property it comes from (``name``, default the
    field's; ``invert``, a switch shown the other way round, with its own ``label`` and ``help``;
    ``choices``, the values a property of an integer field offers; ``redraw``: a change redraws
    rendered viewports; ``subtype``, ``unit``, ``precision``, ``step``: the property's own), None: no
    property. ``cli``: the command line's option (default ``--field-name``; a ``--no-`` option for
    a switch on by default), None: none."""
    meta = {"label": label, "help": help, "choices": tuple(choices), "low": low, "high": high,
            "soft_max": soft_max, "optional": optional, "blender": blender, "cli": cli, "metavar": metavar}
    return field(default=default, metadata=meta)


def kind(f) -> str:
    """``bool``, ``int``, ``float`` or ``str``: a field's type, from its declaration."""
    return str(f.type).split(" | ")[0]


def check(f, v) -> None:
    """Raise ``ValueError`` if ``v`` is not a value field ``f`` may take."""
    m, name = f.metadata, f.name
    if m["choices"]:
        values = tuple(c.value for c in m["choices"])
        if v not in values:
            raise ValueError(f"{name} must be one of {', '.join(map(str, values))}, not {v!r}")
    elif kind(f) == "bool":
        if not isinstance(v, bool):
            raise ValueError(f"{name} must be True or False, not {v!r}")
    elif v is None and m["optional"]:
        return
    elif kind(f) == "int":
        _integer(v, f"{name} (or None for all)" if m["optional"] else name, low=m["low"], high=m["high"])
    else:
        _number(v, name, low=m["low"])


@dataclass(frozen=True)
class Settings:
    """How shadows are made.

    - ``mode``: ``raytrace`` (rays through the grid), ``shadowmap`` or ``none`` (all lit).
    - ``quality``: mask resolution ``high`` = full, ``medium`` = 1/2, ``low`` = 1/4 per side;
      in ``raytrace`` mode the lower ones trace every 2nd / 4th pixel and refine the rest at
      full resolution (their own ray where the coarse answer cannot stand for them).
    - ``max_distance``: shadows only within this camera distance in metres (0 = no limit).
    - ``max_shadowed_lights``: shadow only the nearest N shadow-casting lights (suns always
      count first); ``None`` = all.
    - ``interlace``: ray interlacing (a quarter of the mask's rays per frame).
    - ``shadowmap_size``: texels per side of each shadow map (cube face for point lights).
    - ``pcf``: PCF kernel radius in shadow-map texels (0 = one tap).
    - ``shadow_bias``: constant depth bias in shadow-map texels; ``slope_bias``: slope-scaled
      factor; ``normal_offset``: receiver offset along the normal, in texels.
    - ``pcss_samples``: ``shadowmap`` mode, lights with a size (unless ``hard``): PCF taps per
      pixel of the percentage-closer soft shadow filter (its blocker search takes half as many).
    - ``upsample``: how reduced-resolution masks reach full resolution: ``bilateral`` (depth/normal
      aware; ray-traced medium/low refine instead, so their masks need none) or ``nearest`` (the
      thesis' blocky look; ray-traced medium/low then keep their coarse rays unrefined).
    - ``specular``: Blinn-Phong highlights in the lighting (False: diffuse and ambient only).
    - ``conservative``: conservative light-space occupancy maps in ``raytrace`` mode, which let
      receivers no caster can reach skip their ray and cut the others short; exact (the masks
      do not change), only the work does. ``off`` (default: on a software GPU building the map
      costs about what it saves, see BENCHMARKS.md), ``sun`` (suns only) or ``all`` (every
      light; point, spot and area lights get a cube of six maps).
    - ``structure``: the acceleration structure the shadow rays walk: ``grid`` (the thesis'
      hierarchical 2D grid over per-model BVHs) or ``bvh`` (a two-level BVH: binned-SAH model
      trees under a binned-SAH tree over the instances, quantised one-texel nodes; the default,
      ``DEFAULT_STRUCTURE``: its shadow rays are faster). The masks are the same; changing it
      re-bakes the scene.
    - ``light_grid``: on the two-level BVH, a hard light's shadow rays (all on lines through
      the light: a sun's parallel, a point, spot or hard area light's meeting at its centre) look
      up a light-space grid of the casters built for that light (``core/bake/lightgrid.py``: a
      plane across a sun, a cube of directions around a local light) instead of walking the
      tree: one lookup and a short list per ray (BENCHMARKS.md). A light's grid is rebuilt when
      it moves or turns, all of them when the scene changes. Scenes with alpha-cut casters keep
      the tree.
    - ``samples``: shadow rays per pixel towards a light with a size (a sun's angle, a point or
      spot light's radius, an area light), well spread over it: the mask is the share of the
      light the pixel sees (soft shadows). A probe pass traces 1 of them per pixel first; only
      pixels within 4 pixels of a probe that saw part of the light (penumbrae) trace them all.
    - ``noise_target``: a final render's noise check (soft lights, the two-level BVH): each
      light's mask is estimated to be off from the exact shares by 0.45 x the mean difference of
      the masks of its two halves of ``samples``, each filtered; a light above this gives its
      partial pixels as many samples again (``Frame.stats["noise"]``: the estimates; ``samples``:
      the most a pixel took). 0: never. The default, 0.003, leaves room within the 0.005 that a
      mask may be off from Cycles' (BENCHMARKS.md).
    - ``hard``: every light hard (one ray to its centre, sizes ignored), as the hard Cycles
      references of ``compare`` are rendered.
    - ``accumulate`` (the viewport, ``raytrace`` at ``high``): each frame traces
      ``frame_samples`` rays per pixel towards each soft light and adds their sums to those of
      the frames before, until ``samples`` are reached; the first frame after a change probes
      every pixel as a final render does and gives the penumbrae four times ``frame_samples``. The
      mask is filtered within its penumbrae, the more the fewer its samples. Any change
      (``Pipeline.reset_history``) starts afresh.
    - ``transparency_samples``: sub-frames averaged where the camera sees see-through surfaces
      (blended materials with an alpha between 0 and 1: ``core/gpu/see_through.py``), each
      keeping such a surface where its alpha exceeds a hashed threshold, so the image and the
      masks converge to alpha x the surface + (1 - alpha) x what lies behind it, as in Cycles.
      A final render renders them all; ``accumulate`` (the viewport) one per frame. 1: one
      frame, such a surface shown where its alpha is at least 0.5. A scene without them renders
      one frame.
    """

    mode: str = setting(
        "raytrace", "Shadow Mode", "How shadows are made: ray traced, shadow maps or none",
        choices=(Choice("raytrace", "Ray Traced", "Shadow rays through the baked scene: soft shadows from the "
                        "lights' sizes (Soft Shadows on), else one ray per pixel towards each light's centre",
                        "SHADING_RENDERED"),
                 Choice("shadowmap", "Shadow Map", "Rasterised shadow maps filtered with PCF, softened by the "
                        "lights' sizes (PCSS) with Soft Shadows on (fast, may alias or leak)", "LIGHT_SUN"),
                 Choice("none", "None", "No shadows: every light reaches every surface", "LIGHT")),
        blender={"redraw": True})
    quality: str = setting(
        "high", "Quality", "Resolution of the ray-traced shadow masks in final renders",
        choices=(Choice("high", "High", "Shadow rays at every pixel, for each light"),
                 Choice("medium", "Medium", "Ray-traced: rays at every 2nd pixel per side, and a ray of its own "
                        "for each pixel they cannot stand for (shadow edges, creases, thin or grazing surfaces): "
                        "nearly High's masks. On a software rasteriser it costs more than High. Shadow maps: "
                        "half-resolution masks"),
                 Choice("low", "Low", "Ray-traced: rays at every 4th pixel per side, refined as Medium. On a "
                        "software rasteriser it costs more than High. Shadow maps: quarter-resolution masks")),
        blender={"redraw": True})
    max_distance: float = setting(
        0.0, "Max Distance", "Shadows only within this distance of the camera, in metres (0 = no limit)",
        low=0.0, soft_max=1000.0, blender={"redraw": True, "subtype": "DISTANCE", "unit": "LENGTH"},
        metavar="M")
    max_shadowed_lights: int | None = setting(
        None, "Max Shadowed Lights", "Shadow only the N nearest shadow-casting lights, suns first (0 in "
        "Blender: every one)", low=0, soft_max=64, optional=True,
        blender={"redraw": False}, metavar="N")
    interlace: bool = setting(
        False, "Interlacing", "Trace a quarter of the shadow rays per frame and keep the rest from the frames "
        "before; after a change the pixels without an up-to-date ray are refined, and a still view is exact "
        "after four frames (the viewport's Interlacing)", cli=None)
    shadowmap_size: int = setting(
        2048, "Shadow Map Resolution", "Texels per side of each shadow map (cube face for point lights)",
        low=16, high=16384, blender={"redraw": True, "choices": (512, 1024, 2048, 4096, 8192)}, metavar="N")
    pcf: int = setting(
        1, "PCF Radius", "Shadow-map filter kernel radius in texels (0 = one tap, hard and aliased)",
        low=0, high=8, blender={"redraw": True}, metavar="N")
    shadow_bias: float = setting(
        1.0, "Bias", "Constant shadow-map depth bias in texels", low=0.0, soft_max=10.0,
        blender={"redraw": True}, metavar="TEXELS")
    slope_bias: float = setting(
        2.0, "Slope Bias", "Slope-scaled shadow-map depth bias", low=0.0, soft_max=10.0, blender={"redraw": True},
        metavar="K")
    normal_offset: float = setting(
        1.5, "Normal Offset", "Offset of the receiver along its normal, in shadow-map texels", low=0.0,
        soft_max=10.0, blender={"redraw": True}, metavar="TEXELS")
    pcss_samples: int = setting(
        32, "Soft Filter Taps", "Shadow maps of lights with a size: percentage-closer soft shadow filter taps "
        "(the blocker search takes half as many)", low=1, high=1024, soft_max=128, blender={"redraw": False},
        metavar="N")
    upsample: str = setting(
        "bilateral", "Upsampling", "How reduced-resolution shadow masks are brought to full resolution",
        choices=(Choice("bilateral", "Bilateral", "Depth and normal aware upsampling of reduced-resolution masks"),
                 Choice("nearest", "Nearest", "Blocky nearest-texel upsampling (the thesis' look)")),
        blender={"redraw": True})
    specular: bool = setting(
        True, "Specular", "Add the specular lobe of the materials to the lighting",
        blender={"name": "use_specular", "redraw": True}, cli="--no-specular")
    conservative: str = setting(
        "off", "Conservative Maps", "Ray traced: skip or shorten shadow rays with conservative light-space "
        "occupancy maps; exact, it only changes the work",
        choices=(Choice("off", "Off", "Trace every shadow ray in full"),
                 Choice("sun", "Suns", "Conservative occupancy maps for suns: receivers no caster can reach take no "
                        "ray, the others stop at the first possible caster (the masks do not change)"),
                 Choice("all", "All Lights", "Conservative occupancy maps for every light (a cube of six maps "
                        "around point, spot and area lights)")),
        blender={"name": "conservative_maps", "redraw": True}, cli="--conservative-maps")
    structure: str = setting(
        DEFAULT_STRUCTURE, "Structure", "Ray traced: acceleration structure the shadow rays walk (the masks are "
        "the same; changing it re-bakes the scene)",
        choices=tuple(Choice(name, cls.label, cls.description) for name, cls in STRUCTURE_CLASSES.items()),
        blender={"redraw": True})
    light_grid: bool = setting(
        True, "Light Grids", "Ray traced, BVH: a hard light's shadow rays look up a grid of the casters laid out "
        "around that light instead of walking the tree (faster; rebuilt when the light moves; scenes with "
        "alpha-cut casters keep the tree)", blender={"name": "use_light_grid", "redraw": True},
        cli="--no-light-grids")
    samples: int = setting(
        64, "Shadow Samples", "Final render: shadow rays per pixel towards each light with a size (pixels away "
        "from any penumbra take 1)", low=1, high=4096, soft_max=256, blender={"redraw": False}, metavar="N")
    noise_target: float = setting(
        0.003, "Noise Target", "Final render: a light whose shadow mask's noise is estimated above this (mean "
        "error of its shares) gives its penumbrae as many samples again (0: never)", low=0.0, soft_max=0.02,
        blender={"redraw": False, "precision": 4, "step": 0.01}, metavar="E")
    hard: bool = setting(
        False, "Hard Shadows", "Every light hard: one ray to its centre, sizes ignored (as compare's references)",
        blender={"name": "use_soft_shadows", "invert": True, "label": "Soft Shadows", "redraw": False,
                 "help": "Honour the lights' sizes (sun angle, point and spot radius, area light size) with "
                         "several shadow rays per pixel; off: every light is hard, one ray to its centre"})
    accumulate: bool = setting(
        False, "Accumulate", "Each frame adds its soft samples to those of the frames before (the viewport)",
        cli=None)
    frame_samples: int = setting(
        4, "Samples per Frame", "Accumulating: shadow rays per pixel and soft light each frame adds",
        low=1, high=4096, cli=None)
    transparency_samples: int = setting(
        16, "See-Through Samples", "Where the camera sees see-through surfaces (blended materials with an alpha "
        "between 0 and 1): frames of stochastic transparency averaged, so that each shows alpha x itself + "
        "(1 - alpha) x what lies behind, as in Cycles. A final render renders them all, a still viewport one per "
        "redraw; scenes without such surfaces render one frame. 1: a surface shows where its alpha is at least "
        "0.5", low=1, high=4096, soft_max=64, blender={"redraw": False}, metavar="N")
    trace_path: str = setting(
        "auto", "Trace Path", "Ray traced: how the hard shadow masks are traced (the masks are the same)",
        choices=(Choice("auto", "Automatic", "Compute shaders where the GPU offers OpenGL 4.3, fragment shaders "
                        "elsewhere"),
                 Choice("compute", "Compute", "Compute shaders over compact queues of the shadow rays: the time "
                        "follows the rays traced (OpenGL 4.3)"),
                 Choice("fragment", "Fragment", "Full-screen fragment shaders, one ray per pixel (what OpenGL "
                        "4.1, macOS, offers)")),
        blender={"redraw": True})

    def __post_init__(self):
        self.validate()

    # -- derived -------------------------------------------------------------------------------
    @property
    def mask_scale(self) -> int:
        """Divisor of the full resolution for the shadow masks: 1, 2 or 4."""
        return QUALITY_SCALE[self.quality]

    def mask_size(self, width: int, height: int) -> tuple[int, int]:
        s = self.mask_scale
        return max(1, -(-int(width) // s)), max(1, -(-int(height) // s))

    def replace(self, **changes) -> Settings:
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Settings:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown setting(s): {', '.join(unknown)} (known: {', '.join(sorted(names))})")
        return cls(**d)

    # -- validation ------------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise ``ValueError`` naming the first field out of its declared choices or range."""
        for f in fields(self):
            check(f, getattr(self, f.name))


def _integer(v, name, low=None, high=None):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise ValueError(f"{name} must be an integer, not {v!r}")
    if (low is not None and v < low) or (high is not None and v > high):
        rng = f"at least {low}" if high is None else f"between {low} and {high}"
        raise ValueError(f"{name} must be {rng}, not {v}")


def _number(v, name, low=None):
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number, not {v!r}")
    if low is not None and v < low:
        raise ValueError(f"{name} must be at least {low}, not {v}")


#: each setting's field (its declaration: :func:`setting`), by name
FIELDS = {f.name: f for f in fields(Settings)}


def option_name(f) -> str | None:
    """The command line's option of setting field ``f`` (None: none)."""
    cli = f.metadata["cli"]
    if cli is None or cli:
        return cli
    name = f.name.replace("_", "-")
    return f"--no-{name}" if kind(f) == "bool" and f.default else f"--{name}"


def add_arguments(parser) -> list[str]:
    """An option on ``parser`` for each setting declared with one (:func:`setting`): its help,
    choices and range from the declaration, its default left to :class:`Settings` (None). The
    names of the settings added."""
    names = []
    for f in FIELDS.values():
        opt = option_name(f)
        if opt is None:
            continue
        m = f.metadata
        text = m["help"].replace("%", "%%")
        if kind(f) == "bool":
            off = opt.startswith("--no-")
            parser.add_argument(opt, dest=f.name, action="store_const", const=not off, default=None,
                                help=f"{text} (on unless this is given)" if off else text)
        else:
            values = tuple(c.value for c in m["choices"])
            default = "all" if f.default is None else f.default
            parser.add_argument(opt, dest=f.name, type=type(f.default) if f.default is not None else int,
                                choices=values or None, default=None, metavar=None if values else m["metavar"],
                                help=f"{text} (default: {default})")
        names.append(f.name)
    return names


def from_arguments(args, names, **fixed) -> Settings:
    """The :class:`Settings` of parsed command-line ``args``: the settings ``names``
    (:func:`add_arguments`) that were given, ``fixed`` ones, defaults for the rest; a value out
    of range raises ``ValueError`` naming the setting."""
    given = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    return Settings(**given, **fixed)
