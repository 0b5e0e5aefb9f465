"""Helpers shared by the stiff scene scripts (hidden from the scene list by the leading ``_``).

``lib()`` returns ``test_scenes/_lib.py``'s builders plus:

- ``exact_light``: a light whose world matrix is an exact permutation/rotation (light directions
  with components exactly 0), through a parent empty and ``matrix_parent_inverse``;
- ``sun0`` / ``point0`` / ``spot0``: lights with a zero radius / angle (hard shadows, so one
  Cycles sample per pixel is an exact visibility reference);
- ``resolution(PARAMS)``: the small default size of the stiff scenes (200x150).
"""
import math
import os
import runpy

import bpy
from mathutils import Matrix

_HERE = os.path.dirname(os.path.abspath(__file__))


def lib():
    L = runpy.run_path(os.path.join(_HERE, "..", "_lib.py"))

    def resolution(params, default=(200, 150)):
        return int(params.get("width", default[0])), int(params.get("height", default[1]))

    def sun0(name, elevation, azimuth, energy=5.0):
        return L["add_sun"](name, elevation=elevation, azimuth=azimuth, energy=energy, angle=0.0)

    def point0(name, location, energy=500.0):
        return L["add_light"](name, "POINT", location=location, energy=energy, shadow_soft_size=0.0)

    def spot0(name, location, target, energy=1000.0, spot_size=math.radians(60), spot_blend=0.1):
        return L["add_light"](name, "SPOT", location=location, target=target, energy=energy,
                              shadow_soft_size=0.0, spot_size=spot_size, spot_blend=spot_blend)

    def exact_light(name, kind, rotation3x3, parent_euler=(0.0, 0.0, 0.0), location=(0, 0, 0), energy=5.0, **props):
        """``rotation3x3``: rows of an exact (0/±1) rotation; the light shines along its -Z
        column, then rotated by the parent's Euler angles (zeros stay exactly zero)."""
        light = bpy.data.lights.new(name, kind)
        light.energy = energy
        for k, v in props.items():
            setattr(light, k, v)
        if kind == "SUN":
            light.angle = 0.0
        else:
            light.shadow_soft_size = 0.0
        parent = bpy.data.objects.new(name + " frame", None)
        bpy.context.scene.collection.objects.link(parent)
        parent.rotation_euler = parent_euler
        parent.location = location
        ob = bpy.data.objects.new(name, light)
        bpy.context.scene.collection.objects.link(ob)
        ob.parent = parent
        m = Matrix.Identity(4)
        for i in range(3):
            for j in range(3):
                m[i][j] = rotation3x3[i][j]
        ob.matrix_parent_inverse = m
        return ob

    L.update(resolution=resolution, sun0=sun0, point0=point0, spot0=spot0, exact_light=exact_light)
    return L
