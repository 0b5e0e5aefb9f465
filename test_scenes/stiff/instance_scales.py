"""Negative, non-uniform and rotated instance scales: one asymmetric wedge mesh and one sphere
mesh shared by many objects with mirrored (det < 0), squashed and rotated transforms; a sun and
a point light. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_instance_scales", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[grey]))
wedge = L["mesh"]("Wedge", [(0, 0, 0), (1, 0, 0), (1, 0.6, 0), (0, 0.6, 0), (0, 0, 0.9), (0, 0.6, 0.9)],
                  [0, 3, 2, 1, 0, 1, 4, 3, 5, 2, 1, 2, 5, 4, 0, 4, 5, 3], [4, 3, 3, 4, 4], materials=[grey])
ball = L["uv_sphere"]("Ball", 0.5, 16, 8, materials=[grey])
cases = [
    (wedge, (-3, -3, 0.0), (0, 0, 0), (1, 1, 1)),
    (wedge, (-1, -3, 0.0), (0, 0, 0), (-1, 1, 1)),          # mirrored in x
    (wedge, (1.5, -3, 0.9), (0, 0, 0.5), (1, 1, -1)),       # mirrored in z (upside down)
    (wedge, (3, -2, 0.0), (0, 0, 1.0), (2.5, 0.4, 1.3)),    # non-uniform
    (wedge, (-3, 0, 0.5), (0.7, 0.2, 0.3), (-0.8, 1.6, -1.2)),  # negative non-uniform rotated
    (wedge, (0, 0, 0.3), (0.3, -0.4, 2.0), (1.5, -1, 0.7)),
    (ball, (2.5, 1, 0.6), (0, 0, 0), (-1, 1, 1)),
    (ball, (-1, 2.5, 0.3), (0.4, 0.2, 0.9), (2.4, 0.7, 0.6)),   # ellipsoid, rotated
    (ball, (1, 3, 0.8), (1.0, 0.0, 0.5), (-0.4, -1.8, 0.5)),
    (ball, (3, 3.5, 0.02), (0, 0, 0), (3.0, 3.0, 0.02)),     # pancake 4 cm thick
]
for i, (m, loc, rot, s) in enumerate(cases):
    L["add_object"](f"Inst{i}", m, location=loc, rotation=rot, scale=s)
L["sun0"]("Sun", 40, 60)
L["point0"]("Point", (0.5, -1.0, 3.0), energy=800.0)
L["add_camera"](scene, (8, -8, 6), (0, 0, 0.3), lens=30)
