"""Khronos' glTF sample Water Bottle (CC0, ``models/waterbottle/SOURCE.txt``): about 4,500
smooth-shaded triangles with the file's own normals, read by Blender's glTF importer and scaled
to 2.6 m; one standing, one lying on its side, on a ground under a sun 8° high and a point light;
320x240.

Long smooth terminators down a cylinder-like body and a lying bottle shadowing itself.
"""
import math
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_models.py"))["lib"]()
scene = L["setup_scene"]("model_waterbottle", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
L["set_world"](scene, (0.05, 0.06, 0.08))
grey = L["material"]("Grey", (0.7, 0.7, 0.7))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[L["material"]("Ground", (0.6, 0.6, 0.6))]))

(standing,) = L["import_gltf"]("waterbottle/WaterBottle.gltf", grey)
standing.name = "Bottle"
standing.scale = (10.0, 10.0, 10.0)
standing.location = (-1.0, 0.6, 1.302)
lying = standing.copy()
lying.name = "Bottle lying"
scene.collection.objects.link(lying)
lying.rotation_euler = (math.radians(90), 0.0, math.radians(-20))
lying.location = (1.2, -0.6, 0.545)

L["add_sun"]("Sun", elevation=8, azimuth=130, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(0.2, -1.8, 1.4), energy=300.0)
L["add_camera"](scene, (6.0, -6.5, 3.5), (0.0, 0.0, 0.9), lens=35)
