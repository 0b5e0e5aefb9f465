"""Small Blender scenes for the export tests: an empty scene with a camera, objects, a cube mesh,
geometry-nodes instancers, and the export of the current depsgraph."""
import bpy
import numpy as np

from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.core.scene import Scene


def empty_scene():
    """A factory-settings empty scene with a camera "Cam"."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.camera = add_object("Cam", bpy.data.cameras.new("Cam"), location=(0, -10, 2))
    return sc


def add_object(name, data, collection=None, location=(0, 0, 0)):
    """A new object of ``data`` linked to ``collection`` (default: the scene's) at ``location``."""
    ob = bpy.data.objects.new(name, data)
    (collection or bpy.context.scene.collection).objects.link(ob)
    ob.location = location
    return ob


def cube_mesh(name="cube"):
    """A 2 m cube of six quads centred at the origin."""
    me = bpy.data.meshes.new(name)
    v = [(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
    f = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    me.from_pydata(v, [], f)
    return me


def export_scene(**kw) -> Scene:
    """The export of the current evaluated depsgraph."""
    return export_depsgraph(bpy.context.evaluated_depsgraph_get(), **kw)


def gn_instancer(name, points, instance_node):
    """A mesh object of ``points`` whose node tree instances ``instance_node``'s geometry on them."""
    pts = bpy.data.meshes.new(name)
    pts.vertices.add(len(points))
    pts.vertices.foreach_set("co", np.asarray(points, np.float32).ravel())
    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    iop = tree.nodes.new("GeometryNodeInstanceOnPoints")
    source = instance_node(tree)
    tree.links.new(gin.outputs[0], iop.inputs["Points"])
    tree.links.new(source, iop.inputs["Instance"])
    tree.links.new(iop.outputs[0], gout.inputs[0])
    ob = add_object(name, pts)
    ob.modifiers.new("GN", "NODES").node_group = tree
    return ob


def object_info(target, as_instance):
    """An ``instance_node`` for :func:`gn_instancer`: an Object Info node reading ``target``."""
    def make(tree):
        node = tree.nodes.new("GeometryNodeObjectInfo")
        node.inputs["Object"].default_value = target
        node.inputs["As Instance"].default_value = as_instance
        return node.outputs["Geometry"]
    return make


def row(s, name):
    """The instance row named ``name``."""
    return s.instances.names.index(name)
