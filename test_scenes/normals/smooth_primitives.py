"""Smooth-shaded low-poly primitives at grazing light: an 8-segment UV sphere, 8-sided cylinder and
cone, a level-1 icosphere, a 12x6 torus and a 6-sided prism lying on its side, under a sun 5°
above the horizon and a point light 0.6 m above the ground; 320x240.

The terminators fall across big smooth-shaded facets: where the shading normal faces the light and
the facet does not, Cycles lights (and offsets the shadow ray of) what flat geometry would call
shadowed.
"""
import math
import os
import runpy

import bmesh

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_normals.py"))["lib"]()
scene, grey = L["stage"]("normals_smooth_primitives", PARAMS)
add, mesh = L["add_object"], L["from_bmesh"]

add("Sphere", mesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=8, v_segments=6, radius=1.0), grey),
    location=(-3.0, 1.5, 1.0))
add("Cylinder", mesh("Cylinder", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=8, radius1=0.6, radius2=0.6, depth=2.0), grey), location=(0.0, 2.5, 1.0))
add("Cone", mesh("Cone", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=8, radius1=0.8, radius2=0.0, depth=1.6), grey), location=(2.6, 1.2, 0.8))
add("Ico", mesh("Ico", lambda bm: bmesh.ops.create_icosphere(bm, subdivisions=1, radius=0.8), grey),
    location=(-0.6, -0.4, 0.8))
add("Torus", mesh("Torus", lambda bm: L["torus"](bm, 0.9, 0.3, 12, 6), grey), location=(-2.6, -2.0, 0.3))
add("Prism", mesh("Prism", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=6, radius1=0.5, radius2=0.5, depth=2.4), grey),
    location=(1.8, -1.8, 0.45), rotation=(0.0, math.radians(90), math.radians(30)))

L["add_sun"]("Sun", elevation=float(PARAMS.get("elevation", 5.0)), azimuth=35, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(0.9, 0.3, 0.6), energy=300.0)
L["add_camera"](scene, (8, -9, 5.5), (0, 0, 0.6), lens=35)
