"""Builders shared by the built-in scene scripts: numpy meshes, materials, lights, camera, world,
geometry-nodes instancing. Not a scene itself (the leading ``_`` hides it from the scene list).

A script loads it with ``runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))``
and uses the returned dict.
"""
import math

import bpy
import numpy as np
from mathutils import Vector


# --------------------------------------------------------------------------------------------
# Scene set-up
# --------------------------------------------------------------------------------------------
def setup_scene(name, resolution, frames=(1, 1)):
    """The current scene, renamed, at ``resolution`` (100 %) and frame range ``frames``."""
    scene = bpy.context.scene
    scene.name = name
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.frame_start, scene.frame_end = frames
    scene.frame_current = frames[0]
    return scene


def set_world(scene, color, strength=1.0):
    """A world whose Background node has ``color`` × ``strength``."""
    world = bpy.data.worlds.new(f"{scene.name} world")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    world.color = color
    scene.world = world
    return world


def material(name, color, roughness=0.5, specular=0.5):
    """A Principled BSDF material (base colour RGB, roughness, Specular IOR Level)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Specular IOR Level"].default_value = specular
    mat.diffuse_color = (*color, 1.0)
    return mat


def add_object(name, data, collection=None, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1)):
    """A new object linked to ``collection`` (default: the scene's)."""
    ob = bpy.data.objects.new(name, data)
    (collection or bpy.context.scene.collection).objects.link(ob)
    ob.location, ob.rotation_euler, ob.scale = location, rotation, scale
    return ob


def aim(ob, target):
    """Point the object's -Z axis at ``target`` with +Y up."""
    direction = Vector(target) - Vector(ob.location)
    ob.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def add_light(name, kind, location=(0, 0, 0), target=None, energy=1000.0, color=(1, 1, 1), **props):
    """A light object; ``target`` aims it, ``props`` set light data attributes."""
    light = bpy.data.lights.new(name, kind)
    light.energy, light.color = energy, color
    for key, value in props.items():
        setattr(light, key, value)
    ob = add_object(name, light, location=location)
    if target is not None:
        aim(ob, target)
    return ob


def add_sun(name, elevation, azimuth, energy=3.0, color=(1, 1, 1), angle=math.radians(0.53)):
    """A sun ``elevation`` degrees above the horizon, shining from ``azimuth`` degrees (0 = +X,
    counter-clockwise) towards the origin."""
    e, a = math.radians(elevation), math.radians(azimuth)
    source = (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))
    ob = add_light(name, "SUN", location=tuple(10 * c for c in source), energy=energy, color=color, angle=angle)
    aim(ob, (0, 0, 0))
    return ob


def add_camera(scene, location, target, lens=35.0, clip=(0.1, 1000.0)):
    """A perspective camera at ``location`` looking at ``target``, made the scene camera."""
    cam = bpy.data.cameras.new("Camera")
    cam.lens = lens
    cam.clip_start, cam.clip_end = clip
    ob = add_object("Camera", cam, location=location)
    aim(ob, target)
    scene.camera = ob
    return ob


# --------------------------------------------------------------------------------------------
# Meshes from numpy arrays
# --------------------------------------------------------------------------------------------
def mesh(name, verts, loops, sizes=None, materials=()):
    """A flat-shaded mesh from vertices (V, 3) and polygons: ``loops`` (F, k) for k-gons only,
    or flat vertex indices with per-polygon ``sizes``."""
    verts = np.asarray(verts, np.float32).reshape(-1, 3)
    loops = np.asarray(loops, np.int32)
    if sizes is None:
        sizes = np.full(len(loops), loops.shape[1], np.int32)
    loops = loops.ravel()
    sizes = np.asarray(sizes, np.int32)
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(verts))
    me.vertices.foreach_set("co", verts.ravel())
    me.loops.add(len(loops))
    me.loops.foreach_set("vertex_index", loops)
    me.polygons.add(len(sizes))
    me.polygons.foreach_set("loop_start", np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32))
    # flat shading (Blender >= 4.1 makes new faces smooth): the renderer shades with face
    # normals, so Cycles must too for the comparison to measure shadows, not shading
    me.polygons.foreach_set("use_smooth", np.zeros(len(sizes), bool))
    me.update(calc_edges=True)
    for mat in materials:
        me.materials.append(mat)
    return me


def grid_quads(nx, ny):
    """Quads (nx*ny, 4) of a row-major grid of (ny + 1) x (nx + 1) vertices."""
    a = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]).ravel()
    return np.stack([a, a + 1, a + nx + 2, a + nx + 1], axis=1)


def heightfield(name, size, n, height, materials=()):
    """A square ``size`` m terrain of n x n quads centred on the origin, z = height(x, y)."""
    t = np.linspace(-size / 2, size / 2, n + 1)
    x, y = np.meshgrid(t, t)
    verts = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], axis=1)
    return mesh(name, verts, grid_quads(n, n), materials=materials)


def plane(name, size, materials=()):
    h = size / 2
    return mesh(name, [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [[0, 1, 2, 3]], materials=materials)


def box(name, size=(1, 1, 1), base_at_origin=False, materials=()):
    """An axis-aligned box centred on the origin (or standing on it)."""
    sx, sy, sz = (s / 2 for s in size)
    z0, z1 = (0, 2 * sz) if base_at_origin else (-sz, sz)
    verts = [(-sx, -sy, z0), (sx, -sy, z0), (sx, sy, z0), (-sx, sy, z0),
             (-sx, -sy, z1), (sx, -sy, z1), (sx, sy, z1), (-sx, sy, z1)]
    faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    return mesh(name, verts, faces, materials=materials)


def uv_sphere(name, radius=1.0, segments=16, rings=8, noise=0.0, seed=0, materials=()):
    """A UV sphere: 2 * segments * (rings - 1) triangles. ``noise`` jitters radii (rocks)."""
    s, r = max(3, segments), max(2, rings)
    theta = np.pi * np.arange(1, r) / r
    phi = 2 * np.pi * np.arange(s) / s
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1).reshape(-1, 3)
    verts = np.concatenate([ring, [(0, 0, 1), (0, 0, -1)]]) * radius
    if noise:
        verts *= 1 + noise * np.random.default_rng(seed).uniform(-1, 1, (len(verts), 1))
    top, bottom = len(ring), len(ring) + 1
    j = np.arange(s)
    jn = (j + 1) % s
    rows = np.arange(r - 2)[:, None] * s
    quads = np.stack([rows + j, rows + s + j, rows + s + jn, rows + jn], axis=-1).reshape(-1, 4)
    top_fan = np.stack([np.full(s, top), j, jn], axis=1)
    last = (r - 2) * s
    bottom_fan = np.stack([np.full(s, bottom), last + jn, last + j], axis=1)
    loops = np.concatenate([top_fan.ravel(), quads.ravel(), bottom_fan.ravel()])
    sizes = np.concatenate([np.full(s, 3), np.full(len(quads), 4), np.full(s, 3)])
    return mesh(name, verts, loops, sizes, materials=materials)


def sphere_for_triangles(name, triangles, radius=1.0, noise=0.0, seed=0, materials=()):
    """A UV sphere with about ``triangles`` triangles (at least 6)."""
    m = max(1, round(math.sqrt(triangles / 4)))
    return uv_sphere(name, radius, round(triangles / (2 * m)), m + 1, noise, seed, materials)


def _tube(centres, radii, sides):
    """Vertices and quads of a tube along ``centres`` (n, 3) with ``radii`` (n,), in xy rings."""
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(a), np.sin(a), np.zeros(sides)], axis=1)
    verts = (centres[:, None, :] + radii[:, None, None] * ring[None]).reshape(-1, 3)
    n = len(centres)
    j = np.arange(sides)
    rows = np.arange(n - 1)[:, None] * sides
    quads = np.stack([rows + j, rows + (j + 1) % sides, rows + sides + (j + 1) % sides, rows + sides + j], -1)
    return verts, quads.reshape(-1, 4)


def palm(name, seed, materials=()):
    """A palm-like tree (about 1.5-3k triangles): a bent tapered trunk and drooping fronds, each a
    V-shaped strip with leaflet fringes. Base at the origin, trunk along +Z."""
    rng = np.random.default_rng(seed)
    height = rng.uniform(6, 10)
    bend = rng.uniform(0.5, 2.0)
    segs, sides = 24, int(rng.integers(10, 15))
    t = np.linspace(0, 1, segs + 1)
    centres = np.stack([bend * t ** 2, np.zeros_like(t), height * t], axis=1)
    verts, quads = _tube(centres, 0.25 * (1 - 0.45 * t), sides)
    parts_v, parts_q, offset = [verts], [quads], len(verts)
    crown = centres[-1]
    fronds = int(rng.integers(8, 13))
    fs = 20  # segments per frond
    s = np.linspace(0, 1, fs + 1)
    for k in range(fronds):
        phi = 2 * np.pi * (k + rng.uniform(-0.2, 0.2)) / fronds
        length = rng.uniform(3, 4.5)
        d = np.array([math.cos(phi), math.sin(phi), 0.0])
        side = np.array([-d[1], d[0], 0.0])
        spine = crown + np.outer(length * s, d) + np.outer(length * (0.45 * s - 0.9 * s ** 2), [0, 0, 1])
        width = 0.6 * np.sin(np.pi * np.clip(s, 0.05, 1))[:, None]
        down = np.array([0, 0, -1.0])
        cross = np.stack([spine - width * side + 1.2 * width * down,
                          spine - 0.5 * width * side + 0.2 * width * down,
                          spine,
                          spine + 0.5 * width * side + 0.2 * width * down,
                          spine + width * side + 1.2 * width * down], axis=1)  # (fs + 1, 5, 3)
        a = (np.arange(fs)[:, None] * 5 + np.arange(4)[None, :]).ravel()
        parts_v.append(cross.reshape(-1, 3))
        parts_q.append(np.stack([a, a + 5, a + 6, a + 1], axis=1) + offset)
        offset += cross.shape[0] * 5
    return mesh(name, np.concatenate(parts_v), np.concatenate(parts_q), materials=materials)


# --------------------------------------------------------------------------------------------
# Placement
# --------------------------------------------------------------------------------------------
def jittered_points(rng, count, size, density=None):
    """``count`` (x, y) points spread evenly over a ``size`` m square centred on the origin: one
    per cell of a jittered grid, cells picked with weights ``density(x, y)`` (default uniform)."""
    n = max(1, math.ceil(math.sqrt(count * 1.5)))
    cell = size / n
    c = (np.arange(n) + 0.5) * cell - size / 2
    cx, cy = (a.ravel() for a in np.meshgrid(c, c))
    w = np.ones_like(cx) if density is None else density(cx, cy)
    pick = rng.choice(len(cx), size=min(count, len(cx)), replace=False, p=w / w.sum())
    jitter = rng.uniform(-0.4, 0.4, (len(pick), 2)) * cell
    return np.stack([cx[pick], cy[pick]], axis=1) + jitter


def instance_on_points(name, collection, positions, rotations=None, scales=None, variants=None):
    """A mesh object whose geometry nodes put one instance of the ``collection``'s children on
    each of ``positions`` (N, 3): child ``variants[i]``, Euler ``rotations[i]``, ``scales[i]``."""
    n = len(positions)
    pts = bpy.data.meshes.new(f"{name} points")
    pts.vertices.add(n)
    pts.vertices.foreach_set("co", np.asarray(positions, np.float32).ravel())
    for attr, kind, field, values, default in (
            ("rot", "FLOAT_VECTOR", "vector", rotations, np.zeros((n, 3))),
            ("scale", "FLOAT", "value", scales, np.ones(n)),
            ("variant", "INT", "value", variants, np.zeros(n))):
        data = np.asarray(default if values is None else values)
        pts.attributes.new(attr, kind, "POINT").data.foreach_set(
            field, data.astype(np.int32 if kind == "INT" else np.float32).ravel())
    tree = bpy.data.node_groups.new(f"{name} instancing", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, link = tree.nodes, tree.links.new
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    iop = nodes.new("GeometryNodeInstanceOnPoints")
    info = nodes.new("GeometryNodeCollectionInfo")
    info.inputs["Collection"].default_value = collection
    info.inputs["Separate Children"].default_value = True
    info.inputs["Reset Children"].default_value = True
    iop.inputs["Pick Instance"].default_value = True

    def named(attr, kind):
        node = nodes.new("GeometryNodeInputNamedAttribute")
        node.data_type = kind
        node.inputs["Name"].default_value = attr
        return node.outputs["Attribute"]

    euler = nodes.new("FunctionNodeEulerToRotation")
    link(named("rot", "FLOAT_VECTOR"), euler.inputs[0])
    link(gin.outputs[0], iop.inputs["Points"])
    link(info.outputs[0], iop.inputs["Instance"])
    link(named("variant", "INT"), iop.inputs["Instance Index"])
    link(euler.outputs[0], iop.inputs["Rotation"])
    link(named("scale", "FLOAT"), iop.inputs["Scale"])
    link(iop.outputs[0], gout.inputs[0])
    ob = add_object(name, pts)
    ob.modifiers.new("Instances", "NODES").node_group = tree
    return ob


def hidden_collection(name):
    """A collection not linked to the scene: holds instancing sources that do not render."""
    return bpy.data.collections.new(name)


# --------------------------------------------------------------------------------------------
# Image textures and UV-mapped materials
# --------------------------------------------------------------------------------------------
def image_from_array(name, rgba, colorspace="sRGB"):
    """A packed byte image from ``rgba`` (H, W, 4) floats 0..1, row 0 at the bottom (Blender's
    order); packed so that it survives saving the .blend."""
    rgba = np.clip(np.asarray(rgba, np.float32), 0.0, 1.0)
    h, w = rgba.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=True)
    img.colorspace_settings.name = colorspace
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    return img


def set_uvs(me, uvs, name="UVMap"):
    """A UV map of ``uvs`` (one (u, v) per loop, in loop order) on mesh ``me``."""
    layer = me.uv_layers.new(name=name)
    layer.uv.foreach_set("vector", np.asarray(uvs, np.float32).ravel())
    return layer


def uv_quad(name, size_x, size_y, upright=False, base_at_origin=False, materials=()):
    """A ``size_x`` x ``size_y`` quad with UVs 0..1 (u along x, v along y or, ``upright``, along
    z: it then stands in the xz plane facing -y). Centred on the origin, or with its bottom edge
    on it (``base_at_origin``)."""
    hx, hy = size_x / 2, size_y / 2
    y0, y1 = (0.0, size_y) if base_at_origin else (-hy, hy)
    if upright:
        verts = [(-hx, 0, y0), (hx, 0, y0), (hx, 0, y1), (-hx, 0, y1)]
    else:
        verts = [(-hx, y0, 0), (hx, y0, 0), (hx, y1, 0), (-hx, y1, 0)]
    me = mesh(name, verts, [[0, 1, 2, 3]], materials=materials)
    set_uvs(me, [(0, 0), (1, 0), (1, 1), (0, 1)])
    return me


def textured_material(name, image, color=(0.8, 0.8, 0.8), use_color=True, use_alpha=True, alpha_from="Alpha",
                      scale=None, extension="REPEAT", interpolation="Linear", roughness=0.5, specular=0.5):
    """A Principled BSDF material reading ``image`` at the mesh's UVs: Base Color from its Color
    output (``use_color``; else ``color``), Alpha from its ``alpha_from`` output ("Alpha" or
    "Color"; ``use_alpha``). ``scale`` (su, sv): a Mapping node (point) repeating the image."""
    mat = material(name, color, roughness, specular)
    nodes, link = mat.node_tree.nodes, mat.node_tree.links.new
    bsdf = nodes["Principled BSDF"]
    tex = nodes.new("ShaderNodeTexImage")
    tex.image, tex.extension, tex.interpolation = image, extension, interpolation
    if scale is not None:
        coords = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        mapping.vector_type = "POINT"
        mapping.inputs["Scale"].default_value = (scale[0], scale[1], 1.0)
        link(coords.outputs["UV"], mapping.inputs["Vector"])
        link(mapping.outputs["Vector"], tex.inputs["Vector"])
    if use_color:
        link(tex.outputs["Color"], bsdf.inputs["Base Color"])
    if use_alpha:
        link(tex.outputs[alpha_from], bsdf.inputs["Alpha"])
    if hasattr(mat, "use_transparent_shadow"):  # EEVEE's setting (Cycles' shadows are always transparent)
        mat.use_transparent_shadow = True
    return mat


def mesh_to_points(ob, radius_attribute):
    """Turn mesh object ``ob`` into a point cloud with a geometry-nodes modifier: a point per
    vertex, its radius from the float point attribute ``radius_attribute``."""
    tree = bpy.data.node_groups.new("ToPoints", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    to_points = tree.nodes.new("GeometryNodeMeshToPoints")
    named = tree.nodes.new("GeometryNodeInputNamedAttribute")
    named.inputs["Name"].default_value = radius_attribute
    tree.links.new(gin.outputs[0], to_points.inputs["Mesh"])
    tree.links.new(named.outputs["Attribute"], to_points.inputs["Radius"])
    tree.links.new(to_points.outputs[0], gout.inputs[0])
    ob.modifiers.new("ToPoints", "NODES").node_group = tree
    return ob
