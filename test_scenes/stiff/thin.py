"""Sub-pixel shadow casters: thin poles, wires strung between them and a fan of narrow leaf
blades over a ground, whose shadows are thinner than the spacing of coarse shadow rays (and
often than a pixel); a low sun, a spot light and a point light. 200x150."""
import math
import os
import runpy

import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_thin", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[grey]))
rng = np.random.default_rng(int(PARAMS.get("seed", 7)))
width = float(PARAMS.get("width_m", 0.025))  # ~1/3 of a pixel's footprint on the ground at 200x150
pole = L["box"]("Pole", (width, width, 2.0), base_at_origin=True, materials=[grey])
poles = []
for i in range(int(PARAMS.get("poles", 12))):
    loc = (rng.uniform(-4.0, 4.0), rng.uniform(-4.0, 4.0), 0.0)
    tilt = (rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(0, math.pi))
    L["add_object"](f"Pole{i}", pole, location=loc, rotation=tilt)
    poles.append(loc)
# wires: long thin boxes at 1.5-1.9 m between pole positions (rotated about z to join them)
wire = L["box"]("Wire", (1.0, width * 0.6, width * 0.6), materials=[grey])
for i in range(int(PARAMS.get("wires", 8))):
    a, b = np.asarray(poles[i % len(poles)]), np.asarray(poles[(i + 3) % len(poles)])
    mid, d = (a + b) / 2, b - a
    length = float(np.hypot(d[0], d[1]))
    L["add_object"](f"Wire{i}", wire, location=(mid[0], mid[1], 1.5 + 0.05 * i),
                    rotation=(0.0, 0.0, math.atan2(d[1], d[0])), scale=(length, 1.0, 1.0))
# leaf blades: narrow single-sided triangles fanned out on a stalk, some nearly edge-on
blade = L["mesh"]("Blade", [(0.0, -width, 0.0), (0.0, width, 0.0), (0.9, 0.0, 0.0)], [[0, 1, 2]], materials=[grey])
for i in range(int(PARAMS.get("blades", 24))):
    cx, cy = (-2.0, 2.0) if i % 2 else (2.5, -1.5)
    L["add_object"](f"Blade{i}", blade, location=(cx, cy, 1.2 + 0.02 * i),
                    rotation=(rng.uniform(-0.4, 0.4), rng.uniform(-0.6, 0.2),
                              2 * math.pi * i / 24 + rng.uniform(-0.1, 0.1)))
L["sun0"]("Sun", 35, 30)
L["spot0"]("Spot", (-3, -4, 5), (0, 0, 0), energy=3000.0, spot_size=math.radians(80))
L["point0"]("Point", (1.0, 1.5, 3.2), energy=800.0)
L["add_camera"](scene, (8, -8, 6), (0, 0, 0.3), lens=30)
