"""Light and shadow linking (Blender 4.0+): each light's ``light_linking.receiver_collection``
and ``blocker_collection`` as the scene model's light and shadow sets
(:mod:`hybrid_shadow_addon.core.scene.linking`).

A collection lists objects and child collections, each with a link state (Include or Exclude;
a child collection's state holds for every object in it). As Blender's light linking reads it:
where the collection includes something, only what it includes is lit (casts); where it only
excludes, everything but what it excludes. An object both included and excluded is included.
Each distinct collection is one set; past :data:`MAX_SETS` of a kind the further lights are
exported unlinked, and the export says so. An instance belongs to the sets of the object it
instances (a realised geometry-nodes mesh: of its object).
"""
from __future__ import annotations

import bpy
import numpy as np

from ...core.scene.instances import ALL_SETS
from ...core.scene.linking import MAX_SETS, set_bits
from .common import warn_export


def collection_states(coll) -> dict:
    """``{object name: included}`` of every object a linking collection lists, directly or
    through its child collections."""
    out: dict = {}
    for ob, entry in zip(coll.objects, coll.collection_objects):
        out[ob.name] = out.get(ob.name, False) or entry.light_linking.link_state == "INCLUDE"
    for child, entry in zip(coll.children, coll.collection_children):
        included = entry.light_linking.link_state == "INCLUDE"
        for ob in child.all_objects:
            out[ob.name] = out.get(ob.name, False) or included
    return out


class _Sets:
    """The distinct collections of one kind (receiver or blocker), each a set index."""

    def __init__(self, kind: str):
        self.kind = kind
        self.index: dict = {}  # collection pointer -> set index
        self.states: list = []  # per set: ({object name: included}, includes anything)

    def of(self, coll, light_name: str) -> int:
        if coll is None:
            return -1
        key = coll.original.as_pointer() if getattr(coll, "original", None) is not None else coll.as_pointer()
        s = self.index.get(key)
        if s is None:
            if len(self.states) >= MAX_SETS:
                warn_export(f"light '{light_name}': its {self.kind} collection '{coll.name}' is past the "
                            f"{MAX_SETS} {self.kind} collections a scene may link; the light is not linked by it")
                return -1
            states = collection_states(coll)
            s = self.index[key] = len(self.states)
            self.states.append((states, any(states.values())))
        return s

    def bits(self, names: list) -> np.ndarray:
        """(N,) uint64 membership of the objects ``names``."""
        out = np.full(len(names), ALL_SETS, np.uint64)
        if not self.states:
            return out
        unique = {n: None for n in names}
        for name in unique:
            b = np.uint64(0)
            for s, (states, includes) in enumerate(self.states):
                if states.get(name, not includes):
                    b |= set_bits(s)
            unique[name] = b
        return np.fromiter((unique[n] for n in names), np.uint64, len(names))


def _light_object(name: str):
    """The light object a scene-model light named ``name`` comes from (``parent/light`` for an
    instanced one)."""
    ob = bpy.data.objects.get(name)
    if ob is None and "/" in name:
        ob = bpy.data.objects.get(name.rsplit("/", 1)[-1])
    return ob if ob is not None and ob.type == "LIGHT" else None


def apply_linking(lights: list, instances, sources: list) -> None:
    """Give ``lights`` their receiver and blocker sets and ``instances`` (whose rows come from the
    objects named ``sources``) their memberships, in place. Without linking nothing changes."""
    receivers, blockers = _Sets("receiver"), _Sets("blocker")
    for light in lights:
        ob = _light_object(light.name)
        ll = getattr(ob, "light_linking", None) if ob is not None else None
        if ll is None:
            continue
        light.receiver_set = receivers.of(ll.receiver_collection, light.name)
        light.blocker_set = blockers.of(ll.blocker_collection, light.name)
    if receivers.states or blockers.states:
        instances.light_sets = receivers.bits(sources)
        instances.shadow_sets = blockers.bits(sources)
