"""Hair, curves and points as Cycles renders them: a sphere with particle-hair strands (root to
tip radius, closed tips), a Curves object of bent strands with a radius per point, and a point
cloud made by a geometry-nodes Mesh to Points (radius per point); a sun and a point light.
Parameters: ``width``, ``height`` (320x240), ``hair`` (particle strands, 300), ``strands`` (Curves
strands, 200), ``points`` (point-cloud points, 300). 320x240."""
import math
import os
import runpy

import bpy
import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
N_HAIR = int(PARAMS.get("hair", 300))
N_STRANDS = int(PARAMS.get("strands", 200))
N_POINTS = int(PARAMS.get("points", 300))
KEYS = 6  # points per Curves strand

scene = lib["setup_scene"]("hair", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
scene.cycles_curves.shape = "THICK"  # Cycles' round 3D curves
grey = lib["material"]("Grey", (0.6, 0.6, 0.6))
brown = lib["material"]("Brown", (0.5, 0.3, 0.1))
blond = lib["material"]("Blond", (0.8, 0.7, 0.4))
teal = lib["material"]("Teal", (0.1, 0.6, 0.6))
add = lib["add_object"]
rng = np.random.default_rng(7)

add("Ground", lib["plane"]("Ground", 14.0, materials=[grey]))

# a sphere with particle hair
head = add("Head", lib["uv_sphere"]("Head", 0.8, 24, 12, materials=[brown]), location=(-1.6, 0.2, 1.0))
head.modifiers.new("Hair", "PARTICLE_SYSTEM")
psys = head.particle_systems[0]
psys.seed = 5
ps = psys.settings
ps.type = "HAIR"
ps.count = N_HAIR
ps.hair_length = 0.7
ps.emit_from = "FACE"
ps.use_emit_random = True
ps.distribution = "RAND"
ps.child_type = "NONE"
ps.radius_scale = 0.05
ps.root_radius = 1.0
ps.tip_radius = 0.2
ps.use_close_tip = False
ps.display_step = ps.render_step = 3

# a Curves object: strands rising from a patch, bending away from the origin
fur_data = bpy.data.hair_curves.new("Fur")
fur_data.add_curves([KEYS] * N_STRANDS)
roots = np.column_stack([rng.uniform(-0.9, 0.9, (N_STRANDS, 2)), np.zeros(N_STRANDS)])
t = np.linspace(0.0, 1.0, KEYS)
lean = rng.uniform(0.2, 0.5, (N_STRANDS, 1)) * t ** 2
angle = rng.uniform(0, 2 * math.pi, (N_STRANDS, 1))
pos = np.stack([roots[:, None, 0] + lean * np.cos(angle), roots[:, None, 1] + lean * np.sin(angle),
                np.broadcast_to(1.1 * t, (N_STRANDS, KEYS))], axis=2)
fur_data.attributes["position"].data.foreach_set("vector", pos.astype(np.float32).ravel())
radius = fur_data.attributes.new("radius", "FLOAT", "POINT")
radius.data.foreach_set("value", np.tile(np.linspace(0.025, 0.008, KEYS), N_STRANDS).astype(np.float32))
fur_data.materials.append(blond)
add("Fur", fur_data, location=(1.6, -0.6, 0.0))

# a point cloud: mesh vertices turned into points by geometry nodes, radius from an attribute
cloud = bpy.data.meshes.new("Cloud")
cloud.vertices.add(N_POINTS)
cloud.vertices.foreach_set("co", (rng.uniform(-0.7, 0.7, (N_POINTS, 3)) + (0, 0, 0.9)).ravel())
r = cloud.attributes.new("r", "FLOAT", "POINT")
r.data.foreach_set("value", rng.uniform(0.03, 0.07, N_POINTS))
cloud.materials.append(teal)
lib["mesh_to_points"](add("Points", cloud, location=(0.2, 2.0, 0.0)), "r")

lib["add_sun"]("Sun", elevation=40, azimuth=30, energy=3.0)
lib["add_light"]("Point", "POINT", location=(-1.0, -3.0, 4.0), energy=1500.0)
lib["add_camera"](scene, (7, -7, 5.5), (0.0, 0.3, 0.6), lens=32)
