"""clip_start 1e-4 with clip_end 1e6: a leaf 3 cm in front of the lens, boxes and a mat 2 cm
above the ground at 6-15 m, a 'mountain' 800 m away on a 3 km ground; a sun and a point
light. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_clip_range", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 3000.0, materials=[grey]))
L["add_object"]("Cube", L["box"]("Cube", (2, 2, 2), base_at_origin=True, materials=[grey]), rotation=(0, 0, 0.4))
L["add_object"]("Post", L["box"]("Post", (0.3, 0.3, 3), base_at_origin=True, materials=[grey]), location=(-3, 3, 0))
L["add_object"]("Mat", L["box"]("Mat", (2.5, 1.5, 0.01), materials=[grey]), location=(-2.5, -2.5, 0.02))
L["add_object"]("Mountain", L["box"]("Mountain", (200, 200, 150), base_at_origin=True, materials=[grey]),
                location=(-600, 550, 0), rotation=(0, 0, 0.7))
L["sun0"]("Sun", 30, 200)
L["point0"]("Point", (2, -3, 2.5), energy=800.0)
cam = L["add_camera"](scene, (8, -8, 3.5), (0, 0, 0.8), lens=30, clip=(1e-4, 1e6))
L["add_object"]("Leaf", L["plane"]("Leaf", 0.02, materials=[grey]), location=(8 - 0.025, -8 + 0.03, 3.5 - 0.018),
                rotation=(1.2, 0.3, 0.5))
