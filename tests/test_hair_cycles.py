"""Particle hair, a Curves object and a point cloud against Cycles' per-light hard references
(``test_scenes/hair.py``, Cycles' round 3D curves): ray traced ``high`` within 1 % of the valid
pixels per light, and far from it without the strands and points."""
import copy

import numpy as np
import pytest

from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import mask_error

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.cycles]

W, H = 320, 240
LIMIT_PCT = 1.0


@pytest.fixture(scope="module")
def hair():
    import bpy

    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.export import export_depsgraph
    from hybrid_shadow_addon.blender.load import open_scene

    bscene = open_scene("hair")
    scene = export_depsgraph(bpy.context.evaluated_depsgraph_get(), resolution=(W, H)).validate()
    return scene, render_reference(bscene, resolution=(W, H))


def _errors(pipeline, scene, reference):
    settings = Settings(mode="raytrace", quality="high", hard=True)
    pipeline.set_scene(scene, settings.structure)
    frame = pipeline.render(scene, settings, W, H)
    return {scene.lights[li].name: mask_error(reference.visibility[scene.lights[li].name], frame.mask_array(li))
            for li in frame.lights}


def test_masks_match_cycles(hair, pipeline):
    scene, reference = hair
    errors = _errors(pipeline, scene, reference)
    assert set(errors) == {"Sun", "Point"}
    for name, e in errors.items():
        assert e.valid_pixels > 0.3 * W * H
        assert e.mismatch_pct <= LIMIT_PCT, (name, e.mismatch_pct)


def test_without_strands_and_points_masks_do_not_match(hair, pipeline):
    scene, reference = hair
    keep = [i for i, n in enumerate(scene.instances.names) if not (n.startswith(("Fur", "Points[")) or "/Hair" in n)]
    assert len(keep) < len(scene.instances)
    bare = copy.copy(scene)
    bare.instances = scene.instances.take(np.array(keep))
    errors = _errors(pipeline, bare, reference)
    assert all(e.mismatch_pct > 3 * LIMIT_PCT for e in errors.values()), {n: e.mismatch_pct for n, e in errors.items()}
