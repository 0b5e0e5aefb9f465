"""A chain-link fence seen from a distance: one alpha-cut card whose wire texels are smaller than
the pixels, front-lit by a low sun that casts the fence's shadow on the ground behind it, seen
through the mesh. Which of the wire or the ground a pixel shows is decided texel by texel at the
pixel centre's hit, as Cycles decides it (a mip-mapped alpha would blur the wires away here).

The wire image is made here (numpy, packed into the file): one diamond of two diagonal wires,
alpha 1 on the wire and 0 in the hole, repeated ``REPEAT`` times over the card by a Mapping
node. A plain ground and a dark box behind the fence. 320x240.

PARAMS: ``interpolation`` (``Linear``, ``Closest``, ``Cubic``, ``Smart``: the Image Texture
node's); ``wire`` (the wire's width, a share of the diamond: 0.09, about 3 texels);
``distance`` (m, camera to fence, default 20); ``width``, ``height``.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
INTERPOLATION = str(PARAMS.get("interpolation", "Linear")).capitalize()
DISTANCE = float(PARAMS.get("distance", 20.0))
WIRE = float(PARAMS.get("wire", 0.09))
#: the fence card (m) and how many wire diamonds repeat across and up it
FENCE_SIZE = (16.0, 2.4)
REPEAT = (80.0, 12.0)


def wire_image(n=32, wire=WIRE):
    """One diamond of a chain-link fence, ``n`` texels square: wires along both diagonals
    (``wire`` of the cell wide), galvanised grey, alpha 1 on the wire and 0 in the hole."""
    c = (np.arange(n) + 0.5) / n
    U, V = np.meshgrid(c, c)
    d1 = np.abs(((U + V) % 1.0) - 0.5)
    d2 = np.abs(((U - V) % 1.0) - 0.5)
    on = np.minimum(0.5 - d1, 0.5 - d2) < wire / 2 * math.sqrt(2)
    rgba = np.zeros((n, n, 4))
    rgba[..., :3] = 0.65
    rgba[..., 3] = on
    return rgba


scene = lib["setup_scene"]("fence_far", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))

ground = lib["material"]("Ground", (0.45, 0.42, 0.35), roughness=0.9)
lib["add_object"]("Ground", lib["plane"]("Ground", 80.0, materials=[ground]))
dark = lib["material"]("Shed", (0.2, 0.18, 0.16), roughness=0.7)
lib["add_object"]("Shed", lib["box"]("Shed", (3.0, 2.0, 1.6), base_at_origin=True, materials=[dark]),
                  location=(-3.5, 5.0, 0.0))

wire_img = lib["image_from_array"]("chain_link", wire_image())
fence = lib["textured_material"]("Chain link", wire_img, color=(0.6, 0.6, 0.62), use_color=False,
                                 scale=REPEAT, extension="REPEAT", interpolation=INTERPOLATION,
                                 roughness=0.4, specular=0.6)
lib["add_object"]("Fence", lib["uv_quad"]("Fence", *FENCE_SIZE, upright=True, base_at_origin=True,
                                          materials=[fence]))

# a low sun from the camera's side: the fence is lit on the side the camera sees and its shadow
# falls on the ground behind it
lib["add_sun"]("Sun", elevation=20, azimuth=-75, energy=4.0)
lib["add_camera"](scene, (2.0, -DISTANCE, 0.25 * DISTANCE), (0.0, 0.0, 0.9), lens=50)
