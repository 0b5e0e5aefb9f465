"""Render settings: the one value object the CLI, Blender properties and benchmarks all build."""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace

from .bake.structures import DEFAULT_STRUCTURE
from .bake.structures import STRUCTURES as STRUCTURE_CLASSES

MODES = ("raytrace", "shadowmap", "none")
QUALITIES = ("high", "medium", "low")
QUALITY_SCALE = {"high": 1, "medium": 2, "low": 4}  # mask resolution = full / scale
UPSAMPLE_FILTERS = ("bilateral", "nearest")
CONSERVATIVE_MAPS = ("off", "sun", "all")
STRUCTURES = tuple(STRUCTURE_CLASSES)  # acceleration structures the bake can build
TRACE_PATHS = ("auto", "compute", "fragment")


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

    mode: str = "raytrace"
    quality: str = "high"
    max_distance: float = 0.0
    max_shadowed_lights: int | None = None
    interlace: bool = False
    shadowmap_size: int = 2048
    pcf: int = 1
    shadow_bias: float = 1.0
    slope_bias: float = 2.0
    normal_offset: float = 1.5
    pcss_samples: int = 32
    upsample: str = "bilateral"
    specular: bool = True
    conservative: str = "off"
    structure: str = DEFAULT_STRUCTURE
    light_grid: bool = True
    samples: int = 64
    noise_target: float = 0.003
    hard: bool = False
    accumulate: bool = False
    frame_samples: int = 4
    transparency_samples: int = 16
    trace_path: str = "auto"

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
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, not {self.mode!r}")
        if self.quality not in QUALITIES:
            raise ValueError(f"quality must be one of {', '.join(QUALITIES)}, not {self.quality!r}")
        if self.conservative not in CONSERVATIVE_MAPS:
            raise ValueError(f"conservative must be one of {', '.join(CONSERVATIVE_MAPS)}, not {self.conservative!r}")
        if self.structure not in STRUCTURES:
            raise ValueError(f"structure must be one of {', '.join(STRUCTURES)}, not {self.structure!r}")
        if self.trace_path not in TRACE_PATHS:
            raise ValueError(f"trace_path must be one of {', '.join(TRACE_PATHS)}, not {self.trace_path!r}")
        if self.upsample not in UPSAMPLE_FILTERS:
            raise ValueError(f"upsample must be one of {', '.join(UPSAMPLE_FILTERS)}, not {self.upsample!r}")
        _number(self.max_distance, "max_distance", low=0.0)
        if self.max_shadowed_lights is not None:
            _integer(self.max_shadowed_lights, "max_shadowed_lights (or None for all)", low=0)
        if not isinstance(self.interlace, bool):
            raise ValueError(f"interlace must be True or False, not {self.interlace!r}")
        if not isinstance(self.light_grid, bool):
            raise ValueError(f"light_grid must be True or False, not {self.light_grid!r}")
        if not isinstance(self.hard, bool):
            raise ValueError(f"hard must be True or False, not {self.hard!r}")
        _integer(self.samples, "samples", low=1, high=4096)
        _number(self.noise_target, "noise_target", low=0.0)
        _integer(self.frame_samples, "frame_samples", low=1, high=4096)
        _integer(self.transparency_samples, "transparency_samples", low=1, high=4096)
        if not isinstance(self.accumulate, bool):
            raise ValueError(f"accumulate must be True or False, not {self.accumulate!r}")
        if not isinstance(self.specular, bool):
            raise ValueError(f"specular must be True or False, not {self.specular!r}")
        _integer(self.shadowmap_size, "shadowmap_size", low=16, high=16384)
        _integer(self.pcf, "pcf", low=0, high=8)
        _number(self.shadow_bias, "shadow_bias", low=0.0)
        _number(self.slope_bias, "slope_bias", low=0.0)
        _number(self.normal_offset, "normal_offset", low=0.0)
        _integer(self.pcss_samples, "pcss_samples", low=1, high=1024)


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
