"""Ray visibility and holdout as Cycles renders them: a box the camera does not see (it casts), a
box that casts nothing, a holdout sphere (a hole in the image that casts), a box in a holdout
collection and one in an indirect-only collection of the view layer, cones scattered by a hair
particle system whose emitter does not show in render (nor cast), a collection instance hidden
from shadow rays, and geometry-nodes posts whose instancer the camera does not see; a sun and a
point light. 320x240."""
import math
import os
import runpy

import bpy
import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("visibility", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
grey = lib["material"]("Grey", (0.6, 0.6, 0.6))
red = lib["material"]("Red", (0.8, 0.15, 0.1))
blue = lib["material"]("Blue", (0.1, 0.2, 0.8))
add, box = lib["add_object"], lib["box"]


def cone(name, radius, height, sides=16, materials=()):
    """A closed cone whose base is centred on the origin and whose apex points along +X (a hair
    particle instance's X axis follows its strand, here the emitter's normal)."""
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.zeros(sides), radius * np.cos(a), radius * np.sin(a)], axis=1)
    verts = np.concatenate([ring, [(height, 0, 0)]])
    apex = sides
    j = np.arange(sides)
    sides_loops = np.stack([j, (j + 1) % sides, np.full(sides, apex)], axis=1).ravel()
    loops = np.concatenate([sides_loops, j[::-1]])
    sizes = np.concatenate([np.full(sides, 3), [sides]])
    return lib["mesh"](name, verts, loops, sizes, materials=materials)


add("Ground", lib["plane"]("Ground", 16.0, materials=[grey]))

# Camera visibility off: not seen, casts
unseen = add("Unseen", box("Unseen", (1.0, 1.0, 2.0), base_at_origin=True, materials=[red]), location=(-2.5, -1.0, 0))
unseen.visible_camera = False
# Shadow visibility off: seen, casts nothing
shadowless = add("Shadowless", box("Shadowless", (1.2, 1.2, 1.6), base_at_origin=True, materials=[blue]),
                 location=(0.5, -2.5, 0))
shadowless.visible_shadow = False
# a holdout sphere: a hole in the image, casts
ball = add("Holdout", lib["uv_sphere"]("Ball", 0.8, 24, 12, materials=[red]), location=(1.8, 0.8, 0.8))
ball.is_holdout = True

# holdout and indirect-only collections of the view layer
mattes = bpy.data.collections.new("Mattes")
ghosts = bpy.data.collections.new("Ghosts")
scene.collection.children.link(mattes)
scene.collection.children.link(ghosts)
add("MatteBox", box("MatteBox", (0.8, 0.8, 1.2), base_at_origin=True, materials=[blue]), mattes,
    location=(-0.8, 2.4, 0))
add("GhostBox", box("GhostBox", (0.9, 0.9, 1.4), base_at_origin=True, materials=[blue]), ghosts,
    location=(3.2, -1.2, 0))
layers = scene.view_layers[0].layer_collection.children
layers["Mattes"].holdout = True
layers["Ghosts"].indirect_only = True

# cones scattered by a hair particle system; the emitter does not show in render (nor casts), the
# cone it instances is hidden from render (only its instances appear)
proto = add("Cone", cone("Cone", 0.35, 1.2, materials=[red]), location=(0, 0, 5))
proto.hide_render = True
emitter = add("Emitter", lib["plane"]("Emitter", 3.0, materials=[grey]), location=(-2.2, 2.6, 0.3))
emitter.modifiers.new("Scatter", "PARTICLE_SYSTEM")
psys = emitter.particle_systems[0]
psys.seed = 3
ps = psys.settings
ps.type = "HAIR"
ps.count = 10
ps.hair_length = 1.0
ps.emit_from = "FACE"
ps.use_emit_random = True
ps.distribution = "RAND"
ps.render_type = "OBJECT"
ps.instance_object = proto
ps.particle_size = 1.0
emitter.show_instancer_for_render = False

# a collection instance hidden from shadow rays (its objects cast through the instancer's flag)
arch = lib["hidden_collection"]("Arch")
add("Pillar", box("Pillar", (0.3, 0.3, 1.5), base_at_origin=True, materials=[grey]), arch, location=(-0.6, 0, 0))
add("Pillar.001", box("Pillar.001", (0.3, 0.3, 1.5), base_at_origin=True, materials=[grey]), arch, location=(0.6, 0, 0))
add("Lintel", box("Lintel", (1.6, 0.4, 0.3), materials=[grey]), arch, location=(0, 0, 1.65))
arch_inst = add("ArchInstance", None, location=(0.2, 0.2, 0), rotation=(0, 0, math.radians(20)))
arch_inst.instance_type, arch_inst.instance_collection = "COLLECTION", arch
arch_inst.visible_shadow = False

# geometry-nodes posts whose instancer the camera does not see: the posts cast, unseen
posts = lib["hidden_collection"]("Posts")
add("Post", box("Post", (0.2, 0.2, 1.8), base_at_origin=True, materials=[red]), posts)
post_points = [(4.0, 1.5, 0), (4.0, 2.5, 0), (4.0, 3.5, 0)]
lib["instance_on_points"]("PostRow", posts, post_points).visible_camera = False

lib["add_sun"]("Sun", elevation=38, azimuth=35, energy=3.0)
lib["add_light"]("Point", "POINT", location=(-1.0, -3.5, 4.5), energy=1500.0)
lib["add_camera"](scene, (9, -9, 7), (0.3, 0.3, 0.3), lens=30)
