"""Shader-node materials: what Cycles draws and casts for set-ups other than a Principled BSDF.

On a grey ground, in front of the camera: a leaf card cut by a Mix Shader of a Transparent and a
Diffuse BSDF whose factor is a leaf image's alpha (inside a node group), a Principled pane with
Alpha 0.3, a box with a Diffuse BSDF, a box with an Emission shader, a Glass sphere (a mesh) and a
veil with a Transparent BSDF alone. A sun and a point light cast their shadows on the ground.
The world is a Sky Texture (its average colour is the ambient term). 320x240.

PARAMS: ``width``, ``height``.
"""
import os
import runpy

import bpy
import numpy as np

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("materials", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
world = lib["set_world"](scene, (0.05, 0.06, 0.08))
sky = world.node_tree.nodes.new("ShaderNodeTexSky")
world.node_tree.links.new(sky.outputs["Color"], world.node_tree.nodes["Background"].inputs["Color"])
world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.2


def leaf_alpha(w=64, h=96):
    """A pointed leaf along v, alpha strictly 0 or 1 (no pixel centre sees a fractional alpha)."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    U, V = np.meshgrid(u, v)
    t = (V - 0.05) / 0.9
    half = 0.9 * np.sin(np.pi * np.clip(t, 0, 1)) ** 0.7
    inside = (half - np.abs(2 * U - 1) > 0) & (np.hypot(U - 0.6, V - 0.55) > 0.08)
    rgba = np.zeros((h, w, 4))
    rgba[..., 1] = 0.5
    rgba[..., 3] = inside
    return rgba


def node_material(name):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    return mat, nodes, mat.node_tree.links.new, nodes["Material Output"]


# the leaf: Mix(Transparent, Diffuse) by the image's alpha, inside a node group
leaf_mat, nodes, link, out = node_material("Leaf")
group = bpy.data.node_groups.new("Leaf cut", "ShaderNodeTree")
group.interface.new_socket("Alpha", in_out="INPUT", socket_type="NodeSocketFloat")
group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
mix = group.nodes.new("ShaderNodeMixShader")
clear = group.nodes.new("ShaderNodeBsdfTransparent")
diffuse = group.nodes.new("ShaderNodeBsdfDiffuse")
diffuse.inputs["Color"].default_value = (0.1, 0.5, 0.08, 1)
group.links.new(gin.outputs["Alpha"], mix.inputs["Fac"])
group.links.new(clear.outputs[0], mix.inputs[1])
group.links.new(diffuse.outputs[0], mix.inputs[2])
group.links.new(mix.outputs[0], gout.inputs["Shader"])
tex = nodes.new("ShaderNodeTexImage")
tex.image = lib["image_from_array"]("leaf", leaf_alpha())
tex.interpolation = "Closest"
gnode = nodes.new("ShaderNodeGroup")
gnode.node_tree = group
link(tex.outputs["Alpha"], gnode.inputs["Alpha"])
link(gnode.outputs["Shader"], out.inputs["Surface"])

# the pane: Principled, Alpha 0.3
pane_mat = lib["material"]("Pane", (0.2, 0.4, 0.8))
pane_mat.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.3

diffuse_mat, nodes, link, out = node_material("Clay")
d = nodes.new("ShaderNodeBsdfDiffuse")
d.inputs["Color"].default_value = (0.7, 0.35, 0.2, 1)
link(d.outputs[0], out.inputs["Surface"])

emit_mat, nodes, link, out = node_material("Panel")
e = nodes.new("ShaderNodeEmission")
e.inputs["Color"].default_value = (1.0, 0.6, 0.2, 1)
e.inputs["Strength"].default_value = 0.5
link(e.outputs[0], out.inputs["Surface"])

glass_mat, nodes, link, out = node_material("Glass")
g = nodes.new("ShaderNodeBsdfGlass")
g.inputs["Color"].default_value = (0.8, 0.9, 1.0, 1)
link(g.outputs[0], out.inputs["Surface"])

veil_mat, nodes, link, out = node_material("Veil")
t = nodes.new("ShaderNodeBsdfTransparent")
link(t.outputs[0], out.inputs["Surface"])

lib["add_object"]("Ground", lib["plane"]("Ground", 14.0, materials=[lib["material"]("Ground", (0.6, 0.6, 0.6))]))
lib["add_object"]("Leaf card", lib["uv_quad"]("Leaf card", 1.4, 2.0, upright=True, base_at_origin=True,
                                              materials=[leaf_mat]), location=(-2.4, 0.5, 0.2))
lib["add_object"]("Pane", lib["uv_quad"]("Pane", 1.2, 1.6, upright=True, base_at_origin=True,
                                         materials=[pane_mat]), location=(-0.8, -0.4, 0.0))
lib["add_object"]("Clay box", lib["box"]("Clay box", (0.9, 0.9, 0.9), base_at_origin=True, materials=[diffuse_mat]),
                  location=(0.8, 1.2, 0.0))
lib["add_object"]("Panel box", lib["box"]("Panel box", (0.6, 0.6, 1.2), base_at_origin=True, materials=[emit_mat]),
                  location=(2.4, -0.2, 0.0))
lib["add_object"]("Glass ball", lib["uv_sphere"]("Glass ball", 0.6, 24, 12, materials=[glass_mat]),
                  location=(0.6, -1.4, 0.6))
lib["add_object"]("Veil", lib["uv_quad"]("Veil", 1.6, 1.4, upright=True, base_at_origin=True,
                                         materials=[veil_mat]), location=(-1.2, 2.2, 0.0))
lib["add_sun"]("Sun", elevation=40, azimuth=200, energy=3.0)
lib["add_light"]("Lamp", "POINT", location=(1.5, -3.0, 3.5), energy=1200.0)
lib["add_camera"](scene, (6.0, -7.5, 4.5), (0.0, 0.3, 0.6), lens=32, clip=(0.1, 100.0))
