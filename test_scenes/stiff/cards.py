"""Thin single-sided cards (one quad each, no thickness) at many angles, some almost edge-on to
the sun, over a ground; a sun and a spot light. 200x150."""
import math
import os
import runpy

import numpy as np

PARAMS = globals().get("PARAMS", {})
L = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_stiff.py"))["lib"]()

scene = L["setup_scene"]("stiff_cards", L["resolution"](PARAMS))
L["set_world"](scene, (0.05, 0.05, 0.05))
grey = L["material"]("Grey", (0.6, 0.6, 0.6))
L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[grey]))
card = L["mesh"]("Card", [(-0.5, -0.3, 0), (0.5, -0.3, 0), (0.5, 0.3, 0), (-0.5, 0.3, 0)], [[0, 1, 2, 3]],
                 materials=[grey])
rng = np.random.default_rng(int(PARAMS.get("seed", 5)))
n = int(PARAMS.get("cards", 30))
for i in range(n):
    loc = (rng.uniform(-3.5, 3.5), rng.uniform(-3.5, 3.5), rng.uniform(0.2, 1.6))
    rot = tuple(rng.uniform(0, math.pi, 3))
    if i % 5 == 0:   # almost edge-on to the sun (which lies in the x-z plane): the card's normal along y
        rot = (math.pi / 2 + rng.uniform(-0.02, 0.02), 0.0, rng.uniform(-0.02, 0.02))
    L["add_object"](f"Card{i}", card, location=loc, rotation=rot)
L["sun0"]("Sun", 50, 0)
L["spot0"]("Spot", (-4, 3, 4), (0, 0, 0), energy=3000.0, spot_size=math.radians(70))
L["add_camera"](scene, (8, -8, 6), (0, 0, 0.3), lens=30)
