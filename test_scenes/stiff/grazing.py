"""Grazing light: suns 0.1°, 0.5° and 1° above the horizon over a tessellated flat ground
(coplanar neighbour triangles invite acne), boxes, a wall and a low-poly sphere. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_grazing", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["heightfield"]("Ground", 40.0, 40, lambda x, y: 0 * x, materials=[grey]))
L["add_object"]("Box", L["box"]("Box", (1.5, 1.5, 1.5), base_at_origin=True, materials=[grey]), location=(0, 0, 0))
L["add_object"]("Low box", L["box"]("Low box", (2, 1, 0.3), base_at_origin=True, materials=[grey]),
                location=(-3, 2.5, 0), rotation=(0, 0, 0.4))
L["add_object"]("Wall", L["box"]("Wall", (0.2, 5, 1), base_at_origin=True, materials=[grey]),
                location=(3.5, -1, 0), rotation=(0, 0, 0.2))
L["add_object"]("Ball", L["uv_sphere"]("Ball", 0.8, 12, 6, materials=[grey]), location=(-1.5, -3, 0.8))
L["add_object"]("Slab", L["box"]("Slab", (3, 3, 0.05), base_at_origin=True, materials=[grey]),
                location=(2.5, 4, 0.0))
L["sun0"]("Sun 0.1", float(PARAMS.get("e1", 0.1)), 20, energy=50.0)
L["sun0"]("Sun 0.5", float(PARAMS.get("e2", 0.5)), 135, energy=20.0)
L["sun0"]("Sun 1", float(PARAMS.get("e3", 1.0)), 250, energy=10.0)
L["add_camera"](scene, (11, -11, 6), (0, 0, 0), lens=30)
