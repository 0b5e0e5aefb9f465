"""Light and shadow linking as Cycles applies it (Blender 4.0+), over the scene model.

Each distinct receiver collection of the lights is a light set, each distinct blocker collection
a shadow set (``Light.receiver_set`` / ``blocker_set``, at most :data:`MAX_SETS` of each); an
instance holds a bit per set (``Instances.light_sets`` / ``shadow_sets``): a light with a receiver
set lights only the instances with its bit, one with a blocker set is shadowed only by the
instances with its bit. A light without a set lights (is shadowed by) every instance.
"""
from __future__ import annotations

import numpy as np

#: sets of each kind a scene may hold (Cycles' LIGHT_LINK_SET_MAX)
MAX_SETS = 64


def set_bits(s: int) -> np.uint64:
    """The membership bit of set ``s`` (0..63)."""
    return np.uint64(1) << np.uint64(int(s))


def in_set(bits: np.ndarray, s: int) -> np.ndarray:
    """(N,) bool: which of the memberships ``bits`` (uint64) hold set ``s``; all where ``s < 0``."""
    bits = np.asarray(bits, np.uint64)
    if int(s) < 0:
        return np.ones(bits.shape, bool)
    return (bits & set_bits(s)) != 0


def receivers(scene, light) -> np.ndarray:
    """(N,) bool: the instances ``light`` (a :class:`Light` or its index) lights."""
    light = scene.lights[light] if isinstance(light, (int, np.integer)) else light
    return in_set(scene.instances.light_sets, light.receiver_set)


def blockers(scene, light) -> np.ndarray:
    """(N,) bool: the shadow-casting instances that may block ``light``'s rays (its blocker
    collection's, or every caster)."""
    light = scene.lights[light] if isinstance(light, (int, np.integer)) else light
    inst = scene.instances
    return np.asarray(inst.casts_shadow, bool) & in_set(inst.shadow_sets, light.blocker_set)


def uses_linking(scene) -> bool:
    """Whether some light of ``scene`` has a receiver or blocker set."""
    return any(light.receiver_set >= 0 or light.blocker_set >= 0 for light in scene.lights)


def membership_words(instances) -> np.ndarray:
    """(N, 4) uint32 per instance: light-set bits low, high, shadow-set bits low, high (the
    shaders' ``hs_link_tex``, ``shaders/common/linking.glsl``)."""
    ls = np.asarray(instances.light_sets, np.uint64)
    ss = np.asarray(instances.shadow_sets, np.uint64)
    lo = np.uint64(0xFFFFFFFF)
    return np.stack([ls & lo, ls >> np.uint64(32), ss & lo, ss >> np.uint64(32)], axis=1).astype(np.uint32)
