"""Smooth-shaded low-poly shapes on a ground, the meshes an artist's scene is made of: an 8-segment
UV sphere and a 10-sided cylinder shaded smooth, a Suzanne with one subdivision level, a torus
with a Weighted Normal modifier and a wall whose faces are flipped (normals against the camera);
a low sun (terminators across the shapes) and a point light; 320x240.

Every other built-in scene is flat-shaded: this one is where shading normals, custom normals and
flipped faces decide what Cycles shows (its shadow terminator, the back-facing flip).
"""
import math
import os
import runpy

import bmesh
import bpy
import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("smooth_shapes", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
grey = lib["material"]("Grey", (0.7, 0.7, 0.7))
lib["add_object"]("Ground", lib["plane"]("Ground", 14.0, materials=[lib["material"]("Ground", (0.6, 0.6, 0.6))]))


def from_bmesh(name, build, smooth=True, flip=False):
    """A mesh built by ``build(bm)`` with bmesh, shaded smooth (or flat), faces reversed if
    ``flip``."""
    bm = bmesh.new()
    build(bm)
    if flip:
        bmesh.ops.reverse_faces(bm, faces=bm.faces)
    me = bpy.data.meshes.new(name)
    bm.to_mesh(me)
    bm.free()
    me.polygons.foreach_set("use_smooth", np.full(len(me.polygons), smooth))
    me.update()
    me.materials.append(grey)
    return me


def torus(bm, major=1.0, minor=0.35, segments=12, sides=8):
    """A torus of quads around +Z."""
    a = 2 * np.pi * np.arange(segments) / segments
    b = 2 * np.pi * np.arange(sides) / sides
    verts = [bm.verts.new(((major + minor * math.cos(v)) * math.cos(u), (major + minor * math.cos(v)) * math.sin(u),
                           minor * math.sin(v))) for u in a for v in b]
    for i in range(segments):
        for j in range(sides):
            i1, j1 = (i + 1) % segments, (j + 1) % sides
            bm.faces.new((verts[i * sides + j], verts[i1 * sides + j], verts[i1 * sides + j1], verts[i * sides + j1]))


lib["add_object"]("Sphere", from_bmesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(
    bm, u_segments=8, v_segments=6, radius=1.0)), location=(-3.0, 1.5, 1.0))
lib["add_object"]("Cylinder", from_bmesh("Cylinder", lambda bm: bmesh.ops.create_cone(
    bm, cap_ends=True, segments=10, radius1=0.6, radius2=0.6, depth=2.0)), location=(0.0, 2.5, 1.0))
monkey = lib["add_object"]("Suzanne", from_bmesh("Suzanne", lambda bm: bmesh.ops.create_monkey(bm)),
                           location=(3.0, 1.0, 1.0), rotation=(0.0, 0.0, math.radians(200)))
subsurf = monkey.modifiers.new("Subdivision", "SUBSURF")
subsurf.levels = subsurf.render_levels = 1
ring = lib["add_object"]("Torus", from_bmesh("Torus", torus), location=(-1.5, -1.5, 0.6),
                         rotation=(math.radians(60), 0.0, 0.0))
ring.modifiers.new("WeightedNormal", "WEIGHTED_NORMAL")
lib["add_object"]("Wall", from_bmesh("Wall", lambda bm: bmesh.ops.create_cube(bm, size=1.0), smooth=False, flip=True),
                  location=(2.0, -2.0, 1.0), scale=(2.0, 0.2, 1.0))

lib["add_sun"]("Sun", elevation=18, azimuth=40, energy=3.0)
lib["add_light"]("Lamp", "POINT", location=(0.5, -0.5, 3.5), energy=600.0)
lib["add_camera"](scene, (9, -9, 6), (0, 0, 0.8), lens=35)
