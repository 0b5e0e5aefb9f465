"""A city at night: blocks of buildings of varied heights along streets, street lamps (point
lights over poles, spot lights over crossings), a dim moon and a dark world.

PARAMS: blocks (per side), width, height, seed.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
BLOCKS = int(PARAMS.get("blocks", 6))
BLOCK, STREET = 30.0, 10.0
rng = np.random.default_rng(int(PARAMS.get("seed", 3)))

scene = lib["setup_scene"]("city", (int(PARAMS.get("width", 640)), int(PARAMS.get("height", 360))))
lib["set_world"](scene, (0.01, 0.012, 0.03), 1.0)
pitch = BLOCK + STREET
extent = BLOCKS * pitch + STREET
lib["add_object"]("Streets", lib["plane"]("Streets", extent,
                                          materials=[lib["material"]("Asphalt", (0.05, 0.05, 0.05), 0.7)]))

unit = lib["box"]("Building", (1, 1, 1), base_at_origin=True,
                  materials=[lib["material"]("Concrete", (0.5, 0.48, 0.45), 0.8)])
pole = lib["box"]("Pole", (0.2, 0.2, 6), base_at_origin=True,
                  materials=[lib["material"]("Steel", (0.3, 0.3, 0.32), 0.4, 0.8)])
start = -extent / 2 + STREET
n = 0
for bx in range(BLOCKS):
    for by in range(BLOCKS):
        x0, y0 = start + bx * pitch, start + by * pitch
        for sx in range(2):
            for sy in range(2):
                w, d = rng.uniform(10, 14, 2)
                h = rng.lognormal(math.log(18), 0.6)
                cx, cy = x0 + (sx + 0.5) * BLOCK / 2, y0 + (sy + 0.5) * BLOCK / 2
                lib["add_object"](f"Building.{n:03d}", unit, location=(cx, cy, 0), scale=(w, d, h))
                n += 1

lamp = 0
for i in range(BLOCKS + 1):
    for j in range(BLOCKS + 1):
        x, y = start - STREET / 2 + i * pitch, start - STREET / 2 + j * pitch
        lib["add_object"](f"Pole.{lamp:03d}", pole, location=(x + 2.5, y + 2.5, 0))
        lib["add_light"](f"Lamp.{lamp:03d}", "POINT", (x + 2.5, y + 2.5, 6.3), energy=300, color=(1.0, 0.75, 0.45),
                         shadow_soft_size=0.15)
        if (i + j) % 2 == 0:
            lib["add_light"](f"Crossing.{lamp:03d}", "SPOT", (x, y, 12), (x, y, 0), energy=1500, color=(0.9, 0.9, 1.0),
                             spot_size=math.radians(70), spot_blend=0.4, shadow_soft_size=0.1)
        lamp += 1

lib["add_sun"]("Moon", elevation=40, azimuth=250, energy=0.05, color=(0.6, 0.7, 1.0))
street_y = start - STREET / 2 + (BLOCKS // 2) * pitch
lib["add_camera"](scene, (-extent / 2 + 5, street_y, 2.0), (extent / 2, street_y + 3, 8), lens=24, clip=(0.1, 1000))
