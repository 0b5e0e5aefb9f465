"""Tiled draws under a per-draw budget (``Pipeline.render(max_draw_ms=...)``) write what whole
draws write, bit for bit; a progress callback that raises stops a bake, a light grid's build and
a tiled trace within 0.2 s, and the next render works as if nothing had happened."""
import threading
import time

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.errors import Cancelled
from hybrid_shadow_addon.core.gpu.passes.trace import RaytraceOptions
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import all_lights, basic_scene, random_scene, soft_scene

pytestmark = pytest.mark.gpu

STOP_S = 0.2  # a cancel stops the work within this


def _frame(pipe, scene, settings, max_draw_ms, progress=None, size=(160, 120)):
    pipe.reset_history()
    frame = pipe.render(scene, settings, *size, max_draw_ms=max_draw_ms, progress=progress)
    return frame.image, {li: frame.mask_array(li) for li in frame.lights}


def _assert_same(a, b):
    img_a, masks_a = a
    img_b, masks_b = b
    assert masks_a.keys() == masks_b.keys() and masks_a
    for li in masks_a:
        np.testing.assert_array_equal(masks_a[li], masks_b[li], err_msg=f"mask of light {li}")
    np.testing.assert_array_equal(img_a, img_b)


CASES = {
    "hard": (basic_scene(lights=all_lights()), Settings(hard=True)),
    "medium": (basic_scene(lights=all_lights()), Settings(hard=True, quality="medium")),
    "soft": (soft_scene(), Settings(samples=16)),
    "interlaced": (basic_scene(lights=all_lights()), Settings(hard=True, interlace=True)),
    "shadowmap": (soft_scene(), Settings(mode="shadowmap")),
}


@pytest.fixture(scope="module")
def tiled_pipeline(gl_ctx):
    """A pipeline of its own (its targets apart from ``pipeline``'s, so that a tile left
    undrawn cannot show the whole draw's pixels)."""
    p = Pipeline(gl_ctx)
    yield p
    p.release()


@pytest.mark.parametrize("case", sorted(CASES))
def test_tiled_equals_whole(pipeline, tiled_pipeline, case):
    scene, settings = CASES[case]
    frames = 3 if settings.interlace else 1  # (interlacing: the history and the refinement too)
    whole = [_frame(pipeline, scene, settings, None) for _ in range(frames)]
    budget = tiled_pipeline.gpu.budget
    budget.reset_stats()
    ticks = []
    tiled = [_frame(tiled_pipeline, scene, settings, 1e-3, progress=lambda d, t, label: ticks.append((d, label)))
             for _ in range(frames)]
    assert budget.tiles > 8 * frames  # (16-pixel tiles at the least budget: many per draw)
    for a, b in zip(whole, tiled):
        _assert_same(a, b)
    tile_ticks = [d for d, label in ticks if "(tile " in label]
    assert len(tile_ticks) == budget.tiles
    assert all(b >= a for a, b in zip(tile_ticks, tile_ticks[1:]) if b // 1 == a // 1)  # within a step: forward


def test_tiles_follow_the_budget(pipeline):
    """A heavy final render at 640x360 takes several bands per draw; the longest is reported."""
    scene = soft_scene()
    budget = pipeline.gpu.budget
    budget.reset_stats()
    t0 = time.perf_counter()
    pipeline.render(scene, Settings(samples=64), 640, 360, max_draw_ms=20.0)
    total_ms = (time.perf_counter() - t0) * 1e3
    print(f"640x360 soft, 64 samples: {budget.tiles} tiles, longest {budget.longest_ms:.1f} ms "
          f"(budget 20 ms), frame {total_ms:.0f} ms")
    assert budget.tiles > 1
    budget.reset_stats()
    pipeline.render(scene, Settings(samples=64), 640, 360)
    assert budget.tiles == 0  # (no budget: whole draws)


class _CancelAfter:
    """A progress callback that raises Cancelled at its first call after a cancel was asked
    for: by a timer ``after_s`` after :meth:`start` or, with ``when``, after the first label
    holding it (at once without ``after_s``); :meth:`caught` is the time from the request."""

    def __init__(self, after_s: float | None = None, when: str | None = None):
        self.after_s, self.when = after_s, when
        self.requested = None
        self.started = False

    def start(self):
        if not self.started and self.after_s is not None:
            self.started = True
            timer = threading.Timer(self.after_s, self._request)
            timer.daemon = True
            timer.start()
        return self

    def _request(self):
        if self.requested is None:
            self.requested = time.perf_counter()

    def __call__(self, done, total, label=""):
        if self.when is not None and self.when in label:
            if self.after_s is None:
                self._request()
            self.start()
        if self.requested is not None:
            raise Cancelled("cancelled by the test")

    def caught(self) -> float:
        assert self.requested is not None, "the work ended before the cancel was asked for"
        return time.perf_counter() - self.requested


def _big_scene():
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n_inst=400, tri_counts=tuple(range(200, 4200, 40)) + (300000, 500000))
    base = basic_scene(lights=all_lights())
    scene.camera, scene.lights, scene.resolution = base.camera, base.lights, (160, 120)
    return scene


def test_cancel_stops_a_bake(gl_ctx):
    scene = _big_scene()
    cancel = _CancelAfter(after_s=0.15).start()
    with pytest.raises(Cancelled):
        bake_scene(scene, BakeConfig(), progress=cancel)
    latency = cancel.caught()
    print(f"bake cancelled {latency * 1e3:.0f} ms after the request")
    assert latency < STOP_S
    pipe = Pipeline(gl_ctx)
    try:  # a pipeline's bake stopped: no bake (or the one before); the next render bakes
        pipe.set_scene(basic_scene(), "bvh")
        old = pipe.baked
        cancel = _CancelAfter(after_s=0.15).start()
        with pytest.raises(Cancelled):
            pipe.set_scene(scene, "bvh", progress=cancel)
        assert cancel.caught() < STOP_S
        assert pipe.baked is old
        cancel = _CancelAfter(after_s=0.15).start()
        with pytest.raises(Cancelled):
            pipe.render(scene, Settings(hard=True, structure="grid"), progress=cancel)
        assert cancel.caught() < STOP_S
        frame = pipe.render(scene, Settings(hard=True, structure="grid"))
        assert pipe.baked.structure == "grid" and np.isfinite(frame.image).all()
    finally:
        pipe.release()


def test_cancel_stops_an_update(gl_ctx):
    scene = _big_scene()
    pipe = Pipeline(gl_ctx)
    try:
        pipe.set_scene(scene, "bvh")
        big = len(scene.models) - 2  # (the 500k-triangle model)
        cancel = _CancelAfter(after_s=0.03).start()
        with pytest.raises(Cancelled):
            pipe.update_model(scene, big, progress=cancel)
        assert cancel.caught() < STOP_S
        assert pipe.baked is None  # (half updated: dropped)
        frame = pipe.render(scene, Settings(hard=True))  # (bakes again)
        assert pipe.baked is not None and np.isfinite(frame.image).all()
    finally:
        pipe.release()


@pytest.mark.slow
def test_cancel_stops_a_light_grid_build(gl_ctx, loaded):
    scene = loaded("forest")
    settings = Settings(hard=True, max_shadowed_lights=2)
    pipe = Pipeline(gl_ctx)
    try:
        rp = pipe.shadow_pass("raytrace")
        rp.options = RaytraceOptions(eager_light_grids=True)
        pipe.set_scene(scene, "bvh")
        cancel = _CancelAfter(after_s=0.3, when="light grid of")  # (0.3 s into the first build)
        with pytest.raises(Cancelled):
            pipe.render(scene, settings, progress=cancel)
        latency = cancel.caught()
        print(f"light grid build cancelled {latency * 1e3:.0f} ms after the request")
        assert latency < STOP_S
        assert not rp.light_grids._grids  # (nothing half-built kept)
        frame = pipe.render(scene, settings)
        assert rp.light_grids.last and np.isfinite(frame.image).all()  # (the grids built in full)
    finally:
        pipe.release()


def test_cancel_stops_a_tiled_trace(pipeline):
    scene, settings = soft_scene(), Settings(samples=64)
    reference = _frame(pipeline, scene, settings, None, size=(320, 240))
    cancel = _CancelAfter(when="(tile 3)")
    with pytest.raises(Cancelled):
        _frame(pipeline, scene, settings, 5.0, progress=cancel, size=(320, 240))
    latency = cancel.caught()
    print(f"tiled trace cancelled {latency * 1e3:.1f} ms after the request")
    assert latency < STOP_S
    assert pipeline.ctx.scissor is None or pipeline.ctx.scissor == (0, 0, *pipeline.ctx.fbo.size)
    _assert_same(reference, _frame(pipeline, scene, settings, 5.0, size=(320, 240)))
    _assert_same(reference, _frame(pipeline, scene, settings, None, size=(320, 240)))
