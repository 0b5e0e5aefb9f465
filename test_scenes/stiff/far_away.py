"""A scene 100 km from the origin: boxes, a sphere, a card and a ground around
(100000, 20000, 10), a sun and a point light. 200x150. PARAMS: x, y, z (the offset)."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()
ORIGIN = (float(PARAMS.get("x", 100000.0)), float(PARAMS.get("y", 20000.0)), float(PARAMS.get("z", 10.0)))


def at(x, y, z):
    return (ORIGIN[0] + x, ORIGIN[1] + y, ORIGIN[2] + z)


scene = L["setup_scene"]("stiff_far_away", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["heightfield"]("Ground", 16.0, 8, lambda x, y: 0 * x, materials=[grey]),
                location=at(0, 0, 0))
L["add_object"]("Cube", L["box"]("Cube", (2, 2, 2), materials=[grey]), location=at(0, 0, 1))
L["add_object"]("Post", L["box"]("Post", (0.3, 0.3, 3), base_at_origin=True, materials=[grey]), location=at(-2.5, 2, 0),
                rotation=(0, 0, 0.5))
L["add_object"]("Ball", L["uv_sphere"]("Ball", 0.7, 16, 8, materials=[grey]), location=at(2.5, -2.5, 1.2))
L["add_object"]("Card", L["plane"]("Card", 1.5, materials=[grey]), location=at(-2, -2, 1.0), rotation=(0.6, 0.3, 0))
L["sun0"]("Sun", 40, 30)
L["point0"]("Point", at(2.0, -3.5, 3.5), energy=800.0)
L["add_camera"](scene, at(7, -7, 5), at(0, 0, 0.5), lens=30)
