"""Scene 1 of the thesis: palm forest on rolling hills at dawn, spheres rolling between the trees.

A 256x256-quad heightfield, ``trees`` palms (``variants`` meshes of 1.5-3k triangles, linked
duplicates), ``spheres`` rolling UV spheres (every other one flagged ``hybrid_sphere``), a low
dawn sun, point and spot lights, and a camera flying through dense and sparse parts over
``frames`` frames. PARAMS: trees, spheres, variants, terrain, size, frames, width, height, seed.
"""
import math
import os
import runpy

import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
TREES = int(PARAMS.get("trees", 300))
SPHERES = int(PARAMS.get("spheres", 60))
VARIANTS = int(PARAMS.get("variants", 4))
TERRAIN = int(PARAMS.get("terrain", 256))
SIZE = float(PARAMS.get("size", 200.0))
FRAMES = int(PARAMS.get("frames", 250))
rng = np.random.default_rng(int(PARAMS.get("seed", 1)))


def height(x, y):
    return 3.0 * np.sin(x / 23.0) * np.cos(y / 31.0) + 1.5 * np.sin((x + 2 * y) / 17.0)


def density(x, y):  # dense forest in the west, sparse in the east
    return 0.15 + 1.0 / (1.0 + np.exp(x / (0.1 * SIZE)))


scene = lib["setup_scene"]("forest", (int(PARAMS.get("width", 640)), int(PARAMS.get("height", 360))), (1, FRAMES))
lib["set_world"](scene, (0.35, 0.3, 0.4), 0.4)
ground = lib["material"]("Grass", (0.18, 0.3, 0.08), 0.9, 0.2)
lib["add_object"]("Terrain", lib["heightfield"]("Terrain", SIZE, TERRAIN, height, materials=[ground]))

frond, bark = lib["material"]("Frond", (0.1, 0.4, 0.05), 0.6), lib["material"]("Bark", (0.3, 0.2, 0.1), 0.9)
palms = [lib["palm"](f"Palm {v}", seed=100 + v, materials=[frond, bark]) for v in range(VARIANTS)]
xy = lib["jittered_points"](rng, TREES, SIZE * 0.95, density)
variant = rng.integers(0, VARIANTS, len(xy))
turn = rng.uniform(0, 2 * math.pi, len(xy))
scale = rng.uniform(0.8, 1.2, len(xy))
for i, ((x, y), v) in enumerate(zip(xy, variant)):
    lib["add_object"](f"Palm.{i:04d}", palms[v], location=(x, y, height(x, y) - 0.2),
                      rotation=(0, 0, turn[i]), scale=(scale[i],) * 3)

ball = lib["uv_sphere"]("Ball", radius=1.0, segments=24, rings=12,
                        materials=[lib["material"]("Ball", (0.7, 0.7, 0.75), 0.3, 0.6)])
xy = lib["jittered_points"](rng, SPHERES, SIZE * 0.8)
roll = rng.uniform(-10, 10, (len(xy), 2))
for i, (x, y) in enumerate(xy):
    r = rng.uniform(0.5, 1.5)
    ob = lib["add_object"](f"Ball.{i:03d}", ball, location=(x, y, height(x, y) + r), scale=(r, r, r))
    ob["hybrid_sphere"] = i % 2 == 0
    ob.keyframe_insert("location", frame=1)
    ob.keyframe_insert("rotation_euler", frame=1)
    ex, ey = x + roll[i, 0], y + roll[i, 1]
    ob.location = (ex, ey, float(height(ex, ey)) + r)
    ob.rotation_euler = (roll[i, 1] / r, -roll[i, 0] / r, 0)
    ob.keyframe_insert("location", frame=FRAMES)
    ob.keyframe_insert("rotation_euler", frame=FRAMES)

lib["add_sun"]("Dawn sun", elevation=8, azimuth=200, energy=2.5, color=(1.0, 0.65, 0.4), angle=math.radians(1.0))
for i, (x, y) in enumerate([(-40, 10), (5, -30), (45, 35)]):
    lib["add_light"](f"Lantern.{i}", "POINT", (x, y, height(x, y) + 3), energy=800, color=(1, 0.8, 0.5),
                     shadow_soft_size=0.2)
for i, (x, y) in enumerate([(-20, -20), (30, 0)]):
    lib["add_light"](f"Spot.{i}", "SPOT", (x, y, height(x, y) + 12), (x + 4, y, height(x, y)), energy=3000,
                     spot_size=math.radians(50), spot_blend=0.3, shadow_soft_size=0.1)

# camera path: a loop through the dense west and the sparse east, looking ahead
cam = lib["add_camera"](scene, (0, 0, 0), (1, 0, 0), lens=28, clip=(0.1, 500))
target = lib["add_object"]("Camera target", None)
con = cam.constraints.new("TRACK_TO")
con.target, con.track_axis, con.up_axis = target, "TRACK_NEGATIVE_Z", "UP_Y"
keys = 6
for k in range(keys + 1):
    a = 2 * math.pi * k / keys
    frame = 1 + round((FRAMES - 1) * k / keys)
    px, py = 0.3 * SIZE * math.cos(a), 0.2 * SIZE * math.sin(a)
    tx, ty = 0.3 * SIZE * math.cos(a + 0.4), 0.2 * SIZE * math.sin(a + 0.4)
    cam.location = (px, py, float(height(px, py)) + 4)
    target.location = (tx, ty, float(height(tx, ty)) + 2)
    cam.keyframe_insert("location", frame=frame)
    target.keyframe_insert("location", frame=frame)
scene.frame_set(1)
