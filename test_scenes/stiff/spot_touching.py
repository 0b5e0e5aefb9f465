"""Spot lights almost touching a surface: one 1 mm above the ground shining along it, one 1 mm
in front of a wall; boxes and a post in their cones. 200x150."""
import math
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()
gap = float(PARAMS.get("gap", 0.001))

scene = L["setup_scene"]("stiff_spot_touching", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["heightfield"]("Ground", 12.0, 12, lambda x, y: 0 * x, materials=[grey]))
L["add_object"]("Wall", L["mesh"]("Wall", [(-3, -4, 0), (-3, 4, 0), (-3, 4, 3), (-3, -4, 3)], [[0, 1, 2, 3]],
                                  materials=[grey]))
L["add_object"]("Box", L["box"]("Box", (0.5, 0.5, 0.5), base_at_origin=True, materials=[grey]), location=(1.5, 0.6, 0))
L["add_object"]("Post", L["box"]("Post", (0.1, 0.1, 1.2), base_at_origin=True, materials=[grey]),
                location=(0.5, -1.0, 0))
L["add_object"]("Crate", L["box"]("Crate", (0.6, 0.6, 0.6), base_at_origin=True, materials=[grey]),
                location=(-1.2, 1.5, 0), rotation=(0, 0, 0.4))
L["spot0"]("Ground spot", (-1.0, -0.5, gap), (3.0, 0.5, 0.0), energy=20000.0, spot_size=math.radians(80))
L["spot0"]("Wall spot", (-3 + gap, 0.0, 1.5), (0.0, 0.5, 0.0), energy=3000.0, spot_size=math.radians(90))
L["add_camera"](scene, (4.5, -4.5, 3.5), (0, 0, 0.3), lens=28)
