"""Custom normals from Weighted Normal modifiers: a chamfered box (face-area weights, sharp edges
kept), a 12-sided capped cylinder (area weights at full bias), a 12x8 torus (corner-angle
weights) and a low-poly rock (an icosphere with jittered vertices, area-and-angle weights), under
a sun 12° high and a point light; 320x240.

The modifier tilts the normals of small faces towards their big neighbours: the shading normal
of a chamfer is far from its face, where Cycles decides facing with the shading normal.
"""
import os
import runpy

import bmesh
import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_normals.py"))["lib"]()
scene, grey = L["stage"]("normals_weighted", PARAMS)
add, mesh = L["add_object"], L["from_bmesh"]


def chamfered_box(bm):
    bmesh.ops.create_cube(bm, size=1.6)
    bmesh.ops.bevel(bm, geom=list(bm.edges) + list(bm.verts), offset=0.25, segments=1, affect="EDGES")


def rock(bm):
    bmesh.ops.create_icosphere(bm, subdivisions=1, radius=0.9)
    rng = np.random.default_rng(3)
    for v in bm.verts:
        v.co *= float(rng.uniform(0.75, 1.2))


def weighted(ob, mode="FACE_AREA", keep_sharp=True, weight=50):
    m = ob.modifiers.new("WeightedNormal", "WEIGHTED_NORMAL")
    m.mode, m.keep_sharp, m.weight = mode, keep_sharp, weight
    return ob


weighted(add("Box", mesh("Box", chamfered_box, grey), location=(-2.6, 1.4, 0.8), rotation=(0, 0, 0.5)))
weighted(add("Cylinder", mesh("Cylinder", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=12, radius1=0.7, radius2=0.7, depth=1.8), grey), location=(0.4, 2.2, 0.9)),
         keep_sharp=False, weight=100)
weighted(add("Torus", mesh("Torus", lambda bm: L["torus"](bm, 1.0, 0.35, 12, 8), grey), location=(-0.8, -1.2, 0.8),
             rotation=(1.1, 0.0, 0.3)), mode="CORNER_ANGLE", keep_sharp=False, weight=100)
weighted(add("Rock", mesh("Rock", rock, grey), location=(2.5, -0.4, 0.6)), mode="FACE_AREA_WITH_ANGLE", weight=80)

L["add_sun"]("Sun", elevation=12, azimuth=150, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(1.0, 0.5, 2.8), energy=500.0)
L["add_camera"](scene, (8, -9, 6), (0, 0, 0.6), lens=35)
