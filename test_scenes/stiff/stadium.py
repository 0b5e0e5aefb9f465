"""Teapot in a stadium: a 5 km ground, a 20 x 20 x 200 m tower and, 150 m away, 1 cm cubes and
a 3 cm 'teapot' seen from 30 cm; the tower's shadow edge crosses the little scene. A second,
close point light. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_stadium", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 5000.0, materials=[grey]))
L["add_object"]("Tower", L["box"]("Tower", (20, 20, 200), base_at_origin=True, materials=[grey]))
C = (150.0, 10.0)   # the tower's shadow (sun from -X) has its side edge along y = 10
cube = L["box"]("Cube 1cm", (0.01, 0.01, 0.01), base_at_origin=True, materials=[grey])
for i, (dx, dy, rz) in enumerate([(-0.06, -0.03, 0.0), (-0.03, 0.02, 0.3), (0.0, -0.05, 0.7), (0.03, 0.04, 1.1),
                                  (0.06, -0.01, 0.2), (-0.08, 0.05, 0.9), (0.08, 0.06, 0.5), (0.01, 0.08, 0.0)]):
    L["add_object"](f"Cube{i}", cube, location=(C[0] + dx, C[1] + dy, 0), rotation=(0, 0, rz))
L["add_object"]("Teapot", L["uv_sphere"]("Teapot", 0.015, 16, 8, materials=[grey]), location=(C[0], C[1] + 0.01, 0.015))
L["add_object"]("Spout", L["box"]("Spout", (0.025, 0.006, 0.006), materials=[grey]),
                location=(C[0] + 0.02, C[1] + 0.01, 0.018), rotation=(0, -0.6, 0))
L["add_object"]("Lid", L["box"]("Lid", (0.012, 0.012, 0.006), base_at_origin=True, materials=[grey]),
                location=(C[0], C[1] + 0.01, 0.029))
L["sun0"]("Sun", 35, 180)
L["point0"]("Lamp", (C[0] - 0.1, C[1] - 0.12, 0.12), energy=2.0)
L["add_camera"](scene, (C[0] - 0.22, C[1] - 0.2, 0.14), (C[0], C[1], 0.0), lens=30, clip=(0.001, 10000.0))
