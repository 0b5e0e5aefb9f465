"""Every built-in test scene, exported, against what bpy itself reports."""
import math

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.blender.export import export_depsgraph
from hybrid_shadow_addon.blender.load import builtin_scenes, open_scene

pytestmark = [pytest.mark.blender]


# small versions: the whole file stays within seconds
SMALL = {
    "cube_on_plane": "cube_on_plane",
    "forest": "forest:trees=40,spheres=10,terrain=32,variants=2,frames=50",
    "clusters": "clusters:clusters=4,spheres=60",
    "city": "city:blocks=2",
    "scaling": "scaling:triangles=20000,instances=500,models=3",
    "animated": "animated",
    "alpha_cards": "alpha_cards",
    "soft_lights": "soft_lights",
    "smooth_shapes": "smooth_shapes",
    "fence_far": "fence_far",
    "materials": "materials",
    "visibility": "visibility",
    "linking": "linking",
    "see_through": "see_through",
    "hair": "hair:hair=60,strands=40,points=50",
    "render_settings": "render_settings",
}
# the shading-normal scenes and third-party models (against Cycles in test_real_meshes.py)
SMALL.update({n: n for n in ("normals/smooth_primitives", "normals/weighted_normals", "normals/custom_split",
                             "normals/flipped_faces", "normals/gltf_roundtrip", "normals/obj_roundtrip",
                             "models/avocado", "models/lantern", "models/waterbottle")})


def test_every_builtin_scene_is_covered():
    """Every built-in scene outside stiff/ is exported here (the stiff/ ones in test_stiff.py)."""
    assert {n for n in builtin_scenes() if not n.startswith("stiff/")} == set(SMALL)


def _tube_triangles(points_per_strand, subdivisions=2, sides=5):
    """Triangles of the tubes around strands of these point counts (spline-sampled, closed)."""
    samples = (np.asarray(points_per_strand) - 1) * subdivisions + 1
    return int(np.sum((samples - 1) * 2 * sides + 2 * sides))


def _strands_and_points(inst, ob, matrices, meshes):
    """Triangles of particle hair, Curves and point clouds as rows, models and matrices."""
    tris = 0
    if not inst.is_instance:
        for ps in ob.particle_systems:
            if ps.settings.type == "HAIR" and ps.settings.render_type == "PATH":
                keys = 2 ** ps.settings.display_step + 1
                tris += _tube_triangles([keys] * len(ps.particles))
                meshes.add(("hair", ps.as_pointer()))
                matrices.append(np.array(ob.matrix_world))
    if ob.type == "CURVES":
        sizes = [c.points_length for c in ob.data.curves]
        tris += _tube_triangles(sizes)
        meshes.add(ob.data.as_pointer())
        matrices.append(np.array(inst.matrix_world.copy()))
    elif ob.type == "POINTCLOUD":
        world = np.array(inst.matrix_world.copy())
        for p in ob.data.points:
            local = np.diag([p.radius, p.radius, p.radius, 1.0])
            local[:3, 3] = p.co
            matrices.append(world @ local)
            tris += 2 * 12 * (6 - 1)  # the unit UV sphere of 12 segments, 6 rings
        meshes.add("unit sphere")
    return tris


def _reference(depsgraph):
    """What bpy reports, read independently: rendered mesh instances with triangles, their world
    matrices, triangle count, distinct evaluated meshes, lights by type; strands and points as
    tube rows and one sphere row per point."""
    matrices, tris, meshes, lights = [], 0, set(), {}
    for inst in depsgraph.object_instances:
        ob = inst.object
        owner = (inst.parent if inst.is_instance else ob).original
        if not owner.hide_render:
            tris += _strands_and_points(inst, ob, matrices, meshes)
        if owner.hide_render or not inst.is_instance and ob.is_instancer and not owner.show_instancer_for_render:
            continue  # not rendered: hidden, or an emitter that does not show itself
        if ob.type == "MESH":
            n = len(ob.data.loop_triangles)
            if n:
                tris += n
                meshes.add(ob.data.as_pointer())
                matrices.append(np.array(inst.matrix_world.copy()))
        elif ob.type == "LIGHT":
            lights[ob.data.type] = lights.get(ob.data.type, 0) + 1
    return np.array(matrices).reshape(-1, 4, 4), tris, len(meshes), lights


def _sorted(m):
    flat = m.reshape(len(m), 16)
    return flat[np.lexsort(np.round(flat, 3).T[::-1])]


@pytest.mark.parametrize("name", sorted(SMALL))
def test_scene_matches_bpy(name):
    bscene = open_scene(SMALL[name])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = export_depsgraph(depsgraph)
    _check_counts_and_matrices(depsgraph, scene)
    _check_lights(bscene, scene)
    _check_camera_resolution_world(name, bscene, scene)


def _check_counts_and_matrices(depsgraph, scene):
    matrices, tris, models, lights = _reference(depsgraph)
    assert len(scene.instances) == len(matrices)
    assert scene.triangle_count == tris
    assert len(scene.models) == models
    assert {k: v for k, v in scene.lights_by_type().items() if v} == lights
    np.testing.assert_allclose(_sorted(scene.instances.matrices), _sorted(matrices), rtol=1e-5, atol=1e-4)
    scene.validate()


def _check_lights(bscene, scene):
    objects = {ob.name: ob for ob in bscene.objects if ob.type == "LIGHT"}
    assert sorted(light.name for light in scene.lights) == sorted(objects)
    for light in scene.lights:
        ob = objects[light.name]
        d = ob.data
        assert light.type == d.type
        assert light.power == pytest.approx(d.energy)
        np.testing.assert_allclose(light.color, d.color, rtol=1e-6)
        np.testing.assert_allclose(light.matrix, np.array(ob.matrix_world), atol=1e-5)
        assert light.use_shadow == d.use_shadow
        if d.type == "SUN":
            assert light.angle == pytest.approx(d.angle)
        if d.type in ("POINT", "SPOT"):
            assert light.radius == pytest.approx(d.shadow_soft_size)
        if d.type == "SPOT":
            assert (light.spot_size, light.spot_blend) == pytest.approx((d.spot_size, d.spot_blend))
        if d.type == "AREA":
            assert (light.size, light.area_shape) == (pytest.approx(d.size), d.shape)


def _check_camera_resolution_world(name, bscene, scene):
    cam = bscene.camera
    assert scene.camera.name == cam.name
    assert scene.camera.lens == pytest.approx(cam.data.lens)
    np.testing.assert_allclose(scene.camera.matrix, np.array(cam.matrix_world), atol=1e-5)
    r = bscene.render
    assert scene.resolution == (r.resolution_x * r.resolution_percentage // 100,
                                r.resolution_y * r.resolution_percentage // 100)
    assert scene.world_color.max() > 0
    assert scene.lights, f"{name} has no lights"
    # the camera sees the scene: the world-bounds centre is in front of it
    lo, hi = scene.world_bounds()
    to_centre = (lo + hi) / 2 - scene.camera.matrix[:3, 3]
    assert np.dot(to_centre, -scene.camera.matrix[:3, 2]) > 0


def test_forest_content():
    scene = open_scene("forest:trees=30,spheres=8,terrain=16,variants=3,frames=100")
    exported = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    palms = [m for m in exported.models if m.name.startswith("Palm")]
    assert len(palms) == 3
    assert all(1000 <= m.triangle_count <= 5000 for m in palms)
    assert exported.instances.sphere.sum() == 4  # every other ball
    types = exported.lights_by_type()
    assert types["SUN"] == 1 and types["POINT"] >= 1 and types["SPOT"] >= 1
    sun = next(light for light in exported.lights if light.type == "SUN")
    assert math.degrees(math.asin(-sun.direction[2])) == pytest.approx(8, abs=0.5)  # dawn
    first = exported.camera.matrix.copy()
    scene.frame_set(60)
    later = export_depsgraph(bpy.context.evaluated_depsgraph_get())
    assert later.frame == 60
    assert np.linalg.norm(later.camera.matrix[:3, 3] - first[:3, 3]) > 1  # animated camera


def test_scenes_are_deterministic():
    a = export_depsgraph((open_scene("clusters:clusters=3,spheres=20"), bpy.context.evaluated_depsgraph_get())[1])
    b = export_depsgraph((open_scene("clusters:clusters=3,spheres=20"), bpy.context.evaluated_depsgraph_get())[1])
    np.testing.assert_array_equal(a.instances.matrices, b.instances.matrices)


def test_scaling_params():
    scene = export_depsgraph((open_scene("scaling:triangles=6000,instances=300"),
                              bpy.context.evaluated_depsgraph_get())[1])
    ground = [i for i, m in enumerate(scene.models) if m.name == "Ground"]
    assert len(ground) == 1 and len(scene.models) == 2
    assert len(scene.instances) == 301
    assert (scene.instances.model_ids != ground[0]).sum() == 300
    assert scene.triangle_count - 2 == pytest.approx(6000, rel=0.1)
