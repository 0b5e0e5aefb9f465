"""An orthographic camera (tilted, and PARAMS top=1: straight down, exact axes) over boxes, a
sphere and cards; a sun and a point light. 200x150."""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_ortho", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 12.0, materials=[grey]))
L["add_object"]("Cube", L["box"]("Cube", (1.5, 1.5, 1.5), base_at_origin=True, materials=[grey]), rotation=(0, 0, 0.3))
L["add_object"]("Tall", L["box"]("Tall", (0.4, 0.4, 2.5), base_at_origin=True, materials=[grey]), location=(-2, 1.5, 0))
L["add_object"]("Ball", L["uv_sphere"]("Ball", 0.7, 16, 8, materials=[grey]), location=(2, -1.5, 0.7))
L["add_object"]("Card", L["plane"]("Card", 1.2, materials=[grey]), location=(-1.5, -2, 1.0), rotation=(0.5, 0.4, 0))
L["sun0"]("Sun", 35, 120)
L["point0"]("Point", (1.0, 2.0, 3.0), energy=600.0)
cam = L["add_camera"](scene, (7, -7, 7), (0, 0, 0), lens=30, clip=(0.1, 100.0))
cam.data.type = "ORTHO"
cam.data.ortho_scale = 11.0
if int(PARAMS.get("top", 0)):
    cam.location, cam.rotation_euler = (0, 0, 10), (0, 0, 0)
