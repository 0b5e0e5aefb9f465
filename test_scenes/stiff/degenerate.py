"""Degenerate meshes: zero-area triangles (collinear and all-in-one-point), duplicate (unwelded)
vertices, coincident faces, non-manifold edges (three quads sharing an edge); a sun and a point
light. 200x150."""
import os
import runpy

import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_degenerate", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 12.0, materials=[grey]))

# unwelded box: every face has its own 4 vertices (duplicates), plus zero-area triangles along
# its edges and at a corner
c = np.array([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (-1, -1, 2), (1, -1, 2), (1, 1, 2), (-1, 1, 2)],
             float) * 0.6
faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
verts, loops, sizes = [], [], []
for f in faces:
    loops += list(range(len(verts), len(verts) + 4))
    verts += [c[i] for i in f]
    sizes.append(4)
mid = (c[4] + c[5]) / 2
k = len(verts)
verts += [c[4], mid, c[5], c[6], c[6], c[6]]            # collinear triangle; triangle in one point
loops += [k, k + 1, k + 2, k + 3, k + 4, k + 5]
sizes += [3, 3]
L["add_object"]("Unwelded", L["mesh"]("Unwelded", verts, loops, sizes, materials=[grey]), location=(-1.5, 0.5, 0))

# coincident faces: a slab whose top is doubled, and two identical overlapping boxes
slab = L["box"]("Slab", (1.6, 1.0, 0.1), materials=[grey])
L["add_object"]("Slab", slab, location=(1.5, 1.5, 1.2))
top = L["mesh"]("Slab top", [(-0.8, -0.5, 0.05), (0.8, -0.5, 0.05), (0.8, 0.5, 0.05), (-0.8, 0.5, 0.05)],
                [[0, 1, 2, 3], [0, 1, 2, 3], [3, 2, 1, 0]], materials=[grey])
L["add_object"]("Slab top", top, location=(1.5, 1.5, 1.2))
twin = L["box"]("Twin", (0.8, 0.8, 0.8), base_at_origin=True, materials=[grey])
L["add_object"]("Twin A", twin, location=(2, -2, 0), rotation=(0, 0, 0.3))
L["add_object"]("Twin B", twin, location=(2, -2, 0), rotation=(0, 0, 0.3))

# non-manifold: three quads sharing one edge (a 'book'), and a fin on a box edge
book = L["mesh"]("Book", [(0, -0.6, 0.3), (0, 0.6, 0.3), (0, 0.6, 1.5), (0, -0.6, 1.5), (0.9, 0.6, 0.6),
                          (0.9, -0.6, 0.6), (-0.9, 0.6, 0.6), (-0.9, -0.6, 0.6)],
                 [0, 1, 2, 3, 0, 1, 4, 5, 0, 1, 6, 7], [4, 4, 4], materials=[grey])
L["add_object"]("Book", book, location=(-1.5, -2.2, 0))
L["sun0"]("Sun", 45, 60)
L["point0"]("Point", (0.5, -0.5, 3.5), energy=800.0)
L["add_camera"](scene, (7, -7, 5.5), (0, 0, 0.6), lens=30)
