"""GL objects are given back, not dropped (``core/gpu/memory.py``).

moderngl frees an object's GPU memory only on ``release()``; one that Python collects unreleased
is recorded by the context's ledger as dropped, and its bytes stay counted until the context's
collection queue releases it. These tests fail when any path drops an object: final frames
(hard, soft, shadow maps, the lower qualities, both trace paths), viewport frames (reuse,
interlacing, accumulation), alpha, see-through surfaces, linking and hair, scene edits and the pipeline's release.
"""
from __future__ import annotations

import dataclasses
import gc

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu import memory
from hybrid_shadow_addon.core.gpu.context import create_context
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

SIZE = (160, 90)


def test_an_object_dropped_without_release_is_reported_and_collected():
    ctx = create_context()
    try:
        assert ctx.gc_mode == "context_gc"
        kept = ctx.texture((64, 64), 4, dtype="f4")
        kept.release()
        lost = ctx.texture((64, 64), 4, dtype="f4")
        ctx.program(vertex_shader="#version 410 core\nvoid main(){gl_Position=vec4(0.0);}")
        assert memory.in_use(ctx) == 64 * 64 * 16
        del lost
        gc.collect()
        assert memory.dropped(ctx) == [("Texture", 64 * 64 * 16), ("Program", 0)]
        assert memory.in_use(ctx) == 64 * 64 * 16  # moderngl has not freed it yet
        assert memory.collect(ctx) == 2
        assert memory.in_use(ctx) == 0
    finally:
        ctx.release()


def _orbit(scene, step):
    cam = scene.camera
    m = cam.matrix.copy()
    m[:3, 3] += np.array([0.05, 0.0, 0.02]) * step
    return dataclasses.replace(scene, camera=dataclasses.replace(cam, matrix=m))


def test_no_path_drops_a_gl_object(loaded):
    cube, soft, forest = loaded("cube_on_plane"), loaded("soft_lights"), loaded("forest")
    pipe = Pipeline()
    ctx = pipe.ctx
    try:
        for scene in (cube, soft, forest):
            for settings in (Settings(hard=True), Settings(samples=4), Settings(quality="medium"),
                             Settings(quality="low", hard=True), Settings(mode="shadowmap"),
                             Settings(trace_path="fragment", samples=4), Settings(structure="grid", hard=True)):
                pipe.render(scene, settings, *SIZE)
            pipe.release_targets()
        # the viewport's frames: reuse across a camera move, interlacing, accumulation
        for name in ("alpha_cards", "see_through", "linking", "hair"):
            for settings in (Settings(hard=True), Settings(samples=4, transparency_samples=2)):
                pipe.render(loaded(name), settings, *SIZE)
        pipe.release_targets()
        pipe.reuse, pipe.reuse_choice = True, "always"
        for step in range(3):
            pipe.render(_orbit(forest, step), Settings(hard=True), *SIZE)
        pipe.reuse = False
        for _ in range(3):
            pipe.render(forest, Settings(interlace=True, hard=True), *SIZE)
            pipe.render(soft, Settings(accumulate=True, samples=8, frame_samples=2), *SIZE)
        # scene edits: a moved instance, an edited model, a new scene
        moved = dataclasses.replace(forest, instances=dataclasses.replace(forest.instances))
        moved.instances.matrices = forest.instances.matrices.copy()
        moved.instances.matrices[0, :3, 3] += 0.5
        pipe.set_scene(forest)
        pipe.render(forest, Settings(hard=True), *SIZE)
        pipe.move_instances(moved, [0])
        pipe.update_model(moved, int(moved.instances.model_ids[0]))
        pipe.render(moved, Settings(hard=True), *SIZE)
        pipe.set_scene(cube)
        pipe.render(cube, Settings(samples=4), *SIZE)
        pipe.release_targets(keep_history=True)
        pipe.drop_bake()
        pipe.release()
        gc.collect()
        assert memory.dropped(ctx) == []
        assert memory.in_use(ctx) == 0
    finally:
        ctx.release()
