"""The command line, ``compare`` and ``--frames`` export what a final render evaluates
(``blender/render_eval.py``: Blender's F12 path hands the export a render-mode depsgraph), not
the viewport's evaluation, on ``test_scenes/render_settings.py``, which holds one difference per
object:

- ``Render Only``: disabled in the viewports, rendered;
- ``Viewport Array``: its Array modifier enabled in the viewport only (one block for render,
  three in the viewport);
- ``Smooth``: a Subdivision Surface at level 0 in the viewport and 3 for render.

Against Cycles' hard reference of the sun, the render evaluation's mask is within 0.5 % of the
valid pixels; the viewport's evaluation is off by more (each difference shows). The scene's
render engine is the same afterwards, and the export's engine class is gone.
"""
import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error

pytestmark = [pytest.mark.blender]

W, H = 160, 120
LIMIT_PCT = 0.5


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


def test_each_object_as_a_render_evaluates_it(exported):
    import bpy

    bscene, render, viewport = exported
    assert _triangles(render, "Render Only") == 12 and _triangles(viewport, "Render Only") == 0
    assert _triangles(render, "Viewport Array") == 12 and _triangles(viewport, "Viewport Array") == 36
    assert _triangles(render, "Smooth") == 6 * 4 ** 3 * 2 and _triangles(viewport, "Smooth") == 12
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
    assert errors["viewport"] > 2 * LIMIT_PCT, errors
    assert np.isfinite(list(errors.values())).all()


def test_the_command_line_loads_the_render_evaluation():
    """(Last: loading a scene replaces the module's.)"""
    from hybrid_shadow_addon.blender.load import load_scene

    scene = load_scene("render_settings")
    assert _triangles(scene, "Render Only") == 12 and _triangles(scene, "Smooth") == 6 * 4 ** 3 * 2
