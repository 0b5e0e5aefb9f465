"""The viewport's render worker and the sharing between viewports (core/runtime/worker.py), bpy-free
apart from loading the test scene: the worker's frames equal direct ``Pipeline.render`` calls;
render requests coalesce; commands apply in order (and stale refinement stops); errors surface
once and the worker goes on; ``close`` is prompt and an interpreter exits with a live worker;
views sharing one bake keep their own history; snapshots are copy-on-write; the registry and
the update rounds share and de-duplicate."""
import copy
import dataclasses
import threading
import time

import numpy as np
import pytest

from hybrid_shadow_addon.blender import gl  # bpy-free: the context hygiene of Blender's threads
from hybrid_shadow_addon.core.gpu.context import software_renderer
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.runtime.viewport_share import SharedRegistry, SharedViewport, UpdateRounds
from hybrid_shadow_addon.core.runtime.worker import (
    RenderRequest,
    RenderWorker,
    fast_settings,
    refine_frames,
    snapshot,
    writable_matrices,
)
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

W, H = 96, 72
FULL = Settings(mode="raytrace", quality="high", hard=True)
FAST = Settings(mode="raytrace", quality="low", hard=True)


@pytest.fixture(scope="module")
def base(loaded):
    return copy.deepcopy(loaded("animated"))


@pytest.fixture(scope="module")
def worker():
    w = RenderWorker()
    yield w
    w.close()


@pytest.fixture()
def direct(gl_ctx):
    p = Pipeline(gl_ctx)
    yield p
    p.release()


def inline_worker():
    """A synchronous worker whose context steps restore the caller's (the session's) context."""
    return RenderWorker(create=gl.create_pipeline, scope=gl.gl_scope, release=gl.release_pipeline,
                        synchronous=True)


def request(view, scene, fast=FULL, full=FULL, w=W, h=H, post=None):
    return RenderRequest(view=view, scene=snapshot(scene), fast=fast, full=full, width=w, height=h, post=post)


def finish(worker, view):
    assert worker.wait_idle(120)
    result, errors = worker.poll(view)
    assert not errors, errors
    return result


def moved(scene, name="Cube", by=(1.5, 0.5, 0.0)):
    i = scene.instances.names.index(name)
    writable_matrices(scene.instances)  # (as the viewport sync does: snapshots share them)
    m = scene.instances.matrices[i].copy()
    m[:3, 3] += by
    scene.instances.set_matrices([i], m[None])
    return i


def test_worker_renders_what_the_pipeline_renders(worker, direct, base):
    worker.set_scene(base)
    worker.render(request("a", base))
    got = finish(worker, "a")
    direct.set_scene(base)
    want = direct.render(base, FULL, W, H)
    assert got.image.shape == (H, W, 4) and got.step == 0 and got.refine_left == 0
    np.testing.assert_array_equal(got.image, want.image)
    assert threading.current_thread() is not worker._thread and worker.thread_alive


def test_refinement_runs_in_the_worker(worker, direct, base):
    """Fast pass, then the full-quality frames: 4 with interlacing (one per ray phase); the last
    frame equals the same sequence rendered directly."""
    inter = Settings(mode="raytrace", quality="high", hard=True, interlace=True)
    assert refine_frames(FAST, FULL) == 1 and refine_frames(FULL, FULL) == 0 and refine_frames(FAST, inter) == 4
    worker.set_scene(base)
    n = len(worker.log)
    seq = worker.render(request("r", base, fast=FAST, full=inter))
    last = finish(worker, "r")
    steps = [(s, q, left) for v, sq, s, q, left in worker.log[n:] if v == "r" and sq == seq]
    assert steps == [(0, "low", 4), (1, "high", 3), (2, "high", 2), (3, "high", 1), (4, "high", 0)]
    direct.set_scene(base)
    direct.render(base, FAST, W, H)
    for _ in range(4):
        want = direct.render(base, inter, W, H)
    np.testing.assert_array_equal(last.image, want.image)


def test_automatic_navigation_quality_follows_the_renderer(worker, base, direct):
    """``fast_auto``: on a software rasteriser (this one) the fast pass keeps the full pass's
    quality, so a hard-lit change is one frame; on a GPU it is the request's fast settings; soft
    lights keep the fast pass's fewer samples either way."""
    assert software_renderer("llvmpipe (LLVM 15.0.6, 256 bits)") and software_renderer("Apple Software Renderer")
    assert not software_renderer("NVIDIA H200/PCIe/SSE2") and not software_renderer("AMD Radeon Pro 5500M")
    auto = RenderRequest(view="x", scene=None, fast=FAST, full=FULL, width=W, height=H, fast_auto=True)
    assert fast_settings(auto, "llvmpipe (LLVM 15.0.6, 256 bits)") == FULL
    assert fast_settings(auto, "NVIDIA H200/PCIe/SSE2") == FAST
    assert fast_settings(dataclasses.replace(auto, fast_auto=False), "llvmpipe") == FAST
    soft_full = Settings(mode="raytrace", quality="high", hard=False, accumulate=True, samples=20, frame_samples=4)
    soft_fast = soft_full.replace(quality="low", samples=4)
    soft = dataclasses.replace(auto, fast=soft_fast, full=soft_full)
    assert fast_settings(soft, "llvmpipe") == soft_full.replace(samples=4)
    # the worker, on this machine's renderer (llvmpipe here and in CI)
    cpu = software_renderer(direct.ctx.info["GL_RENDERER"])
    worker.set_scene(base)
    n = len(worker.log)
    req = request("auto", base, fast=FAST, full=FULL)
    seq = worker.render(dataclasses.replace(req, fast_auto=True))
    got = finish(worker, "auto")
    steps = [(s, q, left) for v, sq, s, q, left in worker.log[n:] if v == "auto" and sq == seq]
    assert steps == ([(0, "high", 0)] if cpu else [(0, "low", 1), (1, "high", 0)])
    assert got.settings == FULL


def test_a_reusing_view_traces_one_exact_frame_once_it_rests(worker, base, direct):
    """A view that reuses: after a camera move its frame keeps what stands, then one more frame
    traces the hard masks whole, equal to a fresh render of the view."""
    worker.set_scene(base)
    worker.render(dataclasses.replace(request("reuse", base), reuse=True))
    first = finish(worker, "reuse")
    assert first.stats["reuse_ways"]["reused"] == 0 and first.stats["pixels_reused"] is None  # (not read back)
    cam = dataclasses.replace(base.camera, matrix=base.camera.matrix.copy())
    cam.matrix[:3, 3] += (0.02, 0.0, 0.0)
    turned = dataclasses.replace(base, camera=cam)
    n = len(worker.log)
    seq = worker.render(dataclasses.replace(request("reuse", turned), reuse=True))
    last = finish(worker, "reuse")
    steps = [(s, left) for v, sq, s, q, left in worker.log[n:] if v == "reuse" and sq == seq]
    assert steps == [(0, 1), (1, 0)]
    assert last.stats["reuse_ways"]["reused"] == 0
    direct.set_scene(base)
    np.testing.assert_array_equal(last.image, direct.render(turned, FULL, W, H).image)


def test_soft_shadows_accumulate_until_the_samples(worker, base):
    # (the first full frame gives the penumbrae 16 samples, the next one adds 4)
    soft_full = Settings(mode="raytrace", quality="high", hard=False, accumulate=True, samples=20, frame_samples=4)
    soft_fast = Settings(mode="raytrace", quality="low", hard=False, accumulate=True, samples=4, frame_samples=4)
    worker.set_scene(base)
    n = len(worker.log)
    seq = worker.render(request("s", base, fast=soft_fast, full=soft_full))
    last = finish(worker, "s")
    steps = [(s, left) for v, sq, s, q, left in worker.log[n:] if v == "s" and sq == seq]
    assert steps == [(0, 1), (1, 1), (2, 0)]
    assert last.stats["accumulated_samples"] == 20


def test_see_through_surfaces_accumulate_until_the_samples(worker):
    """A view with see-through panes: one sub-frame per step until transparency_samples, then it
    stops; the last frame is the final render's average."""
    from tests.helpers.scenes import pane_scene

    sc = pane_scene()
    full = Settings(mode="raytrace", quality="high", hard=True, accumulate=True, transparency_samples=5)
    worker.set_scene(sc)
    n = len(worker.log)
    seq = worker.render(request("p", sc, fast=full, full=full, w=160, h=120))
    last = finish(worker, "p")
    steps = [(s, left) for v, sq, s, q, left in worker.log[n:] if v == "p" and sq == seq]
    assert steps == [(0, 1), (1, 1), (2, 1), (3, 1), (4, 0)]
    assert last.stats["see_through_samples"] == 5
    p = Pipeline()
    try:
        final = p.render(sc, full.replace(accumulate=False), 160, 120)
        assert np.allclose(last.image, final.image, atol=1e-5)
    finally:
        p.release()


def test_requests_for_a_view_coalesce(worker, base):
    gate = threading.Event()

    def hold(frame, scene, pipe):
        gate.wait(30)
        return frame.image

    worker.set_scene(base)
    worker.render(request("hold", base, post=hold))
    while not worker.busy("hold") or worker._active is None:
        time.sleep(0.01)
    n0, c0 = len(worker.log), worker.coalesced
    seqs = [worker.render(request("c", base)) for _ in range(5)]
    gate.set()
    got = finish(worker, "c")
    rendered = [sq for v, sq, *_ in worker.log[n0:] if v == "c"]
    assert rendered == [seqs[-1]] and got.seq == seqs[-1]
    assert worker.coalesced - c0 == 4


def test_updates_apply_in_order_before_later_renders(worker, gl_ctx, base):
    """A move then a render shows the move, and its masks equal a fresh bake's; the render
    snapshot keeps the moved scene even when the caller moves its scene on meanwhile."""
    scene = copy.deepcopy(base)
    worker.set_scene(scene)
    worker.render(request("m", scene))
    finish(worker, "m")
    idx = moved(scene)
    worker.move_instances(scene, [idx])
    want_scene = copy.deepcopy(scene)
    masks = {}

    def keep_masks(frame, s, pipe):
        masks.update({s.lights[li].name: frame.mask_array(li) for li in frame.lights})
        return frame.image

    worker.render(request("m", scene, post=keep_masks))
    moved(scene, by=(-4.0, 0.0, 0.0))  # the caller's scene moves on: the queued render must not see it
    got = finish(worker, "m")
    fresh = Pipeline(gl_ctx)
    try:
        fresh.set_scene(want_scene)
        f = fresh.render(want_scene, FULL, W, H)
        want = {want_scene.lights[li].name: f.mask_array(li) for li in f.lights}
        np.testing.assert_array_equal(got.image, f.image)
    finally:
        fresh.release()
    assert masks.keys() == want.keys() and masks
    for k in want:
        np.testing.assert_array_equal(masks[k], want[k], err_msg=k)


def test_an_error_surfaces_once_and_the_worker_goes_on(worker, base):
    def boom(frame, scene, pipe):
        raise ValueError("boom in the worker")

    worker.set_scene(base)
    worker.render(request("e", base, post=boom))
    assert worker.wait_idle(120)
    assert worker.has_news("e")
    result, errors = worker.poll("e")
    assert result is None and [str(e) for e in errors] == ["boom in the worker"]
    assert worker.poll("e") == (None, [])
    assert worker.poll("other")[1] == []  # a view's error is that view's
    worker.render(request("e", base))
    assert finish(worker, "e").image.shape == (H, W, 4)


def test_a_scene_command_error_reaches_every_view(base):
    w = RenderWorker()
    try:
        w.move_instances(base, [0])  # nothing baked yet: skipped, not an error
        w.update_model(base, 10 ** 6)
        w.set_scene(base)
        w.update_model(base, 10 ** 6)  # no such model
        assert w.wait_idle(120)
        errs_a, errs_b = w.poll("a")[1], w.poll("b")[1]
        assert len(errs_a) == 1 and len(errs_b) == 1 and errs_a[0] is errs_b[0]
        assert w.poll("a")[1] == []
        w.render(request("a", base))
        assert finish(w, "a").image.shape == (H, W, 4)  # re-baked after the failed update
    finally:
        w.close()


def test_close_is_prompt_with_queued_work(base):
    w = RenderWorker()
    gate = threading.Event()

    def hold(frame, scene, pipe):
        gate.wait(30)
        return frame.image

    w.set_scene(base)
    w.render(request("hold", base, post=hold))
    for i in range(20):
        w.render(request(f"v{i}", base))
    while w._active is None or w._active[0] != "render":
        time.sleep(0.01)
    threading.Timer(0.2, gate.set).start()
    t0 = time.perf_counter()
    w.close()
    dt = time.perf_counter() - t0
    assert not w.thread_alive and dt < 3.0, dt
    assert not any(v.startswith("v") for v, *_ in w.log)  # the queue was dropped
    assert w._pipe is None
    w.render(request("late", base))  # closed: ignored
    assert not w.busy()


def test_two_views_sharing_a_bake_keep_their_histories(worker, gl_ctx, base):
    """Two viewport sizes refining interlaced frames at once (their steps alternate in the
    worker): each ends with what it renders alone."""
    inter = Settings(mode="raytrace", quality="high", hard=True, interlace=True)
    sizes = {"small": (W, H), "big": (128, 96)}
    want = {}
    for name, (w, h) in sizes.items():
        alone = Pipeline(gl_ctx)
        try:
            alone.set_scene(base)
            for _ in range(5):
                frame = alone.render(base, inter, w, h)
            want[name] = frame.image
        finally:
            alone.release()
    worker.set_scene(base)
    n = len(worker.log)
    for name, (w, h) in sizes.items():
        worker.render(request(name, base, fast=inter, full=inter, w=w, h=h))
    assert worker.wait_idle(120)
    order = [v for v, *_ in worker.log[n:]]
    assert order == ["small", "big"] * 5  # interleaved
    for name in sizes:
        got, errors = worker.poll(name)
        assert not errors and got.step == 4
        np.testing.assert_array_equal(got.image, want[name], err_msg=name)


def test_views_share_the_bake_of_their_pipeline(gl_ctx, base):
    owner = Pipeline(gl_ctx)
    a, b = owner.view(), owner.view()
    try:
        assert a.gpu is owner.gpu and a.baked is None
        a.render(base, FULL, W, H)  # bakes through a view
        assert owner.baked is a.baked is b.baked is not None
        scene = copy.deepcopy(base)
        i = moved(scene)
        inter = Settings(mode="raytrace", quality="high", hard=True, interlace=True)
        b.render(scene, inter, W, H)
        b.render(scene, inter, W, H)
        hist = b.shadow_pass("raytrace").hard._valid_phases
        a.move_instances(scene, [i])  # another view's bake change: b's history is stale
        first = b.render(scene, inter, W, H)
        fresh = Pipeline(gl_ctx)
        try:
            fresh.set_scene(scene)
            fresh.render(scene, inter, W, H)
            fresh.render(scene, inter, W, H)  # (the same interlacing phase as b)
            fresh.set_scene(scene)
            np.testing.assert_array_equal(first.image, fresh.render(scene, inter, W, H).image)
        finally:
            fresh.release()
        assert hist != 0
    finally:
        a.release()
        b.release()
        owner.release()


def test_synchronous_mode_runs_inline_one_frame_per_pump(gl_ctx, base):
    w = inline_worker()
    try:
        assert w._thread is None
        w.set_scene(base)
        w.render(request("i", base, fast=FAST, full=FULL))
        assert w.busy("i") and w.poll("i") == (None, [])  # nothing runs until pumped
        w.pump()
        r0, _ = w.poll("i")
        assert r0.step == 0 and r0.refine_left == 1 and w.busy("i")
        w.pump()
        r1, _ = w.poll("i")
        assert r1.step == 1 and r1.refine_left == 0 and not w.busy("i")
        direct = Pipeline(gl_ctx)
        try:
            direct.set_scene(base)
            direct.render(base, FAST, W, H)
            np.testing.assert_array_equal(r1.image, direct.render(base, FULL, W, H).image)
        finally:
            direct.release()
    finally:
        w.close()
    assert w._pipe is None


def test_a_scene_change_stops_refinement_in_progress(base):
    w = inline_worker()
    try:
        w.set_scene(base)
        w.render(request("i", base, fast=FAST, full=FULL))
        w.pump()
        assert w.busy("i")
        w.reset_history()  # e.g. a light changed: the caller renders again
        w.pump()
        assert w.poll("i")[0] is not None and not w.busy("i")
        assert [s for v, sq, s, *_ in w.log] == [0]
        # a move queued behind a render request: that request's refinement would render its
        # snapshot (from before the move) over the moved bake, so it stops after its first frame
        scene = copy.deepcopy(base)
        w.render(request("i", scene, fast=FAST, full=FULL))
        w.move_instances(scene, [moved(scene)])
        w.wait_idle()
        assert [s for v, sq, s, *_ in w.log] == [0, 0] and not w.busy()
    finally:
        w.close()


# -- sharing ---------------------------------------------------------------------------------------
def test_update_rounds_apply_each_update_once():
    r = UpdateRounds()
    assert r.should_apply("A", (1, "move cube"))
    assert not r.should_apply("B", (1, "move cube"))  # the same update, seen by another viewport
    assert r.should_apply("A", (1, "move cube"))  # A again: a genuine second edit
    assert not r.should_apply("B", (1, "move cube"))
    assert r.should_apply("B", (2, "move cube"))  # B first this time
    assert not r.should_apply("A", (2, "move cube"))
    assert r.should_apply("A", (2, "move ball"))  # other updates


class FakeSync:
    def __init__(self):
        self.scene = None
        self.applied = []

    def update(self, depsgraph):
        self.applied.append(depsgraph)

        class Plan:
            nothing = depsgraph == "nothing"
        return Plan()


class FakeWorker:
    def __init__(self):
        self.closed = 0
        self.dropped = []

    def close(self, timeout=None):
        self.closed += 1

    def drop_view(self, view):
        self.dropped.append(view)


def test_shared_viewport_applies_updates_of_two_engines_once():
    shared = SharedViewport(FakeWorker(), FakeSync())
    for key, dg in (((1, "sig"), "move"), ((2, "sig"), "move again"), ((3, "x"), "nothing")):
        plans = [shared.update(engine, key, dg) for engine in ("A", "B")]
        assert plans[0] is not None and plans[1] is None
    assert shared.sync.applied == ["move", "move again", "nothing"]
    assert shared.generation == 2  # "nothing" changed nothing


def test_registry_shares_and_releases_with_the_last_user(base):
    reg = SharedRegistry()
    made = []

    def make():
        made.append(SharedViewport(FakeWorker(), FakeSync()))
        return made[-1]

    a = reg.acquire("A", ("scene", None), make)
    b = reg.acquire("B", ("scene", None), make)
    assert a is b and len(made) == 1 and reg.users("A") == {"A", "B"}
    local = reg.acquire("B", ("scene", frozenset({"Cube"})), make)  # B enters a local view
    assert local is not a and len(made) == 2 and reg.users("A") == {"A"} and a.worker.dropped == ["B"]
    assert reg.release("A")  # a's last user
    assert a.worker.closed == 1 and local.worker.closed == 0 and len(reg) == 1
    assert reg.release("B") and local.worker.closed == 1 and len(reg) == 0
    assert not reg.release("B")  # twice: nothing


def test_snapshot_is_not_reached_by_later_edits(base):
    scene = copy.deepcopy(base)
    snap = snapshot(scene)
    before, old0 = snap.instances.matrices.copy(), scene.models[0]
    moved(scene)
    scene.lights = scene.lights[:1]
    scene.models[0] = copy.deepcopy(old0)
    np.testing.assert_array_equal(snap.instances.matrices, before)
    assert not np.array_equal(scene.instances.matrices, before)
    with pytest.raises(ValueError):  # an edit in place of shared matrices cannot reach the worker
        snapshot(scene).instances.set_matrices([0], np.eye(4)[None])
    again = snapshot(scene)
    with pytest.raises(ValueError):
        scene.instances.set_matrices([0], np.eye(4)[None])
    assert np.shares_memory(again.instances.matrices, scene.instances.matrices)  # shared: no copy
    assert len(snap.lights) == len(base.lights) > 1 and snap.models[0] is old0
    assert all(a is b for a, b in zip(snap.models[1:], scene.models[1:]))  # shared (GPU buffers stay cached)


EXIT_SCRIPT = """
import sys, threading, time
from hybrid_shadow_addon.core.runtime import worker
if {blocked!r}:
    w = worker.RenderWorker(create=lambda: time.sleep(3600))  # stuck in its first command
else:
    w = worker.RenderWorker()
    w.reset_history()  # makes the context in the thread
    assert w.wait_idle(60) and w._pipe is not None
w.reset_history()
print("exiting", w.thread_alive, flush=True)
"""


@pytest.mark.parametrize("blocked", [False, True])
def test_exit_does_not_hang_with_a_live_worker(blocked):
    """Never closed: the interpreter exits anyway (daemon thread; ``atexit`` closes the workers,
    waiting 2 s at most for one stuck in a command)."""
    import subprocess
    import sys
    from pathlib import Path

    repo = str(Path(__file__).resolve().parents[1])
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", EXIT_SCRIPT.format(blocked=blocked)], cwd=repo,
                          capture_output=True, text=True, timeout=120)
    dt = time.perf_counter() - t0
    assert proc.returncode == 0 and "exiting True" in proc.stdout, proc.stderr[-2000:]
    assert dt < 30, dt
