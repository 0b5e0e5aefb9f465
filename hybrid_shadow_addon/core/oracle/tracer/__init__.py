"""Reference shadow-ray tracers in numpy: the oracle for the GLSL tracer.

- :mod:`.primitives`: the float32 ray, triangle, sphere and box tests every walk shares.
- :mod:`.grid`: the hierarchical grid walk of ``scene_grid.glsl`` over a grid bake's textures.
- :mod:`.twolevel`: the two-level BVH walk of ``scene_bvh.glsl`` over a BVH bake's textures.
- :mod:`.brute`: every caster of a :class:`Scene` (occlusion, and visibility through alpha).
- :mod:`.lightgrid`: a hard light's light-space grid walk.

Ray convention: ``origins`` (N,3), ``dirs`` (N,3) world space (not necessarily unit), ``tmax``
(N,) or scalar in units of |dir| (may be inf). Occluded when any caster is hit at t in (0, tmax).
Rays are transformed per instance with the inverse world matrix, the direction is not normalised.
A zero direction, tmax <= 0 or NaN input gives "not occluded".
"""
from __future__ import annotations

import numpy as np

from ...bake.textures import BVH_TEXELS, FLT_BIG, MODEL_TEXELS, OBJECT_TEXELS, SPHERE_FLAG, TRI_TEXELS, f32_up
from .brute import trace_brute, visibility_brute
from .grid import BIG, EPS16, OBVH_EPS, trace_grid
from .lightgrid import instance_sphere_hit, light_grid_place, trace_light_grid
from .primitives import (
    PRETEST_EPS,
    SLAB_BIG,
    TFAR_SCALE,
    TFLOOR,
    F,
    bake_space,
    prepare_rays,
    ragged_pairs,
    slab_hit,
    slab_inv,
    sphere_hit,
    sphere_pretest,
    transform_rays,
    woop_hit,
    woop_hit_bary,
    woop_setup,
)
from .twolevel import LEAF_FLAG, QEPS, TLAS_EPS, trace_twolevel


def trace_structured(baked, origins, dirs, tmax=np.inf, stats: dict | None = None) -> np.ndarray:
    """Occlusion of each ray through the baked textures by the numpy walk of the bake's structure
    (the oracle of its shader: :func:`trace_twolevel` or :func:`trace_grid`). ``origins`` are
    world space; they move into bake space (``baked.origin``) in float64."""
    return WALKS[baked.structure](baked, origins, dirs, tmax, stats)


#: each structure's numpy walk, by its registry name (``AccelerationStructure.name``)
WALKS = {"grid": trace_grid, "bvh": trace_twolevel}


__all__ = [
    "BIG", "BVH_TEXELS", "EPS16", "F", "FLT_BIG", "LEAF_FLAG", "MODEL_TEXELS", "OBJECT_TEXELS", "OBVH_EPS",
    "PRETEST_EPS", "QEPS", "SLAB_BIG", "SPHERE_FLAG", "TFAR_SCALE", "TFLOOR", "TLAS_EPS", "TRI_TEXELS",
    "bake_space", "f32_up", "instance_sphere_hit", "light_grid_place", "prepare_rays", "ragged_pairs", "slab_hit",
    "slab_inv", "sphere_hit", "sphere_pretest", "trace_brute", "trace_grid", "trace_light_grid", "trace_structured",
    "trace_twolevel", "transform_rays", "visibility_brute", "woop_hit", "woop_hit_bary", "woop_setup",
]
