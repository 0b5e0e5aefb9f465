"""Khronos' glTF sample Avocado (CC0, ``models/avocado/SOURCE.txt``): 682 smooth-shaded triangles
with the file's own normals, read by Blender's glTF importer, scaled to 2.5 m; one standing, one
lying on its side, on a ground under a sun 15° high and a point light; 320x240.

A real asset's smooth normals on a coarse curved surface: terminators and self-shadowing across
big facets.
"""
import math
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_models.py"))["lib"]()
scene = L["setup_scene"]("model_avocado", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
L["set_world"](scene, (0.05, 0.06, 0.08))
grey = L["material"]("Grey", (0.7, 0.7, 0.7))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[L["material"]("Ground", (0.6, 0.6, 0.6))]))

(standing,) = L["import_gltf"]("avocado/Avocado.gltf", grey)
standing.name = "Avocado"
standing.scale = (40.0, 40.0, 40.0)
standing.location = (-1.3, -1.1, 0.0)
lying = standing.copy()
lying.name = "Avocado lying"
scene.collection.objects.link(lying)
lying.rotation_euler = (0.0, math.radians(90), math.radians(-35))  # (the importer's Y-up turn dropped)
lying.location = (1.0, 1.3, 0.55)

L["add_sun"]("Sun", elevation=15, azimuth=226, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(-2.1, -2.0, 1.5), energy=300.0)
L["add_camera"](scene, (6.5, -6.5, 4.0), (0.2, 0.0, 0.9), lens=35)
