"""A viewport session under load: 10,000 random edits (moves, colour and light changes, edited
meshes, objects added and deleted) against the renderer process, frames asked for as a viewport
redraws. The last frame equals a fresh render of the final scene, and neither process grows (its
resident memory after the edits within 5 % of its level after a warm-up of 1,000 edits)."""
from __future__ import annotations

import dataclasses
import os
import random

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.memory import process_rss_mb
from hybrid_shadow_addon.core.runtime.remote import RemoteWorker
from hybrid_shadow_addon.core.runtime.worker import RenderRequest
from hybrid_shadow_addon.core.scene import Instances, Light, Scene
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import basic_scene, cube_model, plane_model, trs

pytestmark = [pytest.mark.gpu, pytest.mark.slow]

EDITS = 10_000
WARMUP = 1_000
SIZE = (96, 54)
SETTINGS = Settings(hard=True)


class Session:
    """The scene as plain state, rebuilt into a core Scene after each edit."""

    def __init__(self, rng: random.Random):
        self.rng = rng
        base = basic_scene()
        self.camera = base.camera
        self.objects = [["ground", 0, trs((0, 0, 0), scale=(5, 5, 1)), (0.8, 0.8, 0.8, 1)]]
        for k in range(6):
            self.objects.append([f"box{k}", 1, self._place(), self._colour()])
        self.lights = [["sun", "SUN", 3.0, trs((0, 0, 10), rot_z=0.5, rot_x=0.6)],
                       ["lamp", "POINT", 400.0, trs((1.0, -1.0, 3.0))]]
        self.cube_scale = 1.0
        self.added = 0

    def _place(self):
        r = self.rng
        return trs((r.uniform(-3, 3), r.uniform(-3, 3), r.uniform(0.3, 1.5)), rot_z=r.uniform(0, 3),
                   scale=(r.uniform(0.2, 0.6),) * 3)

    def _colour(self):
        return (self.rng.random(), self.rng.random(), self.rng.random(), 1.0)

    def scene(self) -> Scene:
        cube = cube_model()
        cube = dataclasses.replace(cube, vertices=(cube.vertices * np.float32(self.cube_scale)).astype(np.float32))
        inst = Instances(names=[o[0] for o in self.objects], model_ids=[o[1] for o in self.objects],
                         matrices=np.array([o[2] for o in self.objects]), base_color=[o[3] for o in self.objects])
        lights = [Light(n, t, power=p, matrix=m) for n, t, p, m in self.lights]
        return Scene(models=[plane_model(), cube], instances=inst, lights=lights, camera=self.camera,
                     world_color=(0.05, 0.06, 0.08), resolution=SIZE)

    def edit(self, worker) -> Scene:
        """One random edit, told to ``worker`` as the viewport tells its renderer."""
        r = self.rng.random()
        boxes = range(1, len(self.objects))
        if r < 0.55 and len(boxes):
            i = self.rng.choice(boxes)
            self.objects[i][2] = self._place()
            scene = self.scene()
            worker.move_instances(scene, [i])
        elif r < 0.70 and len(boxes):
            self.objects[self.rng.choice(boxes)][3] = self._colour()
            scene = self.scene()  # (a colour: the bake stays)
        elif r < 0.80:
            i = self.rng.randrange(len(self.lights))
            light = self.lights[i]
            light[3] = trs((self.rng.uniform(-2, 2), self.rng.uniform(-2, 2), self.rng.uniform(3, 9)),
                           rot_z=self.rng.uniform(0, 1), rot_x=self.rng.uniform(0, 0.8))
            scene = self.scene()
            worker.reset_light(i)
        elif r < 0.85:
            self.lights[self.rng.randrange(len(self.lights))][2] *= self.rng.uniform(0.8, 1.25)
            scene = self.scene()  # (power only: every mask stands)
        elif r < 0.90:
            self.cube_scale = self.rng.uniform(0.7, 1.3)
            scene = self.scene()
            worker.update_model(scene, 1)
        else:
            if len(self.objects) > 2 and self.rng.random() < 0.5:
                del self.objects[self.rng.choice(boxes)]
            else:
                self.added += 1
                self.objects.append([f"added{self.added}", 1, self._place(), self._colour()])
            scene = self.scene()
            worker.set_scene(scene)
        return scene


def _request(scene):
    return RenderRequest(view="v", scene=scene, fast=SETTINGS, full=SETTINGS, width=SIZE[0], height=SIZE[1])


def _last_frame(worker, scene):
    worker.render(_request(scene))
    assert worker.wait_idle(300)
    result, errors = worker.poll("v")
    assert errors == [], errors
    return result


def test_ten_thousand_edits_end_as_a_fresh_render_without_growing():
    rng = random.Random(50)
    session = Session(rng)
    worker = RemoteWorker()
    fresh = RemoteWorker()
    try:
        scene = session.scene()
        worker.set_scene(scene)
        rss = {}
        for k in range(1, EDITS + 1):
            scene = session.edit(worker)
            if k % 4 == 0:
                worker.render(_request(scene))
            if k % 250 == 0:
                assert worker.wait_idle(300)
                assert worker.poll("v")[1] == []
            if k == WARMUP:
                rss["warm"] = (process_rss_mb(worker.pid), process_rss_mb(os.getpid()))
        got = _last_frame(worker, scene)
        rss["end"] = (process_rss_mb(worker.pid), process_rss_mb(os.getpid()))
        fresh.set_scene(scene)
        want = _last_frame(fresh, scene)
        assert np.array_equal(got.image, want.image)
        for who, (warm, end) in zip(("renderer", "caller"), zip(rss["warm"], rss["end"])):
            assert end <= 1.05 * warm, (who, warm, end)
    finally:
        worker.close()
        fresh.close()
