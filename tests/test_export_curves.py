"""Particle hair, Curves objects (also instanced by geometry nodes) and point clouds: strands
exported as tube models with their radii, points as sphere primitives; and the tube geometry."""
import math
import runpy
from pathlib import Path

import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.core.scene.curves import (
    catmull_rom,
    prism_scale,
    sphere_matrices,
    tube_model,
    unit_sphere_model,
)
from tests.helpers.export_scenes import add_object, empty_scene, export_scene, gn_instancer, object_info

#: the scene scripts' library (test_scenes/_lib.py)
SCENE_LIB = runpy.run_path(str(Path(__file__).resolve().parents[1] / "test_scenes" / "_lib.py"))


# -- tube geometry (bpy-free) -------------------------------------------------------------------
def _axis_distance(model, axis_xy=(0.0, 0.0)):
    return np.hypot(model.vertices[:, 0] - axis_xy[0], model.vertices[:, 1] - axis_xy[1])


def test_straight_tube_radius_counts_and_silhouette():
    pts = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2]], float)
    m = tube_model("t", pts, [0.1, 0.1, 0.1], [0, 3], sides=5)
    rim = m.vertices[:15]
    np.testing.assert_allclose(_axis_distance(m)[:15], 0.1 * prism_scale(5), rtol=1e-5)
    assert len(m.triangles) == 2 * 5 * 2 + 2 * 5  # two segments of quads, two end caps
    # mean silhouette width over directions equals the diameter
    dirs = np.linspace(0, np.pi, 360, endpoint=False)
    widths = [np.ptp(rim[:, :2] @ (math.cos(a), math.sin(a))) for a in dirs]
    assert np.mean(widths) == pytest.approx(0.2, rel=0.01)
    assert max(widths) / min(widths) < 1.06


def test_tube_radius_follows_points_and_strands_with_one_point_are_dropped():
    pts = np.array([[0, 0, 0], [0, 0, 1], [5, 5, 5], [1, 0, 0], [1, 0, 1]], float)
    radii = np.array([0.2, 0.05, 9.0, 0.1, 0.1])
    m = tube_model("t", pts, radii, [0, 2, 3, 5], sides=3)
    assert m.bounds_max[2] <= 1.0 + 1e-6 and m.bounds_max[0] < 2  # the lone point is gone
    d = _axis_distance(m)[:6] / prism_scale(3)
    np.testing.assert_allclose(d, [0.2] * 3 + [0.05] * 3, rtol=1e-5)
    assert len(m.triangles) == 2 * (2 * 3 + 2 * 3)
    assert tube_model("none", pts[:1], radii[:1], [0, 1]) is None


def test_catmull_rom_passes_through_points_and_keeps_ends():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(7, 3))
    radii = rng.uniform(0.1, 0.2, 7)
    p, r, off = catmull_rom(pts, radii, np.array([0, 4, 7]), 3)
    assert off.tolist() == [0, 10, 17]
    np.testing.assert_allclose(p[[0, 3, 6, 9, 10, 13, 16]], pts, atol=1e-12)
    np.testing.assert_allclose(r[[0, 3, 6, 9, 10, 13, 16]], radii, atol=1e-12)


def test_unit_sphere_and_point_matrices():
    m = unit_sphere_model()
    assert m.sphere_radius == 1.0 and np.allclose(m.sphere_center, 0)
    assert np.linalg.norm(m.vertices, axis=1).max() <= 1.0 + 1e-6
    world = np.eye(4)
    world[:3, 3] = (1, 2, 3)
    mats = sphere_matrices(world, [[0, 0, 1], [1, 0, 0]], [0.5, 0.25])
    np.testing.assert_allclose(mats[:, :3, 3], [[1, 2, 4], [2, 2, 3]])
    np.testing.assert_allclose(mats[:, 0, 0], [0.5, 0.25])


# -- export (Blender) ---------------------------------------------------------------------------
@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()


def _curves(name, n_strands, keys=4, radius=None, height=1.0):
    data = bpy.data.hair_curves.new(name)
    data.add_curves([keys] * n_strands)
    xs = np.arange(n_strands, dtype=np.float32)
    pos = np.stack([np.repeat(xs, keys), np.zeros(n_strands * keys),
                    np.tile(np.linspace(0, height, keys), n_strands)], axis=1)
    data.attributes["position"].data.foreach_set("vector", pos.astype(np.float32).ravel())
    if radius is not None:
        attr = data.attributes.new("radius", "FLOAT", "POINT")
        attr.data.foreach_set("value", np.tile(np.asarray(radius, np.float32), n_strands))
    return data


def _model_of(s, name):
    return s.models[int(s.instances.model_ids[s.instances.names.index(name)])]


def _tube_radii(model, n_strands, keys_x):
    """Distance of each tube vertex from its strand's axis (strand k along z at x = k)."""
    v = model.vertices
    return np.hypot(v[:, 0] - np.round(v[:, 0]), v[:, 1])



@pytest.mark.blender
def test_curves_object_strands_and_radii(scene):
    add_object("Fur", _curves("Fur", 3, radius=[0.04, 0.03, 0.02, 0.01]), location=(0, 0, 1))
    s = export_scene()
    m = _model_of(s, "Fur")
    assert "Curves object 'Fur': 3 strands drawn as 5-sided tubes along their splines" in s.report[0], s.report
    assert not any("not drawn" in w for w in s.report)
    r = _tube_radii(m, 3, None)
    assert r.max() == pytest.approx(0.04 * prism_scale(5), rel=1e-4)
    assert r[r > 0].min() == pytest.approx(0.01 * prism_scale(5), rel=1e-4)
    np.testing.assert_allclose(s.instances.matrices[s.instances.names.index("Fur")][:3, 3], (0, 0, 1))
    assert s.instances.casts_shadow.all()
    # three strands: three tube runs plus caps, spline-sampled (two samples per segment)
    assert len(m.triangles) == 3 * ((4 - 1) * 2 * 2 * 5 + 2 * 5)


@pytest.mark.blender
def test_unchanged_strands_reuse_their_tube_model_and_edits_rebuild_it(scene):
    """Re-exporting unchanged strands takes the cached tube model (as the viewport re-exports on
    unrelated changes); moved points or a changed radius build a new one that shows the edit."""
    from hybrid_shadow_addon.blender.export.curves import TUBES

    data = _curves("Fur", 3, radius=[0.04, 0.03, 0.02, 0.01])
    add_object("Fur", data)
    first = _model_of(export_scene(), "Fur")
    builds = TUBES.builds
    again = export_scene()
    assert _model_of(again, "Fur") is first and TUBES.builds == builds
    assert any("Curves object 'Fur': 3 strands" in w for w in again.report), again.report
    pos = np.empty(3 * len(data.points), np.float32)
    data.attributes["position"].data.foreach_get("vector", pos)
    data.attributes["position"].data.foreach_set("vector", pos + np.float32(0.5))
    moved = _model_of(export_scene(), "Fur")
    assert moved is not first
    np.testing.assert_allclose(moved.bounds_min, first.bounds_min + 0.5, atol=1e-5)
    data.attributes["position"].data.foreach_set("vector", pos)
    data.attributes["radius"].data.foreach_set("value", np.full(len(data.points), 0.1, np.float32))
    thick = _model_of(export_scene(), "Fur")
    assert thick is not moved
    assert _tube_radii(thick, 3, None).max() == pytest.approx(0.1 * prism_scale(5), rel=1e-4)


def test_tube_cache_is_bounded_and_keyed_by_content():
    from hybrid_shadow_addon.blender.export.curves import TubeCache

    cache = TubeCache(max_entries=2)
    pts = np.array([[0, 0, 0], [0, 0, 1]], np.float32)
    radii, offsets = np.full(2, 0.1, np.float32), np.array([0, 2], np.int32)
    a = cache.model("a", "A", pts, radii, offsets, 1)
    assert cache.model("a", "A", pts.copy(), radii, offsets, 1) is a
    assert cache.model("a", "A", pts, radii * 2, offsets, 1) is not a  # content changed
    assert cache.model("a", "A", pts, radii * 2, offsets, 2).triangle_count > a.triangle_count
    cache.model("b", "B", pts, radii, offsets, 1)
    cache.model("c", "C", pts, radii, offsets, 1)
    assert list(cache.entries) == ["b", "c"]
    small = TubeCache(max_bytes=1)  # over budget: only the newest stays
    small.model("a", "A", pts, radii, offsets, 1)
    small.model("b", "B", pts, radii, offsets, 1)
    assert list(small.entries) == ["b"]
    cache.clear()
    assert not cache.entries


@pytest.mark.blender
@pytest.mark.parametrize("render_visibility", [None, False])
def test_the_view_layers_hair_filter_drops_strands_not_points(render_visibility):
    """Cycles draws no particle hair and no Curves when the view layer's Hair filter is off;
    meshes and point clouds stay."""
    from hybrid_shadow_addon.blender.load import open_scene

    open_scene("hair:hair=30,strands=20,points=15,width=96,height=72")

    def names():
        return set(export_scene(render_visibility=render_visibility).instances.names)

    with_hair = names()
    assert {"Fur", "Head", "Head/Hair"} <= with_hair and any(n.startswith("Points[") for n in with_hair)
    bpy.context.view_layer.use_strand = False
    assert names() == with_hair - {"Fur", "Head/Hair"}
    bpy.context.view_layer.use_strand = True
    assert names() == with_hair


@pytest.mark.blender
def test_the_viewport_follows_the_hair_filter():
    """Toggling the view layer's Hair filter (a bare Scene update) re-exports the viewport's scene."""
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.blender.viewport import ViewportSync

    open_scene("hair:hair=30,strands=20,points=15,width=96,height=72")
    sync = ViewportSync()
    sync.full_export(bpy.context.evaluated_depsgraph_get())
    shown = []

    def handler(_scene, depsgraph):
        sync.update(depsgraph)

    bpy.app.handlers.depsgraph_update_post.append(handler)
    try:
        for on in (False, True):
            bpy.context.view_layer.use_strand = on
            bpy.context.view_layer.update()
            shown.append({"Fur", "Head/Hair"} & set(sync.scene.instances.names))
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(handler)
    assert shown == [set(), {"Fur", "Head/Hair"}]


@pytest.mark.blender
def test_curves_without_radius_take_cycles_default(scene):
    add_object("Bare", _curves("Bare", 2))
    r = _tube_radii(_model_of(export_scene(), "Bare"), 2, None)
    assert r.max() == pytest.approx(0.005 * prism_scale(5), rel=1e-4)


@pytest.mark.blender
def test_curves_instanced_by_geometry_nodes_share_one_model(scene):
    fur = add_object("Fur", _curves("Fur", 2, radius=[0.02] * 4))
    fur.hide_render = True
    gn_instancer("Tufts", [(0, 0, 0), (5, 0, 0)], object_info(fur, True))
    s = export_scene(render_visibility=True)
    rows = [i for i, n in enumerate(s.instances.names) if n.startswith("Tufts")]
    assert len(rows) == 2, s.instances.names
    assert len({int(s.instances.model_ids[i]) for i in rows}) == 1
    xs = sorted(float(s.instances.matrices[i][0, 3]) for i in rows)
    assert xs == [0.0, 5.0]


@pytest.mark.blender
def test_particle_hair_strands_and_root_radius(scene):
    me = bpy.data.meshes.new("Skin")
    me.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    ob = add_object("Skin", me, location=(3, 0, 0))
    ob.modifiers.new("Hair", "PARTICLE_SYSTEM")
    ps = ob.particle_systems[0].settings
    ps.type, ps.count, ps.hair_length, ps.child_type = "HAIR", 40, 0.5, "NONE"
    ps.radius_scale, ps.root_radius, ps.tip_radius, ps.use_close_tip = 0.1, 1.0, 0.5, False
    s = export_scene()
    assert any(w.startswith("particle hair 'Hair' of object 'Skin': 40 strands") for w in s.report), s.report
    m = _model_of(s, "Skin/Hair")
    np.testing.assert_allclose(s.instances.matrices[s.instances.names.index("Skin/Hair")][:3, 3], (3, 0, 0))
    # object space: roots on the plane z = 0 within the quad, tips at the hair length
    assert m.bounds_min[2] >= -0.1 and m.bounds_max[2] == pytest.approx(0.5, abs=0.06)
    assert np.abs(m.vertices[:, :2]).max() <= 1.0 + 0.06
    root = m.vertices[np.abs(m.vertices[:, 2]) < 1e-6]
    assert len(root)
    # root rings: radius_scale / 2 x root radius, widened for the prism; tip: half of it
    rim = root[:5]
    centre = rim.mean(axis=0)
    np.testing.assert_allclose(np.linalg.norm(rim - centre, axis=1), 0.05 * prism_scale(5), rtol=1e-3)
    ps.child_type = "SIMPLE"
    ps.rendered_child_count = ps.child_percent = 3
    s = export_scene()
    assert any(w.startswith("particle hair 'Hair' of object 'Skin': 120 strands") for w in s.report), s.report


@pytest.mark.blender
def test_point_cloud_points_are_sphere_primitives(scene):
    n = 6
    me = bpy.data.meshes.new("Cloud")
    me.vertices.add(n)
    co = np.arange(3 * n, dtype=np.float32).reshape(n, 3) * 0.1
    me.vertices.foreach_set("co", co.ravel())
    radii = np.linspace(0.05, 0.3, n).astype(np.float32)
    me.attributes.new("r", "FLOAT", "POINT").data.foreach_set("value", radii)
    SCENE_LIB["mesh_to_points"](add_object("Cloud", me, location=(0, 0, 2)), "r")
    s = export_scene()
    rows = [i for i, name in enumerate(s.instances.names) if name.startswith("Cloud[")]
    assert len(rows) == n
    inst = s.instances
    assert inst.sphere[rows].all() and inst.casts_shadow[rows].all()
    np.testing.assert_allclose(inst.matrices[rows][:, :3, 3], co + (0, 0, 2), atol=1e-6)
    np.testing.assert_allclose(inst.matrices[rows][:, 0, 0], radii, rtol=1e-6)
    assert s.models[int(inst.model_ids[rows[0]])].sphere_radius == 1.0
    assert not any("point cloud" in w for w in s.report), s.report


@pytest.mark.gpu
@pytest.mark.blender
def test_strand_edits_and_moved_points_update_the_bake_in_place(gl_ctx):
    """Re-exported strands and points: unchanged ones keep their models; edited strands update
    their model, moved points their rows, without a full bake, rendering as a fresh bake does."""
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.scene_sync import sync_scene
    from hybrid_shadow_addon.core.settings import Settings

    open_scene("hair:hair=30,strands=20,points=15,width=96,height=72")
    first = export_scene()
    pipe, fresh = Pipeline(gl_ctx), Pipeline(gl_ctx)
    try:
        assert sync_scene(pipe, None, first).kind == "full"
        again = export_scene()
        r = sync_scene(pipe, first, again)
        assert r.kind == "none" and r.models == [] and r.moved == []
        fur = bpy.data.objects["Fur"].data
        pos = np.empty(3 * len(fur.points), np.float32)
        fur.attributes["position"].data.foreach_get("vector", pos)
        fur.attributes["position"].data.foreach_set("vector", pos + np.float32(0.2))
        bpy.data.objects["Points"].location.x += 0.5
        edited = export_scene()
        r = sync_scene(pipe, again, edited)
        fur_model = int(edited.instances.model_ids[edited.instances.names.index("Fur")])
        points = [i for i, n in enumerate(edited.instances.names) if n.startswith("Points[")]
        assert r.kind == "incremental" and r.models == [fur_model] and sorted(r.moved) == points
        settings = Settings(mode="raytrace", quality="high", interlace=False)
        got = pipe.render(edited, settings, 96, 72)
        fresh.set_scene(edited)
        want = fresh.render(edited, settings, 96, 72)
        for li in got.lights:
            np.testing.assert_array_equal(got.mask_array(li), want.mask_array(li))
    finally:
        pipe.release()
        fresh.release()
