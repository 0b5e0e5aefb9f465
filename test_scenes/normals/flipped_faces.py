"""Flipped faces seen from both sides: a box and a smooth sphere with reversed winding (normals
inside), a smooth open shell with reversed winding seen inside and out, a sphere with every other
face reversed (inconsistent winding, its smooth normals averaged across it), two copies of a
flipped banner turned to show the camera one's front and the other's back, and a mirrored
(negative scale) smooth cylinder; a sun 20° high and a point light; 320x240.

Cycles shades the side the ray hits (it flips both normals towards the viewer): winding alone
must not decide facing or the shadow ray's origin.
"""
import math
import os
import runpy

import bmesh
import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_normals.py"))["lib"]()
scene, grey = L["stage"]("normals_flipped_faces", PARAMS)
add, mesh = L["add_object"], L["from_bmesh"]


def shell(bm, radius=1.0, height=1.4, segments=10, arc=1.4 * math.pi):
    a = np.linspace(0.0, arc, segments + 1)
    lo = [bm.verts.new((radius * math.cos(t), radius * math.sin(t), 0.0)) for t in a]
    hi = [bm.verts.new((radius * math.cos(t), radius * math.sin(t), height)) for t in a]
    for i in range(segments):
        bm.faces.new((lo[i], lo[i + 1], hi[i + 1], hi[i]))


def checker_sphere(bm):
    """A UV sphere, every other face of each ring reversed (picked by position: the operator's
    face order varies from run to run)."""
    bmesh.ops.create_uvsphere(bm, u_segments=10, v_segments=8, radius=0.8)
    bmesh.ops.triangulate(bm, faces=bm.faces, quad_method="FIXED")  # (see _normals.from_bmesh)

    def odd(f):
        c = f.calc_center_median()
        segment = math.floor(5 * math.atan2(c.y, c.x) / math.pi)
        ring = math.floor(8 * math.acos(c.z / c.length) / math.pi)
        return (segment + ring) % 2

    bmesh.ops.reverse_faces(bm, faces=[f for f in bm.faces if odd(f)])


def banner(bm):
    bmesh.ops.create_grid(bm, x_segments=4, y_segments=2, size=0.9)
    for v in bm.verts:
        v.co = (v.co.x, 0.15 * math.sin(2.5 * v.co.x), v.co.y * 0.8 + 0.75)  # upright, bent


add("Box", mesh("Box", lambda bm: bmesh.ops.create_cube(bm, size=1.2), grey, smooth=False, flip=True),
    location=(-3.0, 1.8, 0.6), rotation=(0, 0, 0.4))
add("Sphere", mesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=10, v_segments=8, radius=0.9),
                   grey, flip=True), location=(-0.4, 2.4, 0.9))
add("Shell", mesh("Shell", shell, grey, flip=True), location=(2.4, 1.0, 0.0), rotation=(0, 0, math.radians(-30)))
add("Checker", mesh("Checker", checker_sphere, grey), location=(-2.2, -1.0, 0.8))
flag = mesh("Banner", banner, grey, flip=True)
add("Banner front", flag, location=(0.2, -0.6, 0.0), rotation=(0, 0, math.radians(20)))
add("Banner back", flag, location=(0.6, -2.6, 0.0), rotation=(0, 0, math.radians(200)))
add("Mirrored", mesh("Mirrored", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=8, radius1=0.5, radius2=0.5, depth=1.6), grey),
    location=(2.8, -1.8, 0.8), scale=(-1.0, 1.0, 1.0))

L["add_sun"]("Sun", elevation=20, azimuth=120, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(0.0, 0.6, 2.6), energy=500.0)
L["add_camera"](scene, (8, -9, 6), (0, 0, 0.6), lens=35)
