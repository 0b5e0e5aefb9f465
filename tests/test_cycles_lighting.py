"""Unshadowed direct diffuse light of area lights (rectangles and ellipses, partly below the
receiver's horizon, with and without a spread) and of a point light against Cycles' Diffuse Direct pass: the units, the
falloff and the area integral of the lighting pass are Cycles'."""
import math
import os
import tempfile

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender.cycles_reference import _configure, _find, _read_exr, _Saved
from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W = H = 48


def _scene(kind, shape=None, spread=None):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    me = bpy.data.meshes.new("plane")
    me.from_pydata([(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [], [(0, 1, 2, 3)])
    plane = bpy.data.objects.new("plane", me)
    sc.collection.objects.link(plane)
    mat = bpy.data.materials.new("diffuse")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    mat.node_tree.links.new(diffuse.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)  # what the export reads without a Principled BSDF
    me.materials.append(mat)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 8.0
    cam.location = (0.0, 0.0, 6.0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    light = bpy.data.lights.new("light", kind)
    light.energy = 60.0
    light.use_shadow = False
    if kind == "AREA":
        light.shape = shape
        light.size, light.size_y = 2.0, 1.0
        if spread is not None:
            light.spread = math.radians(spread)
    else:
        light.shadow_soft_size = 0.0
    ob = bpy.data.objects.new("light", light)
    ob.location = (0.6, 0.3, 0.9)
    ob.rotation_euler = (math.radians(55.0), 0.0, math.radians(20.0))  # tilted: part of it is
    sc.collection.objects.link(ob)                                      # below some receivers' horizon
    sc.render.resolution_x, sc.render.resolution_y = W, H
    return sc


def _cycles_diffuse_direct(sc):
    saved = _Saved()
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "ref.exr")
        try:
            _configure(sc, saved, (W, H), 512, path)
            sc.view_layers[0].use_pass_diffuse_color = True
            bpy.ops.render.render(write_still=True, scene=sc.name)
            ch = _read_exr(path)
        finally:
            saved.restore()
    return _find(ch, "DiffDir", "Diffuse Direct")[..., :3].mean(axis=-1)


@pytest.mark.parametrize("kind,shape,spread", [("AREA", "RECTANGLE", None), ("AREA", "ELLIPSE", None),
                                               ("POINT", None, None), ("AREA", "RECTANGLE", 60.0),
                                               ("AREA", "ELLIPSE", 100.0)])
def test_unshadowed_diffuse_matches_cycles(pipeline, kind, shape, spread):
    sc = _scene(kind, shape, spread)
    ref = _cycles_diffuse_direct(sc)
    core = export_depsgraph(bpy.context.evaluated_depsgraph_get()).validate()
    frame = pipeline.render(core, Settings(mode="none", specular=False), W, H)
    albedo = frame.gbuffer.read("albedo")[..., :3].mean(axis=-1)
    ours = frame.image[..., :3].mean(axis=-1) / np.maximum(albedo, 1e-6)  # E / pi, as Diffuse Direct
    valid = (albedo > 0.5) & (ref > 0.005 * ref.max())
    assert valid.sum() > (0.2 if spread else 0.3) * W * H  # (a spread narrows the lit patch)
    rel = np.abs(ours[valid] - ref[valid]) / ref[valid]
    assert np.median(rel) < 0.02, np.median(rel)
    # a spread's cut-off is a kink the quadrature smooths a little at the patch's rim
    assert np.percentile(rel, 95) < (0.1 if spread else 0.06), np.percentile(rel, 95)
    surf = albedo > 0.5
    assert abs(ours[surf].sum() / ref[surf].sum() - 1.0) < 0.01  # the light's whole power
    # where Cycles sees no light (behind the area light's emitting side), neither do we
    dark = (albedo > 0.5) & (ref < 1e-4)
    assert np.all(ours[dark] < 1e-3 * ref.max())
