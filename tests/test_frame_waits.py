"""What a viewport frame asks of the host (``Pipeline.timing`` ``"frame"``): no wait between
passes, the image its one read-back, the GPU's ray counts left unread, and the spans the reuse
and light-grid choices are timed by read a frame later (``GpuClock``), where timer queries
measure the device's work; the same masks and images as a frame timed pass by pass."""
import dataclasses

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.clock import GpuClock
from hybrid_shadow_addon.core.gpu.context import software_renderer
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

W, H = 96, 64
IMAGE_BYTES = W * H * 4 * 4  # (the RGBA32F image)


@pytest.fixture(scope="module")
def pipes(gl_ctx):
    """Two views of one bake: ``{"passes": ..., "frame": ...}`` (their ``timing``)."""
    base = Pipeline(gl_ctx)
    other = base.view()
    other.timing = "frame"
    yield {"passes": base, "frame": other}
    other.release()
    base.release()


def _turned(scene, dx):
    cam = dataclasses.replace(scene.camera, matrix=scene.camera.matrix.copy())
    cam.matrix[:3, 3] += (dx, 0.0, 0.0)
    return dataclasses.replace(scene, camera=cam)


@pytest.fixture()
def deferring(pipes):
    """The context's clock as on a GPU (timer queries trusted), restored afterwards. llvmpipe's
    answers are not its work's time, which changes only which way a light's reuse takes."""
    clock = pipes["passes"].gpu.clock
    saved = clock.queries
    clock.queries = True
    yield clock
    clock.queries = saved


@pytest.mark.parametrize("path", ["compute", "fragment"])
def test_a_viewport_frame_waits_once_for_its_image(pipes, loaded, deferring, path):
    """Along a camera move, with reuse (its ways timed by the clock) and without, and light
    grids (timed too), each frame after the first waits once, reads back its image and the
    timer results (8 bytes each), and leaves the counts unread. Without reuse its masks and
    image are those of frames timed pass by pass (with it, the ways chosen from the times may
    differ). Lights are not culled on the host, as on a GPU (``RaytraceOptions.cull_lights``)."""
    scene = loaded("forest" if path == "compute" else "clusters")
    pipes["passes"].set_scene(scene)
    settings = Settings(hard=True, trace_path=path)
    for reuse in (True, False):
        frames = {}
        for timing, pipe in pipes.items():
            rp = pipe.shadow_pass("raytrace")
            rp.options = dataclasses.replace(rp.options, cull_lights=False)  # (a GPU's default)
            pipe.reuse = reuse
            pipe.reset_history()
            try:
                frames[timing] = []
                for i in range(4):
                    f = pipe.render(_turned(scene, 0.01 * i), settings, W, H)
                    # (the masks read now: the next frame draws into the same targets)
                    frames[timing].append((f, {li: f.mask_array(li) for li in f.lights}))
            finally:
                pipe.reuse = False
                rp.options = dataclasses.replace(rp.options, cull_lights=None)
        masks = {k: [m for _, m in v] for k, v in frames.items()}
        frames = {k: [f for f, _ in v] for k, v in frames.items()}
        for f in frames["frame"][1:]:
            s = f.stats
            assert s["waits"] == 1, s
            assert IMAGE_BYTES <= s["bytes_read_back"] <= IMAGE_BYTES + 8 * 64
            assert s["rays_traced"] is None and s["pixels"] is None and s["pixels_reused"] is None
            assert list(f.timings) == ["total_ms"] and f.timings["total_ms"] > 0
        assert any(f.stats["bytes_read_back"] > IMAGE_BYTES for f in frames["frame"])  # (timers were read)
        for f in frames["passes"]:
            assert f.stats["waits"] > 1 and f.stats["rays_traced"] is not None and "shadow_ms" in f.timings
        if reuse:
            assert any(f.stats["reuse_ways"]["reused"] for f in frames["frame"])
            continue
        for a, b, ma, mb in zip(frames["passes"], frames["frame"], masks["passes"], masks["frame"]):
            assert a.lights == b.lights
            np.testing.assert_array_equal(a.image, b.image)
            for li in a.lights:
                np.testing.assert_array_equal(ma[li], mb[li])


def test_a_bad_timing_is_one_clear_error(pipes, loaded):
    pipe = pipes["frame"]
    pipe.timing = "sometimes"
    try:
        with pytest.raises(ValueError, match="timing must be one of"):
            pipe.render(loaded("cube_on_plane"), Settings(), W, H)
    finally:
        pipe.timing = "frame"


def test_clock_spans_at_once_or_a_frame_later(gl_ctx):
    """On the host the callback has the span's time at once (two waits); deferred, the next
    :meth:`collect` hands each span its time, inner spans first, an outer span's time holding
    its inner ones'."""
    clock = GpuClock(gl_ctx)
    assert clock.queries == (not software_renderer(gl_ctx.info["GL_RENDERER"]))
    got = []
    with clock.span(lambda ms: got.append(("host", ms))):
        gl_ctx.finish()
    assert len(got) == 1 and got[0][1] >= 0.0
    clock.queries, clock.deferred = True, True
    try:
        with clock.span(lambda ms: got.append(("outer", ms))):
            with clock.span(lambda ms: got.append(("inner", ms))):
                pass
            with clock.span(lambda ms: got.append(("second", ms))):
                pass
        assert len(got) == 1  # (nothing yet: read at the next collect)
        clock.collect()
        assert [k for k, _ in got[1:]] == ["inner", "second", "outer"]
        times = dict(got[1:])
        assert times["outer"] >= times["inner"] + times["second"] - 1e-9
        clock.collect()
        assert len(got) == 4
    finally:
        clock.release()


def test_lights_culled_on_the_host_on_a_software_rasteriser_only(pipes, loaded):
    """By default the light culling's read-back runs where it saves whole passes, a software
    rasteriser; on a GPU each pixel's reach test leaves such a light."""
    scene = loaded("clusters")  # (spots: cull candidates)
    pipe = pipes["frame"]  # (its one read-back is the image, but for the culling's)
    pipe.set_scene(scene)
    assert pipe.shadow_pass("raytrace").options.cull_lights is None
    f = pipe.render(scene, Settings(hard=True, trace_path="fragment"), W, H)
    assert (f.stats["bytes_read_back"] > IMAGE_BYTES) == software_renderer(pipe.ctx.info["GL_RENDERER"])


def test_big_models_drawn_by_chunks_on_a_software_rasteriser_only(pipes):
    """The G-buffer's chunks of big models are a software rasteriser's (CPU vertex work); a
    GPU draws a model whole."""
    gp = pipes["passes"].gbuffer_pass
    assert gp.chunked == software_renderer(gp.ctx.info["GL_RENDERER"])
