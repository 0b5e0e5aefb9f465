"""Helpers shared by the third-party model scenes (hidden from the scene list by the leading ``_``).

``lib()`` returns ``test_scenes/_lib.py``'s builders plus ``import_gltf(path, material)``: the
file read by Blender's glTF importer with its own normals (custom normals,
``import_shading="NORMALS"``); the new objects without a parent (the model's roots, in Euler XYZ
rotation mode), each mesh given ``material``.
"""
import os
import runpy

import bpy

_HERE = os.path.dirname(os.path.abspath(__file__))


def lib():
    L = runpy.run_path(os.path.join(_HERE, "..", "_lib.py"))

    def import_gltf(path, material):
        if not hasattr(bpy.ops.import_scene, "gltf"):
            import addon_utils
            addon_utils.enable("io_scene_gltf2", default_set=True)
        before = set(bpy.data.objects)
        bpy.ops.import_scene.gltf(filepath=os.path.join(_HERE, path), import_shading="NORMALS")
        new = [ob for ob in bpy.data.objects if ob not in before]
        for ob in new:
            if ob.type == "MESH":
                ob.data.materials.clear()
                ob.data.materials.append(material)
        roots = [ob for ob in new if ob.parent is None]
        for ob in roots:
            ob.rotation_mode = "XYZ"  # (the importer's quaternion, converted)
        return roots

    L.update(import_gltf=import_gltf)
    return L
