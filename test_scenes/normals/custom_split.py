"""Custom normals set with ``Mesh.normals_split_custom_set``: a slab whose normals fan out from a
point under it (up to 65° from their faces, as "pillow" normals on foliage or bevels), a column
whose normals are turned 70° about its axis, a sphere whose normals on one half point against its
winding, and a curved open wall whose normals all do; a sun 25° high and a spot; 320x240.

Shading normals far from, or against, the geometric normal: Cycles decides facing, the shadow
ray's origin and its self-hit from them (the back-facing flip), not from the winding.
"""
import math
import os
import runpy

import bmesh
import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_normals.py"))["lib"]()
scene, grey = L["stage"]("normals_custom_split", PARAMS)
add, mesh, custom = L["add_object"], L["from_bmesh"], L["set_custom_normals"]


def twist(angle):
    c, s = math.cos(angle), math.sin(angle)

    def fn(p, n):
        return np.stack([c * n[:, 0] - s * n[:, 1], s * n[:, 0] + c * n[:, 1], n[:, 2]], axis=1)
    return fn


def open_wall(bm, radius=1.3, height=1.6, segments=10, arc=math.pi):
    a = np.linspace(0.0, arc, segments + 1)
    lo = [bm.verts.new((radius * math.cos(t), radius * math.sin(t), 0.0)) for t in a]
    hi = [bm.verts.new((radius * math.cos(t), radius * math.sin(t), height)) for t in a]
    for i in range(segments):
        bm.faces.new((lo[i], lo[i + 1], hi[i + 1], hi[i]))  # winding: normals point outwards


pillow = mesh("Pillow", lambda bm: L["slab"](bm, (3.0, 2.4, 0.5), cuts=3), grey)
custom(pillow, lambda p, n: p - np.array([0.0, 0.0, -0.2]))
add("Pillow", pillow, location=(-2.4, 1.2, 0.0), rotation=(0, 0, 0.3))

column = mesh("Column", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=8, radius1=0.55, radius2=0.55, depth=2.2), grey)
custom(column, twist(math.radians(70)))
add("Column", column, location=(1.2, 2.2, 1.1))

half = mesh("Half inverted", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=10, v_segments=8, radius=0.9), grey)
custom(half, lambda p, n: np.where((p[:, 0] > 0.0)[:, None], -n, n))
add("Half inverted", half, location=(-0.6, -1.4, 0.9), rotation=(0, 0, 0.8))

wall = mesh("Inverted wall", open_wall, grey)
custom(wall, lambda p, n: -n)
add("Inverted wall", wall, location=(2.4, -1.2, 0.0), rotation=(0, 0, math.radians(-60)))

L["add_sun"]("Sun", elevation=25, azimuth=200, energy=4.0)
L["add_light"]("Spot", "SPOT", location=(3.5, -4.5, 3.5), target=(0.0, 0.5, 0.5), energy=1500.0,
               spot_size=math.radians(75), spot_blend=0.1)
L["add_camera"](scene, (8, -9, 6), (0, 0, 0.6), lens=35)
