"""Thousands of objects in one grid node: 2500 tiny cubes and spheres (geometry-nodes instances,
random rotations, some with negative scale) in a 1 m cloud above a ground, with 150 sparse
boxes spread over 200 m (so the grid's nodes are large); a sun and a point light. 200x150."""
import math
import os
import runpy

import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_crowd", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 8.0, materials=[grey]))
rng = np.random.default_rng(int(PARAMS.get("seed", 1)))
src = L["hidden_collection"]("Crowd sources")
L["add_object"]("Tiny cube", L["box"]("Tiny cube", (0.03, 0.03, 0.03), materials=[grey]), collection=src)
L["add_object"]("Tiny ball", L["uv_sphere"]("Tiny ball", 0.018, 8, 4, materials=[grey]), collection=src)
n = int(PARAMS.get("count", 2500))
pos = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0.05, 0.8, n)], axis=1)
rot = rng.uniform(0, 2 * math.pi, (n, 3))
scale = rng.uniform(0.6, 1.2, n) * np.where(rng.random(n) < 0.2, -1.0, 1.0)
L["instance_on_points"]("Crowd", src, pos, rot, scale, rng.integers(0, 2, n))
far = L["hidden_collection"]("Far sources")
L["add_object"]("Far box", L["box"]("Far box", (1, 1, 1), base_at_origin=True, materials=[grey]), collection=far)
m = 150
fp = np.stack([rng.uniform(-100, 100, m), rng.uniform(-100, 100, m), np.zeros(m)], axis=1)
fp = fp[np.hypot(fp[:, 0], fp[:, 1]) > 8]
L["instance_on_points"]("Far", far, fp)
L["sun0"]("Sun", 50, 30)
L["point0"]("Point", (-0.6, -0.9, 1.6), energy=60.0)
L["add_camera"](scene, (1.6, -1.6, 1.3), (0, 0, 0.3), lens=30)
