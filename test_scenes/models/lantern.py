"""Khronos' glTF sample Lantern (CC0, ``models/lantern/SOURCE.txt``): a lamp post with a chain and
a lantern, about 5,400 smooth-shaded triangles with the file's own normals, read by Blender's glTF
importer and scaled to 2.6 m, on a ground under a sun 20° high and a spot from the other side;
320x240.

Thin smooth parts (the chain, the lantern's frame) over the ground and over each other.
"""
import math
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_models.py"))["lib"]()
scene = L["setup_scene"]("model_lantern", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
L["set_world"](scene, (0.05, 0.06, 0.08))
grey = L["material"]("Grey", (0.7, 0.7, 0.7))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[L["material"]("Ground", (0.6, 0.6, 0.6))]))

for root in L["import_gltf"]("lantern/Lantern.gltf", grey):
    root.scale = (0.1, 0.1, 0.1)
    root.location = (0.0, 0.0, 0.0)
    root.rotation_euler.z += math.radians(-30)

L["add_sun"]("Sun", elevation=10, azimuth=200, energy=4.0)
L["add_light"]("Spot", "SPOT", location=(2.5, -2.5, 3.0), target=(-0.3, 0.3, 1.2), energy=1500.0,
               spot_size=math.radians(70), spot_blend=0.1)
L["add_camera"](scene, (3.2, -4.2, 2.2), (-0.3, 0.0, 1.3), lens=35)
