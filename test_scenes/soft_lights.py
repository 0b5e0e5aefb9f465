"""Soft shadows of extended lights: a slatted pergola and four boxes on a 14 m ground, lit by a
wide sun (4°), a sphere light (point, radius 0.3 m), a spot light (radius 0.2 m, 70° cone,
blend 0.3) and square (1 m), rectangle (1.2 x 0.5 m) and disk (1 m) area lights, each over a box
whose shadow it softens; 200x150. The light sizes are Blender's own settings (sun ``angle``,
``shadow_soft_size``, ``spot_size``, ``spot_blend``, area ``shape``, ``size``, ``size_y``), so Cycles renders the
same penumbrae (``compare --soft``, tests/test_soft_cycles.py).

PARAMS: ``width``, ``height``.
"""
import math
import os
import runpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("soft_lights", (int(PARAMS.get("width", 200)), int(PARAMS.get("height", 150))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
add, box, mat = lib["add_object"], lib["box"], lib["material"]
ground = mat("Ground", (0.6, 0.6, 0.6))
wood = mat("Wood", (0.45, 0.3, 0.18), 0.7)
paint = mat("Paint", (0.75, 0.75, 0.8), 0.4)

add("Ground", lib["plane"]("Ground", 14.0, materials=[ground]))

# the pergola: four posts, two beams along x, seven slats along y on top
for i, (x, y) in enumerate(((-1.5, -1.0), (1.5, -1.0), (1.5, 1.0), (-1.5, 1.0))):
    add(f"Post{i}", box(f"Post{i}", (0.15, 0.15, 2.4), base_at_origin=True, materials=[wood]), location=(x, y, 0))
for i, y in enumerate((-1.0, 1.0)):
    add(f"Beam{i}", box(f"Beam{i}", (3.4, 0.12, 0.18), materials=[wood]), location=(0, y, 2.49))
for i in range(7):
    add(f"Slat{i}", box(f"Slat{i}", (0.1, 2.6, 0.12), materials=[wood]), location=(-1.5 + 0.5 * i, 0, 2.64))

# a box under each local light
add("BoxSphere", box("BoxSphere", (0.8, 0.8, 0.8), base_at_origin=True, materials=[paint]), location=(3.2, 2.4, 0))
add("BoxSquare", box("BoxSquare", (0.5, 0.5, 1.4), base_at_origin=True, materials=[paint]), location=(-3.2, 2.4, 0))
add("BoxRect", box("BoxRect", (0.9, 0.5, 0.7), base_at_origin=True, materials=[paint]), location=(3.2, -2.6, 0),
    rotation=(0, 0, math.radians(20)))
add("BoxSpot", box("BoxSpot", (0.3, 0.3, 1.1), base_at_origin=True, materials=[paint]), location=(-0.6, -4.2, 0))
add("BoxDisk", box("BoxDisk", (0.6, 0.6, 1.0), base_at_origin=True, materials=[paint]), location=(-3.2, -2.6, 0))

lib["add_sun"]("Sun", elevation=50, azimuth=30, energy=3.0, angle=math.radians(4.0))
lib["add_light"]("Sphere", "POINT", location=(2.5, 1.7, 2.6), energy=300.0, shadow_soft_size=0.3)
lib["add_light"]("Spot", "SPOT", location=(-1.7, -4.6, 2.3), target=(0.6, -3.7, 0), energy=400.0,
                 shadow_soft_size=0.2, spot_size=math.radians(70.0), spot_blend=0.3)
lib["add_light"]("Square", "AREA", location=(-2.6, 1.8, 3.0), target=(-3.4, 2.6, 0), energy=300.0,
                 shape="SQUARE", size=1.0)
lib["add_light"]("Rect", "AREA", location=(2.6, -1.9, 2.8), target=(3.4, -2.9, 0), energy=300.0,
                 shape="RECTANGLE", size=1.2, size_y=0.5)
lib["add_light"]("Disk", "AREA", location=(-2.6, -1.9, 3.0), target=(-3.4, -2.9, 0), energy=300.0,
                 shape="DISK", size=1.0)
lib["add_camera"](scene, (8.5, -9.0, 7.5), (0, 0, 0.6), lens=30)
