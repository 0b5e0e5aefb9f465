"""load_scene and open_scene: built-in scenes with parameters, scripts and .blend files opened and
exported, and the errors they raise."""
import bpy
import pytest

from hybrid_shadow_addon.blender.load import SCENES_DIR, builtin_scenes, load_scene, open_scene, parse_scene_arg
from hybrid_shadow_addon.core.errors import SceneError, SceneLoadError

pytestmark = [pytest.mark.blender]


# --------------------------------------------------------------------------------------------
# load_scene
# --------------------------------------------------------------------------------------------
def test_parse_scene_arg():
    assert parse_scene_arg("scaling:triangles=1000000,instances=100000,k=0.5,s=abc") == (
        "scaling", {"triangles": 1000000, "instances": 100000, "k": 0.5, "s": "abc"})
    assert parse_scene_arg("forest") == ("forest", {})
    assert parse_scene_arg("/tmp/a:b.py") == ("/tmp/a:b.py", {})


def test_load_builtin_with_params():
    s = load_scene("scaling:triangles=600,instances=20")
    assert len(s.instances) == 21 and s.name == "scaling"
    assert all((SCENES_DIR / f"{n}.py").is_file() for n in builtin_scenes())


def test_load_script_and_blend(tmp_path):
    script = tmp_path / "mine.py"
    script.write_text(
        "import bpy\n"
        "sc = bpy.context.scene\n"
        "me = bpy.data.meshes.new('t')\n"
        "me.from_pydata([(0,0,0),(1,0,0),(0,1,0)], [], [(0,1,2)])\n"
        "sc.collection.objects.link(bpy.data.objects.new('Tri', me))\n"
        "cam = bpy.data.objects.new('Cam', bpy.data.cameras.new('Cam'))\n"
        "sc.collection.objects.link(cam); sc.camera = cam\n"
        "cam.location = (0, 0, PARAMS.get('z', 5))\n")
    s = load_scene(f"{script}:z=7")
    assert s.instances.names == ["Tri"] and s.camera.matrix[2, 3] == 7
    blend = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    s = load_scene(str(blend), frame=3)
    assert s.instances.names == ["Tri"] and s.frame == 3


@pytest.mark.parametrize("arg, error, pattern", [
    ("/nonexistent/scene.py", SceneLoadError, "not found: /nonexistent/scene.py"),
    ("/nonexistent/scene.blend", SceneLoadError, "not found"),
    ("no_such_scene", SceneLoadError, "unknown scene 'no_such_scene'.*cube_on_plane.*forest"),
    ("_lib", SceneLoadError, "unknown scene"),
])
def test_load_errors(arg, error, pattern):
    with pytest.raises(error, match=pattern) as info:
        load_scene(arg)
    assert "\n" not in str(info.value)


def test_load_failing_script(tmp_path):
    script = tmp_path / "boom.py"
    script.write_text("x = 1\nraise ValueError('the model is broken\\nsecond line')\n")
    with pytest.raises(SceneLoadError, match=r"^scene script boom.py failed: ValueError: the model is broken$"):
        load_scene(str(script))


def test_load_corrupted_blend(tmp_path):
    bad = tmp_path / "bad.blend"
    bad.write_bytes(b"BLENDER-v405 this is not a blend file" * 10)
    with pytest.raises(SceneLoadError, match="cannot open .*bad.blend") as info:
        load_scene(str(bad))
    assert "\n" not in str(info.value)


def test_load_without_camera(tmp_path):
    script = tmp_path / "nocam.py"
    script.write_text("import bpy\nbpy.context.scene.name = 'Empty'\n")
    with pytest.raises(SceneError, match="'Empty'.*no camera"):
        load_scene(str(script))


def test_open_scene_keeps_bpy_scene():
    sc = open_scene("cube_on_plane", frame=2)
    assert sc == bpy.context.scene and sc.frame_current == 2
    assert {o.name for o in sc.objects} >= {"Cube", "Plane", "Sun", "Camera"}
