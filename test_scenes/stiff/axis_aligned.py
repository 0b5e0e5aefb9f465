"""Light directions with components exactly 0 and faces exactly on integer coordinates: unit
boxes on integer positions (touching boxes share faces), a sun straight down (0, 0, -1), a
horizontal sun along -X, a horizontal sun with z exactly 0, a sun with y exactly 0, and a
point light on integer coordinates. 200x150."""
import math
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_axis_aligned", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["mesh"]("Ground", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], [[0, 1, 2, 3]],
                                    materials=[grey]))
unit = L["box"]("Unit", (1, 1, 1), base_at_origin=True, materials=[grey])
tall = L["box"]("Tall", (1, 1, 2), base_at_origin=True, materials=[grey])
# rows along X at the same y: the taller box's +X face is half shadowed by the unit box (horizontal sun)
for i, (x, y, m) in enumerate([(0, 0, unit), (-3, 0, tall), (2, -2, unit), (3, -2, unit), (3, -2 + 1, tall),
                               (-1, -3, tall), (-4, -3, unit), (1, 2, unit), (2, 2, tall)]):
    L["add_object"](f"Box{i}", m, location=(x + 0.5, y + 0.5, 0))   # faces on integers
L["add_object"]("Stacked", unit, location=(2.5, -1.5, 1))          # on top of a box: shared face
L["add_object"]("Floating", unit, location=(-1.5, 1.5, 1))         # bottom face exactly at z = 1
L["add_object"]("Roof", L["box"]("Roof", (2, 2, 1), base_at_origin=True, materials=[grey]), location=(-4, 3, 2))
IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
ROT_Y90 = ((0, 0, 1), (0, 1, 0), (-1, 0, 0))   # -Z column -> (-1, 0, 0): shines towards -X
L["exact_light"]("Sun down", "SUN", IDENTITY, energy=5.0)
L["exact_light"]("Sun X", "SUN", ROT_Y90, energy=5.0)
L["exact_light"]("Sun Z0", "SUN", ROT_Y90, parent_euler=(0, 0, math.radians(30)), energy=5.0)
L["exact_light"]("Sun Y0", "SUN", IDENTITY, parent_euler=(0, math.radians(-50), 0), energy=5.0)
L["exact_light"]("Point", "POINT", IDENTITY, location=(1, 0, 3), energy=800.0)
L["add_camera"](scene, (9, -7, 6), (-0.5, -0.5, 0.5), lens=30)
