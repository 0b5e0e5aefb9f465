"""The renderer process (``core/runtime/remote.py``): GL work in a child process, so that waiting
for the driver never holds the caller's Python lock.

- the viewport's RemoteWorker renders what the in-process worker renders (as half floats), in
  another process, and a thread of the caller keeps ticking meanwhile, where the in-process
  worker's GL frames stall it;
- a child that dies is an error on the next poll, and the next render starts a new one;
- a final render gives its targets back (and, without persistent data, its bake), keeps the bake
  with persistent data, and stops within 0.2 s of a cancel, in the bake or between tiles.
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import pytest

from benchmarks.bench_interface import Ticker
from hybrid_shadow_addon.core.errors import Cancelled
from hybrid_shadow_addon.core.runtime.channel import RendererError
from hybrid_shadow_addon.core.runtime.remote import FinalRenderer, RemoteWorker
from hybrid_shadow_addon.core.runtime.render_server import encode_image
from hybrid_shadow_addon.core.runtime.worker import RenderRequest, RenderWorker
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.metrics import frame_mismatch

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

SIZE = (320, 180)


def _request(scene, settings, view="v", size=SIZE):
    return RenderRequest(view=view, scene=dataclasses.replace(scene, resolution=size), fast=settings, full=settings,
                         width=size[0], height=size[1])


def _render(worker, request, timeout=300):
    worker.render(request)
    assert worker.wait_idle(timeout)
    result, errors = worker.poll(request.view)
    assert not errors, errors
    return result


def test_the_process_renders_what_the_thread_renders(loaded):
    scene = loaded("cube_on_plane")
    settings = Settings(hard=True)
    local = RenderWorker()
    remote = RemoteWorker()
    try:
        want = _render(local, _request(scene, settings))
        got = _render(remote, _request(scene, settings))
        assert remote.pid not in (None, os.getpid())
        assert got.image.dtype == np.float16 and got.image.shape == (SIZE[1], SIZE[0], 4)
        assert np.array_equal(got.image, encode_image(want.image))  # bottom-up half floats
        assert got.stats["gpu_memory_mb"] > 0
        # a camera-only change crosses without the scene: the same scene token
        moved = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, matrix=scene.camera.matrix.copy()))
        moved.camera.matrix[0, 3] += 0.25
        token = remote._token
        again = _render(remote, _request(moved, settings))
        assert remote._token == token and not np.array_equal(again.image, got.image)
    finally:
        local.close()
        remote.close()


def test_waiting_for_the_process_does_not_hold_the_lock(loaded):
    """A heavy soft frame: the in-process worker's GL calls stall a ticking thread for a long
    stretch; the renderer process's do not."""
    scene = loaded("forest")
    settings = Settings(samples=64)
    gaps = {}
    for name, make in (("process", RemoteWorker), ("thread", RenderWorker)):
        worker = make()
        try:
            _render(worker, _request(scene, settings, size=(160, 90)))  # warm-up: context, bake, programs
            ticker = Ticker()
            ticker.start()
            t0 = time.perf_counter()
            _render(worker, _request(scene, settings, view="w", size=(640, 360)))
            gaps[name] = (ticker.stop(), (time.perf_counter() - t0) * 1e3)
        finally:
            worker.close()
    (gap_p, _frame_p), (gap_t, frame_t) = gaps["process"], gaps["thread"]
    assert frame_t > 300 and gap_t > 100, gaps  # (the stall the process removes)
    assert gap_p < 100 and gap_p < gap_t / 3, gaps  # (the machine may be busy: scheduling, not the lock)


def test_a_dead_renderer_is_an_error_and_the_next_render_starts_a_new_one(loaded):
    scene = loaded("cube_on_plane")
    settings = Settings(hard=True)
    remote = RemoteWorker()
    try:
        first = _render(remote, _request(scene, settings))
        pid = remote.pid
        remote._proc.kill()
        deadline = time.monotonic() + 10
        errors = []
        while not errors and time.monotonic() < deadline:
            errors = remote.poll("v")[1]
            time.sleep(0.02)
        assert len(errors) == 1 and isinstance(errors[0], RendererError), errors
        assert "ended unexpectedly" in str(errors[0])
        again = _render(remote, _request(scene, settings))
        assert remote.pid != pid and np.array_equal(again.image, first.image)
    finally:
        remote.close()


@pytest.fixture(scope="module")
def final():
    renderer = FinalRenderer()
    yield renderer
    renderer.close()


def test_a_final_render_gives_its_memory_back(loaded, final):
    scene = loaded("soft_lights")
    settings = Settings(samples=4)
    data = final.render(scene, settings, *SIZE, want=("depth",))
    s = data.stats
    assert s["gpu_peak_mb"] > 1.0 and s["gpu_memory_after_mb"] == 0.0, s
    assert set(data.masks) == set(data.lights) and data.buffers["depth"].shape == (SIZE[1], SIZE[0])
    # with persistent data the bake stays (and only it); the next frame updates it
    kept = final.render(scene, settings, *SIZE, persistent_key=("file", "scene", "layer"))
    assert kept.stats["bake"] == "full" and 0.0 < kept.stats["gpu_memory_after_mb"] < kept.stats["gpu_peak_mb"]
    again = final.render(scene, settings, *SIZE, persistent_key=("file", "scene", "layer"))
    assert again.stats["bake"] == "none" and again.stats["gpu_memory_before_mb"] == kept.stats["gpu_memory_after_mb"]
    assert np.array_equal(again.image, kept.image)


def test_ten_final_renders_end_where_the_first_did(loaded, final):
    """Ten F12 renders in one session: after each, the renderer process's resident memory (and
    the driver's figure of video memory, where it reports one) is within 5 % of its level after
    the first, and no GL object was dropped without release."""
    scene = loaded("soft_lights")
    stats = [final.render(scene, Settings(samples=4), *SIZE, want=("depth",)).stats for _ in range(10)]
    assert all(s["gpu_dropped"] == 0 and s["gpu_memory_after_mb"] == 0.0 for s in stats), stats
    for key in ("process_rss_mb", "gpu_driver_used_mb"):
        first = stats[0][key]
        if first is None:
            continue
        assert max(s[key] for s in stats[1:]) <= 1.05 * first, [s[key] for s in stats]


def test_an_animation_with_persistent_data_reuses_hard_masks_when_told_to(loaded, final):
    """With persistent data and ``reuse``, the next frame keeps the hard masks' history (held
    between frames) and stays within the reuse's bound of a fresh frame; without ``reuse``
    nothing is reused and only the bake stays."""
    scene = loaded("forest")
    settings = Settings(hard=True)
    key = ("file", "reuse", "layer")
    cams = [dataclasses.replace(scene.camera, matrix=scene.camera.matrix @ _turn(a)) for a in (0.0, 0.01)]
    frames = [final.render(dataclasses.replace(scene, camera=c), settings, *SIZE, persistent_key=key, reuse=True)
              for c in cams]
    assert frames[0].stats["pixels_reused"] == 0 and frames[1].stats["pixels_reused"] > 0
    assert frames[1].stats["rays_traced"] < 0.5 * frames[0].stats["rays_traced"]
    held = frames[1].stats["gpu_memory_after_mb"]
    fresh = final.render(dataclasses.replace(scene, camera=cams[1]), settings, *SIZE, persistent_key=key)
    assert fresh.stats["pixels_reused"] == 0 and fresh.stats["gpu_memory_after_mb"] < held
    bad, valid = frame_mismatch(frames[1], fresh)
    assert valid and bad <= 0.0002 * valid + 1, (bad, valid)


def _turn(a: float) -> np.ndarray:
    """A rotation by ``a`` radians about the camera's own vertical axis."""
    m = np.eye(4)
    m[0, 0] = m[2, 2] = np.cos(a)
    m[0, 2], m[2, 0] = np.sin(a), -np.sin(a)
    return m


def _cancel_after(final, scene, settings, size, after_s, **options):
    """Render, asking to stop ``after_s`` s in; returns (seconds from the request to the stop,
    the labels reached)."""
    labels = []
    asked = {}

    def should_stop():
        if time.perf_counter() - t0 >= after_s:
            asked.setdefault("t", time.perf_counter())
            return True
        return False

    t0 = time.perf_counter()
    with pytest.raises(Cancelled):
        final.render(scene, settings, *size, should_stop=should_stop,
                     on_progress=lambda d, n, label: labels.append(label), **options)
    return time.perf_counter() - asked["t"], labels


def test_a_cancelled_final_render_stops_within_0_2_s(loaded, final):
    scene = loaded("forest")
    settings = Settings(samples=64)
    first = final.render(scene, Settings(hard=True), 64, 36)  # programs compiled, process up
    pid = final.pid
    # between tiles of the soft trace
    took, labels = _cancel_after(final, scene, settings, (960, 540), 1.5, max_draw_ms=100.0)
    assert took < 0.2, (took, labels[-3:])
    assert any("tile" in label for label in labels), labels[-5:]
    # in the bake (a structure of its own: baked afresh)
    took, labels = _cancel_after(final, scene, dataclasses.replace(settings, structure="grid"), (960, 540), 0.02)
    assert took < 0.2, (took, labels[-3:])
    # the next render works (in the same process where the child stopped in time, else a new one)
    again = final.render(scene, Settings(hard=True), 64, 36)
    assert np.array_equal(again.image, first.image)
    assert final.pid == pid or final.starts > 1


def test_queued_moves_and_model_edits_merge(loaded):
    """A drag queues one move per depsgraph update: the worker applies one for all those still
    queued (every instance they moved, the newest scene), and one edit per model."""
    from hybrid_shadow_addon.core.runtime.messages import MoveInstances

    scene = loaded("cube_on_plane")
    worker = RenderWorker(synchronous=True)  # (inline: nothing runs until pump)
    try:
        for idx in ([0], [1], [0]):
            worker.move_instances(scene, idx)
        worker.update_model(scene, 0)
        worker.reset_history()
        worker.update_model(scene, 0)
        kinds = [it[0] for it in worker._queue]
        assert kinds == ["move", "reset", "model"], kinds
        assert worker._queue[0][2].tolist() == [0, 1]
        # a bake stands for what was queued before it; a later move merges with nothing before it
        worker.set_scene(scene)
        worker.move_instances(scene, [1])
        kinds = [it[0] for it in worker._queue]
        assert kinds == ["reset", "bake", "move"], kinds
        assert worker._queue[2][2].tolist() == [1]
    finally:
        worker.close()
    merged = MoveInstances("new", np.array([1, 2])).merged([MoveInstances("old", np.array([3, 1]))])
    assert merged.scene == "new" and merged.indices.tolist() == [1, 2, 3]


def test_renders_rewritten_to_a_new_scene_are_queued_behind_it():
    """A render waiting for a scene the sender already took is rewritten to the newer scene and
    queued behind it: the child never gets a render before its scene."""
    import collections
    import itertools
    import threading

    from hybrid_shadow_addon.core.runtime.renderer_process import RendererProcess

    proc = RendererProcess.__new__(RendererProcess)  # (no threads: the queue alone)
    proc._cond, proc._outbox, proc._seq, proc._closing = threading.Condition(), collections.deque(), \
        itertools.count(1), False
    proc.post(("render", "view", 5, 1))
    proc.post(("move", "scene", [0]))
    proc.post(("scene", 6, "newer"), replace=lambda b: b[0] == "scene",
              rewrite=lambda b: (b[0], b[1], 6, b[3]) if b[0] == "render" else b)
    assert [b for _, b in proc._outbox] == [("move", "scene", [0]), ("scene", 6, "newer"), ("render", "view", 6, 1)]


def test_compare_measures_in_the_process_and_a_closed_call_cancels(loaded, final):
    from hybrid_shadow_addon.tools.compare import measure_variants
    from hybrid_shadow_addon.tools.variants import resolve_variants

    scene = loaded("cube_on_plane")
    job = dict(scene=scene, variants=resolve_variants(["raytrace-high,none"]), names=[scene.lights[0].name],
               light_index={scene.lights[0].name: 0}, size=(80, 60), warmup=1, repeats=2)
    steps = final.call_steps(measure_variants, job)
    labels = []
    while len(labels) < 2:
        label = next(steps)
        if label is not None:
            labels.append(label)
    t0 = time.perf_counter()
    steps.close()  # (a cancelled compare)
    assert time.perf_counter() - t0 < 0.3 and labels[0].startswith("bake")
    steps = final.call_steps(measure_variants, job)
    seen = []
    while True:
        try:
            label = next(steps)
        except StopIteration as stop:
            result = stop.value
            break
        if label is not None:
            seen.append(label)
    assert len(seen) == 1 + 2 * (1 + 2 + 1) and len(result["runs"]) == 2
    shadow, total, masks = result["runs"][0]
    assert len(shadow) == 2 and masks[scene.lights[0].name].shape == (60, 80)


def test_a_render_region_renders_that_part_of_the_view(loaded, final):
    """View ▸ Render Region: the cropped projection renders the region's pixels of the whole
    view's frame (same image, same masks), at the region's size."""
    from hybrid_shadow_addon.blender.viewport import crop_window, viewport_camera

    scene = loaded("cube_on_plane")
    W, H = 160, 120
    view = np.linalg.inv(scene.camera.world_matrix_normalized())
    window = scene.camera.projection_matrix(W, H)
    settings = Settings(hard=True)
    whole = final.render(dataclasses.replace(scene, camera=viewport_camera(view, window, W, H)), settings, W, H)
    x0, y0, w, h = rect = (40, 30, 64, 48)  # (bottom-up pixels)
    part = final.render(dataclasses.replace(scene, camera=viewport_camera(view, crop_window(window, rect, W, H), w, h)),
                        settings, w, h)
    rows, cols = slice(H - y0 - h, H - y0), slice(x0, x0 + w)
    assert part.image.shape == (h, w, 4)
    assert np.abs(part.image - whole.image[rows, cols]).max() < 1e-4
    a, b = part.mask_array(part.lights[0]), whole.mask_array(whole.lights[0])[rows, cols]
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.nanmax(np.abs(a - b)) == 0.0
    assert 0.0 < np.nanmean(a) < 1.0  # (the region holds a shadow edge)
    assert np.array_equal(crop_window(window, (0, 0, W, H), W, H), window)
