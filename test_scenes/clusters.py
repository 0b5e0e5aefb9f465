"""Scene 2 of the thesis: fewer objects in tight clusters, many spheres.

``clusters`` collection instances (empties) of two cluster layouts (palms and rocks), and
``spheres`` spheres packed around the cluster centres by geometry nodes (instances of one
sphere object flagged ``hybrid_sphere``). PARAMS: clusters, spheres, width, height, seed.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
CLUSTERS = int(PARAMS.get("clusters", 8))
SPHERES = int(PARAMS.get("spheres", 400))
rng = np.random.default_rng(int(PARAMS.get("seed", 2)))

scene = lib["setup_scene"]("clusters", (int(PARAMS.get("width", 640)), int(PARAMS.get("height", 360))))
lib["set_world"](scene, (0.4, 0.45, 0.55), 0.5)
lib["add_object"]("Ground", lib["plane"]("Ground", 120.0, materials=[lib["material"]("Sand", (0.6, 0.5, 0.35), 0.9)]))

frond, bark = lib["material"]("Frond", (0.1, 0.4, 0.05), 0.6), lib["material"]("Bark", (0.3, 0.2, 0.1), 0.9)
rock_mat = lib["material"]("Rock", (0.4, 0.4, 0.42), 0.8)
layouts = []
for k in range(2):
    coll = lib["hidden_collection"](f"Cluster layout {k}")
    palm = lib["palm"](f"Cluster palm {k}", seed=200 + k, materials=[frond, bark])
    rock = lib["uv_sphere"](f"Rock {k}", radius=1.0, segments=12, rings=7, noise=0.2, seed=k, materials=[rock_mat])
    for j in range(3 + k):
        a = 2 * math.pi * j / (3 + k)
        lib["add_object"](f"Cluster {k} palm {j}", palm, coll, location=(2.5 * math.cos(a), 2.5 * math.sin(a), -0.1),
                          rotation=(0, 0, a))
        lib["add_object"](f"Cluster {k} rock {j}", rock, coll,
                          location=(1.2 * math.cos(a + 0.5), 1.2 * math.sin(a + 0.5), 0.3),
                          scale=(0.8, 0.6, 0.5))
    layouts.append(coll)

centres = lib["jittered_points"](rng, CLUSTERS, 80.0)
for i, (x, y) in enumerate(centres):
    empty = lib["add_object"](f"Cluster.{i:02d}", None, location=(x, y, 0),
                              rotation=(0, 0, rng.uniform(0, 2 * math.pi)))
    empty.instance_type = "COLLECTION"
    empty.instance_collection = layouts[i % 2]

source = lib["hidden_collection"]("Sphere source")
ball = lib["add_object"]("Sphere", lib["uv_sphere"]("Sphere", 1.0, 24, 12,
                         materials=[lib["material"]("Sphere", (0.2, 0.3, 0.8), 0.2, 0.7)]), source)
ball["hybrid_sphere"] = True
owner = rng.integers(0, len(centres), SPHERES)
angle = rng.uniform(0, 2 * math.pi, SPHERES)
dist = 3.5 + rng.gamma(2.0, 1.2, SPHERES)
radius = rng.uniform(0.3, 0.9, SPHERES)
pos = np.stack([centres[owner, 0] + dist * np.cos(angle), centres[owner, 1] + dist * np.sin(angle), radius], axis=1)
lib["instance_on_points"]("Spheres", source, pos, scales=radius)

lib["add_sun"]("Sun", elevation=35, azimuth=120, energy=3.0, color=(1.0, 0.95, 0.85))
for i, (x, y) in enumerate(centres[:4]):
    lib["add_light"](f"Glow.{i}", "POINT", (x + 1, y - 1, 4), energy=600, color=(1.0, 0.7, 0.4), shadow_soft_size=0.3)
lib["add_light"]("Fill", "AREA", (0, -30, 25), (0, 0, 0), energy=2000, size=6.0, shape="RECTANGLE", size_y=3.0)
lib["add_camera"](scene, (0, -75, 35), (0, 0, 0), lens=30)
