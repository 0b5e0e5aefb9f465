"""Scaling test: ``instances`` geometry-nodes instances (up to 100k) of ``models`` sphere-like
meshes with ``triangles`` triangles in all (up to 1M; each model gets triangles / instances),
in a square field on a ground plane, a sun and a camera seeing them all.

PARAMS: triangles (default 100000), instances (1000), models (1), width, height, seed.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
INSTANCES = max(1, int(PARAMS.get("instances", 1000)))
TRIANGLES = int(PARAMS.get("triangles", 100_000))
MODELS = max(1, min(int(PARAMS.get("models", 1)), INSTANCES))
rng = np.random.default_rng(int(PARAMS.get("seed", 4)))

scene = lib["setup_scene"]("scaling", (int(PARAMS.get("width", 640)), int(PARAMS.get("height", 360))))
lib["set_world"](scene, (0.3, 0.35, 0.45), 0.5)
side = math.ceil(math.sqrt(INSTANCES))
spacing = 3.0
field = side * spacing
lib["add_object"]("Ground", lib["plane"]("Ground", field + 10, materials=[lib["material"]("Ground", (0.5, 0.5, 0.5))]))

source = lib["hidden_collection"]("Models")
mat = lib["material"]("Blob", (0.7, 0.5, 0.3), 0.5)
per_model = max(1, TRIANGLES // INSTANCES)
for m in range(MODELS):
    lib["add_object"](f"Model.{m:03d}", lib["sphere_for_triangles"](f"Model.{m:03d}", per_model, 1.0, 0.15, m, [mat]),
                      source)
i = np.arange(INSTANCES)
pos = np.stack([(i % side + 0.5) * spacing - field / 2, (i // side + 0.5) * spacing - field / 2,
                np.full(INSTANCES, 1.0)], axis=1)
pos[:, :2] += rng.uniform(-0.5, 0.5, (INSTANCES, 2))
lib["instance_on_points"]("Field", source, pos, rotations=rng.uniform(0, 2 * math.pi, (INSTANCES, 3)),
                          scales=rng.uniform(0.6, 1.2, INSTANCES), variants=i % MODELS)

lib["add_sun"]("Sun", elevation=40, azimuth=60, energy=3.0)
lib["add_camera"](scene, (0.9 * field, -0.9 * field, 0.8 * field), (0, 0, 0), lens=30, clip=(0.1, 10 * field))
