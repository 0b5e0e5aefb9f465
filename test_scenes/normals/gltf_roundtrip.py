"""Meshes written by Blender's own glTF (binary .glb) exporter and read back by its importer (a temporary
folder, within the script): a smooth UV sphere, a chamfered box with weighted normals, a slab with
fanned custom normals, a smooth cylinder with reversed winding and a subdivided Suzanne; what
renders is what the importer made of the file: its custom normals. A sun and a point light;
320x240.
"""
import os
import runpy

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_normals.py"))["lib"]()
scene, grey = L["stage"]("normals_gltf_roundtrip", PARAMS)
for ob in L["roundtrip"](L["exchange_set"](grey), "gltf"):
    ob.data.materials.clear()
    ob.data.materials.append(grey)

L["add_sun"]("Sun", elevation=6, azimuth=60, energy=4.0)
L["add_light"]("Lamp", "POINT", location=(0.9, -2.8, 1.0), energy=300.0)
L["add_camera"](scene, (8, -9, 6), (0, 0, 0.6), lens=35)
