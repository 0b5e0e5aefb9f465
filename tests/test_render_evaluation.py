"""The command line, ``compare`` and ``--frames`` export what a final render evaluates
(``blender/render_eval.py``: Blender's F12 path hands the export a render-mode depsgraph), not
the viewport's evaluation, on ``test_scenes/render_settings.py``, which holds one difference per
object:

- ``Render Only``: disabled in the viewports, rendered;
- ``Viewport Array``: its Array modifier enabled in the viewport only (one block for render,
  three in the viewport);
- ``Smooth``: a Subdivision Surface at level 0 in the viewport and 3 for render;
- ``Blob``: a metaball polygonised at its render resolution (0.15 m) rather than its viewport one
  (0.5 m): several times the triangles;
- ``Ring``: a bevelled curve at its render resolution (12 segments per span) rather than its
  viewport one (2);
- ``Crates``: hair particles instancing a cube, all 12 for render, a random quarter in the
  viewport (``display_percentage``);
- ``Stored``: in a collection disabled in the viewports, rendered;
- ``Switch Shape``: Geometry Nodes' "Is Viewport" switching between a cube (viewport) and an ico
  sphere (render).

Against Cycles' hard reference of the sun, the render evaluation's mask is within 0.1 % of the
valid pixels (measured: no pixel differs, Blender 4.5 and 5.2); the viewport's evaluation is off
by more (each difference shows; about 6 %). The scene's render engine is the same afterwards, and
the export's engine class is gone.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error

pytestmark = [pytest.mark.blender]

W, H = 160, 120
LIMIT_PCT = 0.1
#: triangles of the render's ico sphere: 3 subdivisions split the icosahedron's 20 faces in 4 twice
ICO = 20 * 4 ** 2


@pytest.fixture(scope="module")
def exported():
    """``(bpy scene, render evaluation, viewport evaluation)`` of the scene."""
    import bpy

    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.blender.render_eval import render_scene

    bscene = open_scene("render_settings")
    bscene.render.engine = "CYCLES"
    render = render_scene(bscene, resolution=(W, H))
    viewport = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    return bscene, render, viewport


def _triangles(scene, name) -> int:
    inst = scene.instances
    if name not in inst.names:
        return 0
    return int(scene.models[int(inst.model_ids[inst.names.index(name)])].triangle_count)


def _instances(scene, name) -> list[int]:
    """Triangles of each instance of object ``name``: itself and what it instances (``name/...``)."""
    inst = scene.instances
    return [int(scene.models[int(m)].triangle_count) for n, m in zip(inst.names, inst.model_ids)
            if n == name or n.startswith(name + "/")]


def _ring(segments_per_span: int) -> int:
    """Triangles of the ring: 4 spans of ``segments_per_span``, 8 sides around its round bevel
    (4 + 2 x its 2 bevel segments)."""
    return 2 * 4 * segments_per_span * 8


def test_each_object_as_a_render_evaluates_it(exported):
    import bpy

    bscene, render, viewport = exported
    assert _triangles(render, "Render Only") == 12 and _triangles(viewport, "Render Only") == 0
    assert _triangles(render, "Viewport Array") == 12 and _triangles(viewport, "Viewport Array") == 36
    assert _triangles(render, "Smooth") == 6 * 4 ** 3 * 2 and _triangles(viewport, "Smooth") == 12
    blob = _triangles(render, "Blob"), _triangles(viewport, "Blob")
    assert blob[1] > 0 and blob[0] > 5 * blob[1], blob  # (0.5 / 0.15) ** 2: about 11 times the triangles
    assert _triangles(render, "Ring") == _ring(12) and _triangles(viewport, "Ring") == _ring(2)
    crates = _instances(render, "Crates"), _instances(viewport, "Crates")
    assert crates[0] == [12] * 12 and 0 < len(crates[1]) < 12 and set(crates[1]) == {12}, crates
    assert _instances(render, "Stored") == [12] and _instances(viewport, "Stored") == []
    assert _triangles(render, "Switch Shape") == ICO and _triangles(viewport, "Switch Shape") == 12
    assert bscene.render.engine == "CYCLES"
    assert not hasattr(bpy.types, "HS_RENDER_EVALUATION")


@pytest.mark.gpu
@pytest.mark.cycles
def test_render_evaluation_matches_cycles_where_the_viewport_does_not(exported, pipeline):
    from hybrid_shadow_addon.blender.cycles_reference import render_reference

    bscene, render, viewport = exported
    ref = render_reference(bscene, resolution=(W, H)).visibility["Sun"]
    errors = {}
    for name, scene in (("render", render), ("viewport", viewport)):
        pipeline.set_scene(scene)
        frame = pipeline.render(scene, Settings(mode="raytrace", hard=True), W, H)
        li = next(i for i in frame.lights if scene.lights[i].name == "Sun")
        e = mask_error(ref, frame.mask_array(li))
        assert e.valid_pixels > 0.3 * W * H
        errors[name] = e.mismatch_pct
    assert errors["render"] <= LIMIT_PCT, errors
    assert errors["viewport"] > 10 * LIMIT_PCT, errors
    assert np.isfinite(list(errors.values())).all()


def test_frames_export_the_render_evaluation(exported):
    """``render --frames`` (``BlenderFrames.scene_at``) exports each frame as F12 evaluates it:
    every object as in the render evaluation."""
    from hybrid_shadow_addon.blender.frames import BlenderFrames

    bscene, render, _ = exported
    frame = BlenderFrames(bscene, resolution=(W, H)).scene_at(bscene.frame_current)
    for name in ("Render Only", "Viewport Array", "Smooth", "Blob", "Ring", "Switch Shape"):
        assert _triangles(frame, name) == _triangles(render, name), name
    for name in ("Crates", "Stored"):
        assert _instances(frame, name) == _instances(render, name), name


def test_the_command_line_loads_the_render_evaluation():
    """(Last: loading a scene replaces the module's.)"""
    from hybrid_shadow_addon.blender.load import load_scene

    scene = load_scene("render_settings")
    assert _triangles(scene, "Render Only") == 12 and _triangles(scene, "Smooth") == 6 * 4 ** 3 * 2
    assert _triangles(scene, "Ring") == _ring(12) and len(_instances(scene, "Crates")) == 12
    assert _instances(scene, "Stored") == [12] and _triangles(scene, "Switch Shape") == ICO
