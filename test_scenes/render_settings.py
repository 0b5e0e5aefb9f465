"""What a final render evaluates apart from the viewport, one difference per object, on a 12 m
plane under a sun (320x240):

- ``Render Only``: a column disabled in the viewports but rendered;
- ``Viewport Array``: a block whose Array modifier (three blocks) is enabled in the viewport only;
- ``Smooth``: a cube under a Subdivision Surface at level 0 in the viewport and 3 for render;
- ``Blob``: a metaball of two elements, polygonised at 0.5 m in the viewport and 0.15 m for render
  (``resolution`` / ``render_resolution``);
- ``Ring``: an upright bevelled Bézier circle of 4 spans, 2 segments per span in the viewport and
  12 for render (``resolution_u`` / ``render_resolution_u``);
- ``Crates``: an emitter (not shown itself) whose hair particle system instances the ``Crate``
  cube (hidden from render) at 12 points, of which the viewport shows a random 25 %
  (``display_percentage``); object instances rather than strands, which the export draws as tubes
  (their shadows differ from Cycles' round curves by about 1 % of the pixels);
- ``Stored``: a post in the collection ``Viewport Hidden``, disabled in the viewports
  (``Collection.hide_viewport``) but rendered;
- ``Switch Shape``: a Geometry Nodes modifier whose "Is Viewport" switch makes a cube in the
  viewport and an ico sphere (3 subdivisions) for render."""
import math
import os
import runpy

import bpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("render_settings", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
grey = lib["material"]("Grey", (0.6, 0.6, 0.6))
add, box = lib["add_object"], lib["box"]
add("Plane", lib["plane"]("Plane", 12.0, materials=[grey]))
column = add("Render Only", box("Column", (1.0, 1.0, 3.0), base_at_origin=True, materials=[grey]),
             location=(-3.0, 1.0, 0.0))
column.hide_viewport = True
block = add("Viewport Array", box("Block", (1.0, 1.0, 1.0), base_at_origin=True, materials=[grey]),
            location=(0.0, -1.5, 0.0))
array = block.modifiers.new("Array", "ARRAY")
array.count = 3
array.relative_offset_displace = (0.0, 1.5, 0.0)
array.show_render = False
smooth = add("Smooth", box("Rounded", (2.0, 2.0, 2.0), materials=[grey]), location=(3.0, 0.0, 1.2))
subsurf = smooth.modifiers.new("Subdivision", "SUBSURF")
subsurf.levels = 0
subsurf.render_levels = 3

# a metaball: coarse in the viewport, fine for render
mball = bpy.data.metaballs.new("Blob")
mball.resolution = 0.5
mball.render_resolution = 0.15
for co, radius in (((0.0, 0.0, 0.0), 0.9), ((0.2, 0.1, 0.8), 0.7)):
    element = mball.elements.new()
    element.co, element.radius = co, radius
mball.materials.append(grey)
add("Blob", mball, location=(-0.9, 3.6, 0.55))

# a bevelled curve: a ring standing upright, 2 segments per span in the viewport, 12 for render
curve = bpy.data.curves.new("Ring", "CURVE")
curve.dimensions = "3D"
curve.bevel_depth = 0.15
curve.bevel_resolution = 2
curve.resolution_u = 2
curve.render_resolution_u = 12
spline = curve.splines.new("BEZIER")
spline.bezier_points.add(3)
for k, point in enumerate(spline.bezier_points):
    a = k * math.pi / 2
    point.co = (0.8 * math.cos(a), 0.8 * math.sin(a), 0.0)
    point.handle_left_type = point.handle_right_type = "AUTO"
spline.use_cyclic_u = True
curve.materials.append(grey)
add("Ring", curve, location=(-1.4, -3.6, 0.95), rotation=(math.radians(90), 0.0, math.radians(-20)))

# a hair particle system instancing a cube at 12 points; the viewport shows a quarter (the cube is
# centred, so it is the same whichever axis a hair instance turns up)
crate = add("Crate", box("Crate", (0.35, 0.35, 0.35), materials=[grey]), location=(0.0, 0.0, -5.0))
crate.hide_render = True
emitter = add("Crates", lib["plane"]("Crates", 2.4, materials=[grey]), location=(4.3, -3.4, 0.175))
emitter.modifiers.new("Particles", "PARTICLE_SYSTEM")
psys = emitter.particle_systems[0]
psys.seed = 4
particles = psys.settings
particles.type = "HAIR"
particles.count = 12
particles.hair_length = 1.0
particles.emit_from = "FACE"
particles.distribution = "JIT"
particles.use_emit_random = False
particles.render_type = "OBJECT"
particles.instance_object = crate
particles.particle_size = 1.0
particles.display_percentage = 25
emitter.show_instancer_for_render = emitter.show_instancer_for_viewport = False

# a collection disabled in the viewports, rendered
stored = bpy.data.collections.new("Viewport Hidden")
scene.collection.children.link(stored)
stored.hide_viewport = True
add("Stored", box("Post", (0.8, 0.8, 1.6), base_at_origin=True, materials=[grey]), stored, location=(4.5, 3.5, 0.0))

# Geometry Nodes: "Is Viewport" switches between a cube (viewport) and an ico sphere (render)
tree = bpy.data.node_groups.new("Viewport Switch", "GeometryNodeTree")
tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
nodes, links = tree.nodes, tree.links
nodes.new("NodeGroupInput")
out = nodes.new("NodeGroupOutput")
is_viewport = nodes.new("GeometryNodeIsViewport")
cube = nodes.new("GeometryNodeMeshCube")
cube.inputs["Size"].default_value = (1.2, 1.2, 1.2)
ico = nodes.new("GeometryNodeMeshIcoSphere")
ico.inputs["Radius"].default_value = 0.7
ico.inputs["Subdivisions"].default_value = 3
switch = nodes.new("GeometryNodeSwitch")
switch.input_type = "GEOMETRY"  # (Blender 5's default is a float switch)
links.new(is_viewport.outputs["Is Viewport"], switch.inputs["Switch"])
links.new(cube.outputs["Mesh"], switch.inputs["True"])
links.new(ico.outputs["Mesh"], switch.inputs["False"])
links.new(switch.outputs["Output"], out.inputs[0])
shape = add("Switch Shape", bpy.data.meshes.new("Switch Shape"), location=(1.4, -3.8, 0.7))  # (input unused)
shape.modifiers.new("Viewport Switch", "NODES").node_group = tree

lib["add_sun"]("Sun", elevation=35, azimuth=-60, energy=3.0)
lib["add_camera"](scene, (0.0, -12.0, 8.0), (0.0, 0.0, 0.5), lens=30)
