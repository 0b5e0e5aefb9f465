"""A point light inside a closed box (a room seen from inside, with a table, a pillar and a
ball), and a sun outside: the sun must not leak in anywhere. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_point_in_box", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Room", L["box"]("Room", (6, 5, 3), base_at_origin=True, materials=[grey]))
L["add_object"]("Table", L["box"]("Table", (1.4, 0.8, 0.06), materials=[grey]), location=(-0.5, 0.5, 0.8))
leg = L["box"]("Leg", (0.06, 0.06, 0.77), base_at_origin=True, materials=[grey])
for i, (x, y) in enumerate([(-1.15, 0.15), (0.15, 0.15), (-1.15, 0.85), (0.15, 0.85)]):
    L["add_object"](f"Leg{i}", leg, location=(x, y, 0))
L["add_object"]("Pillar", L["box"]("Pillar", (0.4, 0.4, 3), base_at_origin=True, materials=[grey]),
                location=(-1.8, -1.2, 0))
L["add_object"]("Ball", L["uv_sphere"]("Ball", 0.35, 16, 8, materials=[grey]), location=(1.0, 1.2, 0.35))
L["point0"]("Bulb", (0.2, 0.1, 2.2), energy=300.0)
L["sun0"]("Sun", 40, 200)
L["add_camera"](scene, (2.8, -2.3, 2.5), (-0.6, 0.6, 0.6), lens=18, clip=(0.05, 100.0))
