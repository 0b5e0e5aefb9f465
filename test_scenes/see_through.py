"""See-through panes: two level glass-like panes (Principled Alpha 0.3 and 0.7, no texture) above
a checker ground, an opaque box under each, a sun whose shadows of the boxes and of the panes
(transparent: 1 - alpha of the light gets through) fall on the ground in view.

Cycles shows alpha x a pane + (1 - alpha) x what lies behind it, each lit as it is lit, which
stochastic transparency converges to (tests/test_see_through_cycles.py). 160x120.

PARAMS: ``width``, ``height``; ``alpha_a``, ``alpha_b`` (the panes' alphas).
"""
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
ALPHAS = (float(PARAMS.get("alpha_a", 0.3)), float(PARAMS.get("alpha_b", 0.7)))

scene = lib["setup_scene"]("see_through", (int(PARAMS.get("width", 160)), int(PARAMS.get("height", 120))))
lib["set_world"](scene, (0.05, 0.06, 0.08))

n = 128
j, i = np.mgrid[0:n, 0:n]
check = ((i * 16 // n) + (j * 16 // n)) % 2
rgb = np.where(check[..., None] == 1, [0.7, 0.62, 0.45], [0.25, 0.35, 0.2])
ground_img = lib["image_from_array"]("see_through_ground", np.concatenate([rgb, np.ones((n, n, 1))], axis=-1))
ground = lib["textured_material"]("Ground", ground_img, use_alpha=False, roughness=0.8)
lib["add_object"]("Ground", lib["uv_quad"]("Ground", 12.0, 12.0, materials=[ground]))

box = lib["box"]("Box", (0.8, 0.8, 1.0), base_at_origin=True,
                 materials=[lib["material"]("Box", (0.8, 0.3, 0.2), 0.5)])
for k, a in enumerate(ALPHAS):
    x = -1.6 + 3.2 * k
    lib["add_object"](f"Box {k}", box, location=(x, 0.3, 0.0))
    glass = lib["material"](f"Pane {a:g}", (0.2, 0.5, 0.9), 0.3)
    glass.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = a
    if hasattr(glass, "surface_render_method"):  # EEVEE's (Blender 4.2+): Cycles blends regardless
        glass.surface_render_method = "DITHERED"
    lib["add_object"](f"Pane {a:g}", lib["uv_quad"](f"Pane {k}", 2.8, 3.6, materials=[glass]), location=(x, 0.0, 1.6))

lib["add_sun"]("Sun", elevation=50, azimuth=60, energy=3.0)
lib["add_camera"](scene, (0.0, -6.5, 7.0), (0.0, 0.3, 0.6), lens=32)
