"""Alpha cards: leaf cards and a chain-link fence cut out by alpha textures, on a textured ground.

Every image is made here (numpy, packed into the file): a checker-and-noise ground colour, a
leaf (green colour, leaf-shaped alpha with bite holes, binary apart from a one-texel edge) and a
diamond wire mesh repeated 24 x 8 times over one 8 x 2.5 m fence quad by a Mapping node. Leaf
cards: a few single ones (flat, tilted, upright) and an instanced cluster of 40 (geometry nodes).
A sun at 40° elevation behind the fence and a spot light cast the cards' and the fence's
shadows on the ground, in front of the camera. 320x240.

PARAMS: ``opaque=1``: the same scene with the cards' and the fence's Alpha unlinked (alpha 1,
the cost of the alpha test by comparison); ``closest=1``: the leaf's and the fence's alpha
strictly binary (no one-texel ramp, Closest interpolation), so that no pixel centre sees a surface
of fractional alpha: Cycles then never blends two surfaces into one pixel, which the per-light
visibility of ``compare`` would count as mismatches (tests/test_alpha_cycles.py); ``width``,
``height``; ``seed``.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
OPAQUE = bool(int(PARAMS.get("opaque", 0)))
CLOSEST = bool(int(PARAMS.get("closest", 0)))
ALPHA_INTERPOLATION = "Closest" if CLOSEST else "Linear"
rng = np.random.default_rng(int(PARAMS.get("seed", 3)))
#: the fence image repeats this many times across and up the fence quad
FENCE_REPEAT = (24.0, 8.0)


def ground_image(n=256, squares=16):
    """Checker of two earthy tones with low-frequency noise, opaque."""
    j, i = np.mgrid[0:n, 0:n]
    check = ((i * squares // n) + (j * squares // n)) % 2
    noise = np.zeros((n, n))
    for k, amp in ((4, 0.5), (8, 0.3), (32, 0.2)):
        coarse = rng.uniform(-1, 1, (k + 1, k + 1))
        t = np.linspace(0, k, n)
        a, b = np.floor(t).astype(int).clip(0, k - 1), t - np.floor(t).clip(0, k - 1)
        rows = coarse[a] * (1 - b)[:, None] + coarse[a + 1] * b[:, None]
        noise += amp * (rows[:, a] * (1 - b)[None, :] + rows[:, a + 1] * b[None, :])
    base = np.where(check[..., None] == 1, [0.55, 0.48, 0.36], [0.36, 0.42, 0.28])
    rgb = base * (1 + 0.25 * noise[..., None])
    return np.concatenate([rgb, np.ones((n, n, 1))], axis=-1)


def leaf_image(w=128, h=192):
    """A pointed leaf along v with a stalk, bite holes and darker veins; alpha 1 inside, 0
    outside, a one-texel ramp on the edge."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    U, V = np.meshgrid(u, v)
    x = 2 * U - 1  # -1..1 across
    t = (V - 0.12) / 0.86  # blade from v = 0.12 to 0.98
    half = 0.92 * np.sin(np.pi * np.clip(t, 0, 1)) ** 0.7 * (1 - 0.35 * np.clip(t, 0, 1))
    inside = half - np.abs(x)
    stalk = np.where(V < 0.14, 0.04 - np.abs(x), -1.0)
    d = np.maximum(inside, stalk) * w / 2  # signed distance in texels, roughly
    for cu, cv, r in ((0.62, 0.55, 0.07), (0.3, 0.7, 0.05), (0.8, 0.35, 0.045), (0.45, 0.86, 0.035)):
        hole = (np.hypot((U - cu) * w, (V - cv) * h) - r * w)
        d = np.minimum(d, hole)
    alpha = (d > 0).astype(float) if CLOSEST else np.clip(d + 0.5, 0, 1)
    vein = np.exp(-(x * 30) ** 2) + 0.5 * np.exp(-((np.abs(x) - 0.6 * (t - 0.1)) * 25) ** 2 * (np.sin(t * 40) > 0.6))
    g = np.clip(0.35 + 0.25 * t - 0.2 * np.clip(vein, 0, 1), 0.05, 1)
    rgb = np.stack([0.25 * g, g, 0.12 * g], axis=-1)
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def wire_image(n=64, wire=0.09):
    """One diamond of a chain-link fence: wires along both diagonals (width ``wire`` of the
    cell), grey metal colour, alpha 1 on the wire and 0 in the holes."""
    c = (np.arange(n) + 0.5) / n
    U, V = np.meshgrid(c, c)
    d1 = np.abs(((U + V) % 1.0) - 0.5)
    d2 = np.abs(((U - V) % 1.0) - 0.5)
    on = (np.minimum(0.5 - d1, 0.5 - d2) < wire / 2 * math.sqrt(2))
    rgba = np.zeros((n, n, 4))
    rgba[..., :3] = 0.6
    rgba[..., 3] = on
    return rgba


scene = lib["setup_scene"]("alpha_cards", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))

# ground: colour texture only
ground_img = lib["image_from_array"]("ground_checker", ground_image())
ground = lib["textured_material"]("Ground", ground_img, use_alpha=False, roughness=0.8)
lib["add_object"]("Ground", lib["uv_quad"]("Ground", 14.0, 14.0, materials=[ground]))

# leaf cards: colour and alpha from one image
leaf_img = lib["image_from_array"]("leaf", leaf_image())
leaf = lib["textured_material"]("Leaf", leaf_img, use_alpha=not OPAQUE, extension="CLIP",
                            interpolation=ALPHA_INTERPOLATION, roughness=0.6)
card = lib["uv_quad"]("Leaf card", 0.8, 1.2, materials=[leaf])
for name, loc, rot in (("Card flat", (-2.2, 0.3, 1.2), (0.0, 0.0, 0.4)),
                       ("Card tilted", (-0.8, -0.4, 1.6), (0.7, 0.3, -0.5)),
                       ("Card steep", (0.6, 0.6, 1.3), (1.2, 0.0, 1.1)),
                       ("Card upright", (-3.2, -1.2, 0.7), (math.pi / 2, 0.0, 0.3))):
    lib["add_object"](name, card, location=loc, rotation=rot)

# an instanced cluster of leaves (geometry nodes instancing a hidden leaf object)
sprigs = lib["hidden_collection"]("Leaf sprig source")
lib["add_object"]("Leaf sprig", card, collection=sprigs, scale=(0.6, 0.6, 0.6))
n = 40
centre = np.array([2.6, -0.2, 1.8])
pts = centre + rng.normal(0, [0.6, 0.6, 0.45], (n, 3))
rot = np.stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-1.2, 1.2, n), rng.uniform(0, 2 * math.pi, n)], axis=1)
lib["instance_on_points"]("Leaf cluster", sprigs, pts, rotations=rot, scales=rng.uniform(0.7, 1.3, n))

# chain-link fence: one big upright quad, the wire image repeated by a Mapping node, and posts
wire_img = lib["image_from_array"]("fence_wire", wire_image(), colorspace="sRGB")
fence = lib["textured_material"]("Fence", wire_img, color=(0.55, 0.56, 0.6), use_color=False, use_alpha=not OPAQUE,
                                 scale=FENCE_REPEAT, extension="REPEAT", interpolation=ALPHA_INTERPOLATION,
                                 roughness=0.35, specular=0.8)
lib["add_object"]("Fence", lib["uv_quad"]("Fence", 8.0, 2.5, upright=True, base_at_origin=True, materials=[fence]),
                  location=(0.0, 2.5, 0.0))
post = lib["box"]("Fence post", (0.08, 0.08, 2.6), base_at_origin=True,
                  materials=[lib["material"]("Post", (0.3, 0.3, 0.32), 0.4)])
for i, x in enumerate((-4.0, 0.0, 4.0)):
    lib["add_object"](f"Fence post.{i}", post, location=(x, 2.56, 0.0))

# a sun behind the fence (shadows fall towards the camera) and a spot light from the side
lib["add_sun"]("Sun", elevation=40, azimuth=100, energy=4.0)
lib["add_light"]("Spot", "SPOT", (-5.0, 1.0, 6.0), (0.0, -1.0, 0.0), energy=1500, spot_size=math.radians(60),
                 spot_blend=0.3, shadow_soft_size=0.05)
lib["add_camera"](scene, (0.8, -7.5, 4.6), (0.0, 0.4, 0.5), lens=28)
