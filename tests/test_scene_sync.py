"""Frame-to-frame bake updates (core/scene_sync.py): what each kind of change costs, and that
the updated bake renders exactly what a fresh bake renders."""
import copy

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.scene import Model
from hybrid_shadow_addon.core.scene_sync import same_model, sync_scene
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

SETTINGS = Settings(mode="raytrace", quality="high", interlace=False)
SCENE = "animated"


@pytest.fixture(scope="module")
def fresh(gl_ctx):
    p = Pipeline(gl_ctx)
    yield p
    p.release()


@pytest.fixture()
def base(loaded):
    return copy.deepcopy(loaded(SCENE))


def masks(pipe, scene):
    frame = pipe.render(scene, SETTINGS, 96, 72)
    return {scene.lights[li].name: frame.mask_array(li) for li in frame.lights}, frame.image


def assert_same_as_fresh(pipe, fresh, scene):
    got, img = masks(pipe, scene)
    fresh.set_scene(copy.deepcopy(scene))
    want, want_img = masks(fresh, scene)
    assert got.keys() == want.keys()
    for name in got:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)
    np.testing.assert_array_equal(img, want_img)


def index(scene, name):
    return scene.instances.names.index(name)


def test_first_frame_bakes_then_nothing_changed(pipeline, base):
    assert sync_scene(pipeline, None, base).kind == "full"
    again = copy.deepcopy(base)
    r = sync_scene(pipeline, base, again)
    assert r.kind == "none" and r.moved == [] and r.models == []
    # unchanged meshes keep the previous Model objects (bake and vertex buffers reused)
    assert all(a is b for a, b in zip(again.models, base.models))


def test_move_is_incremental_and_exact(pipeline, fresh, base):
    sync_scene(pipeline, None, base)
    nxt = copy.deepcopy(base)
    i = index(nxt, "Cube")
    m = nxt.instances.matrices[i].copy()
    m[:3, 3] += (1.5, 0.5, 0.0)
    nxt.instances.set_matrices([i], m[None])
    r = sync_scene(pipeline, base, nxt)
    assert r.kind == "incremental" and r.moved == [i] and r.models == []
    assert_same_as_fresh(pipeline, fresh, nxt)


def test_edited_and_added_meshes_update_only_those_models(pipeline, fresh, base):
    sync_scene(pipeline, None, base)
    nxt = copy.deepcopy(base)
    i = index(nxt, "Cube")
    mid = int(nxt.instances.model_ids[i])
    old = nxt.models[mid]
    nxt.models[mid] = Model(name=old.name, vertices=old.vertices * np.float32([1.0, 1.0, 2.0]),
                            triangles=old.triangles)
    r = sync_scene(pipeline, base, nxt)
    assert r.kind == "incremental" and r.models == [mid] and r.moved == []
    assert_same_as_fresh(pipeline, fresh, nxt)
    # a new mesh for the pillar: appended as the next model id
    third = copy.deepcopy(nxt)
    j = index(third, "Pillar")
    pm = third.models[int(third.instances.model_ids[j])]
    third.models.append(Model(name="Pillar.wide", vertices=pm.vertices * np.float32([3, 3, 1]),
                              triangles=pm.triangles))
    third.instances.model_ids[j] = len(third.models) - 1
    r = sync_scene(pipeline, nxt, third)
    assert r.kind == "incremental" and r.models == [len(nxt.models)]
    assert_same_as_fresh(pipeline, fresh, third)


def test_added_or_removed_instances_bake_in_full(pipeline, base):
    sync_scene(pipeline, None, base)
    inst = base.instances
    more = copy.deepcopy(base)
    from hybrid_shadow_addon.core.scene import Instances

    extra = Instances(names=["Cube copy"], model_ids=inst.model_ids[:1], matrices=inst.matrices[:1])
    more.instances = Instances.concatenate([more.instances, extra])
    r = sync_scene(pipeline, base, more)
    assert r.kind == "full" and "added" in r.reason
    fewer = copy.deepcopy(base)
    keep = np.arange(1, len(inst))
    fewer.instances = Instances(names=[inst.names[k] for k in keep], model_ids=inst.model_ids[keep],
                                matrices=inst.matrices[keep])
    assert sync_scene(pipeline, more, fewer).kind == "full"


def test_reordered_instances_are_aligned(pipeline, fresh, base):
    sync_scene(pipeline, None, base)
    inst = base.instances

    nxt = copy.deepcopy(base)
    nxt.instances = nxt.instances.take(np.arange(len(inst))[::-1].copy())
    r = sync_scene(pipeline, base, nxt)
    assert r.kind == "none"
    assert nxt.instances.names == inst.names
    assert_same_as_fresh(pipeline, fresh, nxt)


def test_camera_light_and_material_changes_need_no_bake(pipeline, fresh, base):
    sync_scene(pipeline, None, base)
    nxt = copy.deepcopy(base)
    nxt.camera.matrix[:3, 3] += (0.5, 0.0, 0.2)
    nxt.lights[0].matrix = nxt.lights[0].matrix @ np.diag([1.0, 1.0, 1.0, 1.0])
    nxt.lights[0].matrix[:3, 3] += (0.3, 0.0, 0.0)
    nxt.instances.base_color[:] = (0.2, 0.9, 0.2, 1.0)
    assert sync_scene(pipeline, base, nxt).kind == "none"
    assert_same_as_fresh(pipeline, fresh, nxt)


def test_without_ray_tracing_nothing_is_baked(gl_ctx, base):
    pipe = Pipeline(gl_ctx)
    try:
        assert sync_scene(pipe, None, base, bake=False).kind == "none"
        assert pipe.baked is None
        sync_scene(pipe, None, base)
        nxt = copy.deepcopy(base)
        nxt.instances.matrices[0, :3, 3] += 1.0
        nxt.instances.set_matrices([0], nxt.instances.matrices[:1])
        assert sync_scene(pipe, base, nxt, bake=False).kind == "none"
        assert pipe.baked is None  # stale after a move: the next ray-traced frame bakes afresh
    finally:
        pipe.release()


def test_same_model():
    v = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    a = Model("a", v, [[0, 1, 2]])
    assert same_model(a, Model("a", v.copy(), [[0, 1, 2]]))
    assert not same_model(a, Model("a", v * 2, [[0, 1, 2]]))
    assert not same_model(a, Model("a", v, [[0, 2, 1]]))


def test_structure_change_bakes_afresh_and_bvh_updates_are_exact(gl_ctx, base):
    pipe, ref = Pipeline(gl_ctx), Pipeline(gl_ctx)
    try:
        sync_scene(pipe, None, base, structure="grid")
        nxt = copy.deepcopy(base)
        r = sync_scene(pipe, base, nxt, structure="bvh")
        assert r.kind == "full" and pipe.baked.structure == "bvh"
        third = copy.deepcopy(nxt)
        i = index(third, "Cube")
        m = third.instances.matrices[i].copy()
        m[:3, 3] += (1.0, 1.0, 0.0)
        third.instances.set_matrices([i], m[None])
        assert sync_scene(pipe, nxt, third, structure="bvh").kind == "incremental"
        bvh = Settings(mode="raytrace", quality="high", interlace=False, structure="bvh")
        got = pipe.render(third, bvh, 96, 72)
        ref.set_scene(copy.deepcopy(third), "bvh")
        want = ref.render(third, bvh, 96, 72)
        np.testing.assert_array_equal(got.image, want.image)
    finally:
        pipe.release()
        ref.release()


def test_one_rule_for_a_stale_shadow(base):
    """A light's colour, power or spot blend leave its shadow; its transform, shape, linking or
    shadow switch make it stale; lights that came, went or were reordered make every one stale. The
    scene sync follows the same rule (:func:`changed_shadows`) as the viewport."""
    from hybrid_shadow_addon.core.scene.lights import changed_shadows
    from hybrid_shadow_addon.core.scene_sync import forget_changed_lights

    class Recorder:
        reuse = True

        def __init__(self):
            self.calls = []

        def reset_history(self):
            self.calls.append("all")

        def reset_light(self, index):
            self.calls.append(index)

    old = base.lights
    assert len(old) >= 2
    for field, value in (("color", np.float32([0.1, 0.2, 0.3])), ("power", 7.0), ("spot_blend", 0.9)):
        new = copy.deepcopy(old)
        setattr(new[1], field, value)
        assert changed_shadows(old, new) == [], field
    for field, value in (("radius", 0.5), ("use_shadow", False), ("blocker_set", 3), ("angle", 0.2)):
        new = copy.deepcopy(old)
        setattr(new[1], field, value)
        assert changed_shadows(old, new) == [1], field
    new = copy.deepcopy(old)
    new[0].matrix[:3, 3] += 0.1
    assert changed_shadows(old, new) == [0]
    assert changed_shadows(old, list(reversed(copy.deepcopy(old)))) is None
    assert changed_shadows(old, copy.deepcopy(old)[:-1]) is None

    nxt = copy.deepcopy(base)
    nxt.lights[0].color = np.float32([1.0, 0.0, 0.0])
    nxt.lights[1].matrix[:3, 3] += 0.1
    rec = Recorder()
    forget_changed_lights(rec, base, nxt)
    assert rec.calls == [1]
    rec.reuse = False
    rec.calls.clear()
    forget_changed_lights(rec, base, nxt)
    assert rec.calls == ["all"]
