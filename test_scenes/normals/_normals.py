"""Helpers shared by the shading-normal scenes (hidden from the scene list by the leading ``_``).

``lib()`` returns ``test_scenes/_lib.py``'s builders plus:

- ``stage(name, PARAMS)``: the scene (320x240 by default), a dark world, a grey material and a
  flat 14 m ground; returns ``(scene, grey)``;
- ``from_bmesh(name, build, material, smooth=True, flip=False)``: a mesh built by
  ``build(bm)``, shaded smooth (or flat), faces reversed if ``flip`` (triangulated first, along
  fixed diagonals: Blender's own split of a reversed quad whose diagonals are equally long varies
  from run to run, and with it the interpolated normals);
- ``torus(bm, ...)``, ``slab(bm, ...)``: bmesh builders the stock operators lack;
- ``set_custom_normals(me, fn)``: custom corner normals ``fn(positions, smooth_normals)``
  (both (L, 3), per loop) through ``Mesh.normals_split_custom_set``;
- ``roundtrip(objects, fmt)``: the objects written by Blender's own glTF or OBJ exporter to a
  temporary folder, deleted, and read back by its importer: the new objects, whose custom normals
  are the file's;
- ``exchange_set(grey)``: the objects the round-trip scenes send through a file: a smooth 8x6 UV
  sphere, a chamfered box with a Weighted Normal modifier, a slab with fanned custom normals, a
  smooth cylinder with reversed winding and a Suzanne with one subdivision level.
"""
import math
import os
import runpy
import tempfile

import bmesh
import bpy
import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))


def lib():
    L = runpy.run_path(os.path.join(_HERE, "..", "_lib.py"))

    def stage(name, params, default=(320, 240)):
        size = int(params.get("width", default[0])), int(params.get("height", default[1]))
        scene = L["setup_scene"](name, size)
        L["set_world"](scene, (0.05, 0.06, 0.08))
        grey = L["material"]("Grey", (0.7, 0.7, 0.7))
        L["add_object"]("Ground", L["plane"]("Ground", 14.0, materials=[L["material"]("Ground", (0.6, 0.6, 0.6))]))
        return scene, grey

    def from_bmesh(name, build, material, smooth=True, flip=False):
        bm = bmesh.new()
        build(bm)
        if flip:
            bmesh.ops.triangulate(bm, faces=bm.faces, quad_method="FIXED", ngon_method="EAR_CLIP")
            bmesh.ops.reverse_faces(bm, faces=bm.faces)
        me = bpy.data.meshes.new(name)
        bm.to_mesh(me)
        bm.free()
        me.polygons.foreach_set("use_smooth", np.full(len(me.polygons), smooth))
        me.update()
        me.materials.append(material)
        return me

    def torus(bm, major=1.0, minor=0.35, segments=12, sides=8):
        """A torus of quads around +Z."""
        a = 2 * np.pi * np.arange(segments) / segments
        b = 2 * np.pi * np.arange(sides) / sides
        verts = [bm.verts.new(((major + minor * math.cos(v)) * math.cos(u),
                               (major + minor * math.cos(v)) * math.sin(u), minor * math.sin(v)))
                 for u in a for v in b]
        for i in range(segments):
            for j in range(sides):
                i1, j1 = (i + 1) % segments, (j + 1) % sides
                bm.faces.new((verts[i * sides + j], verts[i1 * sides + j], verts[i1 * sides + j1],
                              verts[i * sides + j1]))

    def slab(bm, size=(3.0, 3.0, 0.5), cuts=3):
        """A box standing on z = 0, its faces cut ``cuts`` times (interior vertices to carry
        custom normals)."""
        bmesh.ops.create_cube(bm, size=1.0)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges, cuts=cuts, use_grid_fill=True)
        for v in bm.verts:
            v.co = (v.co.x * size[0], v.co.y * size[1], (v.co.z + 0.5) * size[2])

    def set_custom_normals(me, fn):
        n_loops = len(me.loops)
        vi = np.empty(n_loops, np.int32)
        me.loops.foreach_get("vertex_index", vi)
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        smooth = np.empty(n_loops * 3, np.float32)
        me.corner_normals.foreach_get("vector", smooth)
        n = np.asarray(fn(co.reshape(-1, 3)[vi].astype(np.float64), smooth.reshape(-1, 3).astype(np.float64)))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        me.normals_split_custom_set([tuple(v) for v in n])
        me.update()
        return me

    def roundtrip(objects, fmt):
        """``fmt``: ``"gltf"`` (binary .glb, modifiers applied, normals written) or ``"obj"``."""
        addon = "io_scene_gltf2"
        if fmt == "gltf" and not hasattr(bpy.ops.export_scene, "gltf"):
            import addon_utils
            addon_utils.enable(addon, default_set=True)
        names = {ob.name: ob for ob in objects}
        bpy.ops.object.select_all(action="DESELECT")
        for ob in objects:
            ob.select_set(True)
        bpy.context.view_layer.objects.active = objects[0]
        with tempfile.TemporaryDirectory(prefix="hs-roundtrip-") as tmp:
            path = os.path.join(tmp, "meshes." + ("glb" if fmt == "gltf" else "obj"))
            if fmt == "gltf":
                bpy.ops.export_scene.gltf(filepath=path, export_format="GLB", use_selection=True, export_apply=True,
                                          export_normals=True, export_materials="NONE", export_animations=False)
            else:
                bpy.ops.wm.obj_export(filepath=path, export_selected_objects=True, apply_modifiers=True,
                                      export_normals=True, export_uv=False, export_materials=False,
                                      export_smooth_groups=False)
            for name in names:
                bpy.data.objects.remove(bpy.data.objects[name], do_unlink=True)
            before = set(bpy.data.objects)
            if fmt == "gltf":
                bpy.ops.import_scene.gltf(filepath=path)
            else:
                bpy.ops.wm.obj_import(filepath=path)
        return [ob for ob in bpy.data.objects if ob not in before and ob.type == "MESH"]

    def exchange_set(grey):
        add = L["add_object"]

        def chamfered_box(bm):
            bmesh.ops.create_cube(bm, size=1.4)
            bmesh.ops.bevel(bm, geom=list(bm.edges) + list(bm.verts), offset=0.2, segments=1, affect="EDGES")

        sphere = add("Sphere", from_bmesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(
            bm, u_segments=8, v_segments=6, radius=0.9), grey), location=(-2.8, 1.4, 0.9))
        box = add("Box", from_bmesh("Box", chamfered_box, grey), location=(0.2, 2.2, 0.7), rotation=(0, 0, 0.4))
        box.modifiers.new("WeightedNormal", "WEIGHTED_NORMAL").keep_sharp = True
        slab_me = from_bmesh("Slab", lambda bm: slab(bm, (2.4, 1.8, 0.4), cuts=2), grey)
        set_custom_normals(slab_me, lambda p, n: p - np.array([0.0, 0.0, -0.2]))
        slab_ob = add("Slab", slab_me, location=(2.6, 0.4, 0.0), rotation=(0, 0, -0.3))
        cyl = add("Cylinder", from_bmesh("Cylinder", lambda bm: bmesh.ops.create_cone(
            bm, cap_ends=True, segments=10, radius1=0.5, radius2=0.5, depth=1.8), grey, flip=True),
            location=(-1.0, -1.6, 0.9))
        monkey = add("Suzanne", from_bmesh("Suzanne", lambda bm: bmesh.ops.create_monkey(bm), grey),
                     location=(1.4, -1.8, 0.9), rotation=(0.0, 0.0, math.radians(200)))
        sub = monkey.modifiers.new("Subdivision", "SUBSURF")
        sub.levels = sub.render_levels = 1
        return [sphere, box, slab_ob, cyl, monkey]

    L.update(stage=stage, exchange_set=exchange_set, from_bmesh=from_bmesh, torus=torus, slab=slab,
             set_custom_normals=set_custom_normals,
             roundtrip=roundtrip)
    return L
