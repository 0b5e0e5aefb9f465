"""The two trace paths (``Settings.trace_path``): the compute path's queues give the fragment
path's masks bit for bit, in every mode of the hard side on the built-in scenes and in the modes
that trace differently on the stiff ones; the choice of path, its stats and its final-render
slices."""
import dataclasses

import numpy as np
import pytest

from hybrid_shadow_addon.core.errors import GPUError
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

W, H = 96, 64
#: (light grids only where a mode builds them at first sight: one built in the background
#: between the two paths' frames would change which structure the second one walks)
HARD = Settings(hard=True, light_grid=False)
#: mode -> (settings, frames rendered, eager light grids); the last frame's masks are compared
MODES = {
    "high": (HARD, 1, False),
    "medium": (HARD.replace(quality="medium"), 1, False),
    "low": (HARD.replace(quality="low"), 1, False),
    "interlace": (HARD.replace(interlace=True), 3, False),
    "light_grids": (HARD.replace(light_grid=True), 1, True),
    "conservative": (HARD.replace(conservative="all"), 1, False),
    "max_distance": (HARD.replace(max_distance=6.0), 1, False),
    "soft_low": (Settings(quality="low", samples=8, light_grid=False), 1, False),
}
SCENES = ["cube_on_plane", "forest", "clusters", "city", "scaling", "alpha_cards", "linking", "smooth_shapes",
          "soft_lights"] + [
    f"stiff/{n}" for n in ("axis_aligned", "cards", "clip_range", "crowd", "degenerate", "far_away", "grazing",
                           "instance_scales", "ortho", "point_in_box", "spot_touching", "stadium", "thin")]
#: the stiff scenes (a few objects each, hard to trace exactly) in the modes that trace differently
STIFF_MODES = ("high", "medium", "interlace", "light_grids")


def differing(a, b) -> int:
    """Pixels whose masks differ (NaN, no geometry, equal to NaN)."""
    return int((~((a == b) | (np.isnan(a) & np.isnan(b)))).sum())


@pytest.fixture(scope="module")
def paths(gl_ctx):
    """Two pipelines on one bake: ``{"compute": ..., "fragment": ...}``."""
    base = Pipeline(gl_ctx)
    other = base.view()
    yield {"compute": base, "fragment": other}
    other.release()
    base.release()


def render_mode(pipe, scene, mode, path):
    settings, frames, eager = MODES[mode]
    rt = pipe.shadow_pass("raytrace")
    rt.options = dataclasses.replace(rt.options, eager_light_grids=eager)
    pipe.reset_history()
    for _ in range(frames):
        frame = pipe.render(scene, settings.replace(trace_path=path), W, H)
    return frame


@pytest.mark.parametrize("name", SCENES)
def test_compute_masks_equal_fragment_masks(name, paths, loaded):
    scene = loaded(name)
    paths["compute"].set_scene(scene)
    for mode in STIFF_MODES if name.startswith("stiff/") else MODES:
        got = {path: render_mode(pipe, scene, mode, path) for path, pipe in paths.items()}
        assert got["compute"].stats["trace_path"] == "compute"
        assert got["fragment"].stats["trace_path"] == "fragment"
        assert got["compute"].lights == got["fragment"].lights
        for li in got["compute"].lights:
            d = differing(got["compute"].mask_array(li), got["fragment"].mask_array(li))
            assert d == 0, f"{name} {mode}: light {scene.lights[li].name}: {d} pixels differ"


def moved(scene, k):
    cam = scene.camera
    m = np.array(cam.matrix, np.float64)
    m[:3, 3] += np.array([0.03, -0.02, 0.01]) * k * max(1.0, float(np.abs(m[:3, 3]).max()) * 0.01)
    return dataclasses.replace(scene, camera=dataclasses.replace(cam, matrix=m))


@pytest.mark.parametrize("name", ["forest", "clusters", "smooth_shapes"])
def test_reused_masks_equal_across_paths(name, paths, loaded):
    """Reuse along a short camera move: the retraced pixels queued and traced on the compute
    path give the fragment path's reused masks."""
    scene = loaded(name)
    paths["compute"].set_scene(scene)
    for pipe in paths.values():
        pipe.reuse, pipe.reuse_choice = True, "always"
    try:
        for k in range(3):
            s = moved(scene, k)
            got = {path: pipe.render(s, HARD.replace(trace_path=path), W, H) for path, pipe in paths.items()}
        # (more reused on the compute path: the lights the fragment path culls reuse there too)
        assert got["compute"].stats["pixels_reused"] >= got["fragment"].stats["pixels_reused"] > 0
        assert got["compute"].stats["rays_traced"] <= got["fragment"].stats["rays_traced"]
        for li in got["compute"].lights:
            assert differing(got["compute"].mask_array(li), got["fragment"].mask_array(li)) == 0
    finally:
        for pipe in paths.values():
            pipe.reuse = False


def test_compute_frame_counts(paths, loaded):
    """``trace_path`` and the host counts in a frame's stats: the compute path dispatches two
    kernels a light and reads back less (no light culling of hard lights); the fragment path
    dispatches nothing."""
    scene = loaded("clusters")
    paths["compute"].set_scene(scene)
    got = {path: render_mode(pipe, scene, "high", path) for path, pipe in paths.items()}
    c, f = got["compute"].stats, got["fragment"].stats
    traced = len(got["fragment"].lights) - f["lights_culled"]
    assert traced > 0 and c["lights_culled"] == 0  # (a hard light's empty queue costs no read-back)
    assert c["dispatches"] == 2 * len(got["compute"].lights) and f["dispatches"] == 0
    assert c["bytes_read_back"] < f["bytes_read_back"]
    for s in (c, f):
        assert s["waits"] >= 1 and s["bytes_read_back"] >= W * H * 4 * 4  # (at least the image)


def test_compute_counts_its_rays(paths, loaded):
    """The compute path counts the pixels its refinement queued (the queues' tallies), the
    fragment path those its depth test let through: the same pixels. Its coarse and full
    traces count the texels queued, the rays: fewer than the fragment path's pixels shaded
    (those known without a ray are shaded too)."""
    scene = loaded("forest")
    paths["compute"].set_scene(scene)
    for mode in ("medium", "high"):
        got = {path: render_mode(pipe, scene, mode, path) for path, pipe in paths.items()}
        counts = {path: pipe.shadow_pass("raytrace").refiner.count("refined") for path, pipe in paths.items()}
        assert counts["compute"] == counts["fragment"] and (counts["compute"] > 0) == (mode == "medium")
        assert 0 < got["compute"].stats["rays_traced"] < got["fragment"].stats["rays_traced"]


def test_budget_slices_give_the_whole_mask(paths, loaded):
    """A final render's budget splits the compute trace into slices of the queue, each
    finished before the next: the masks are those of one dispatch."""
    scene = loaded("forest")
    pipe = paths["compute"]
    pipe.set_scene(scene)
    frame = pipe.render(scene, HARD.replace(trace_path="compute"), 160, 120)
    whole = {li: frame.mask_array(li) for li in frame.lights}  # (read now: the next frame reuses the targets)
    budget = pipe.gpu.budget
    budget.reset_stats()
    sliced = pipe.render(scene, HARD.replace(trace_path="compute"), 160, 120, max_draw_ms=0.5)
    assert budget.tiles > 2 * len(sliced.lights)
    for li, mask in whole.items():
        assert differing(mask, sliced.mask_array(li)) == 0


def test_trace_path_choice(paths):
    """``auto`` takes compute where a GPU offers GL 4.3, fragment on a software rasteriser and
    where the context has no GL 4.3 (as on macOS' GL 4.1); ``compute`` there is one clear
    error."""
    rt = paths["compute"].shadow_pass("raytrace")
    assert rt._software  # (llvmpipe)
    assert rt.trace_path(HARD) == "fragment"
    assert rt.trace_path(HARD.replace(trace_path="compute")) == "compute"
    assert rt.trace_path(HARD.replace(trace_path="fragment")) == "fragment"
    rt._software = False  # (a GPU's)
    try:
        assert rt.trace_path(HARD) == "compute"
    finally:
        rt._software = True
    queue = rt.queue
    rt.queue = None  # (what a GL 4.1 context leaves: no queue)
    try:
        assert rt.trace_path(HARD) == "fragment"
        with pytest.raises(GPUError, match="needs OpenGL 4.3"):
            rt.trace_path(HARD.replace(trace_path="compute"))
    finally:
        rt.queue = queue
    with pytest.raises(ValueError, match="trace_path must be one of"):
        HARD.replace(trace_path="cuda")


#: soft modes: (settings, frames); the last frame's masks are compared
SOFT_MODES = {
    "final": (Settings(samples=24, noise_target=0.0, light_grid=False), 1),
    "noise_check": (Settings(samples=24, light_grid=False), 1),
    "accumulate": (Settings(samples=32, accumulate=True, light_grid=False), 3),
}


def soft_frames(paths, scene, mode, lanes):
    settings, frames = SOFT_MODES[mode]
    rt = paths["compute"].shadow_pass("raytrace")
    rt.options = dataclasses.replace(rt.options, soft_lanes=lanes)
    try:
        out = {}
        for path, pipe in paths.items():
            pipe.reset_history()
            for _ in range(frames):
                out[path] = pipe.render(scene, settings.replace(trace_path=path), W, H)
        return out
    finally:
        rt.options = dataclasses.replace(rt.options, soft_lanes=None)


@pytest.mark.parametrize("name", ["soft_lights", "forest", "alpha_cards", "smooth_shapes", "linking"])
def test_soft_masks_across_paths(name, paths, loaded):
    """Soft lights on the compute path: probes, penumbra samples, the noise check's second
    round and the viewport's accumulation, queued. Walking as packets (a software rasteriser's
    default), a final frame with the noise check gives the fragment path's masks bit for bit
    (both add the penumbra's sums to the probes'); where the fragment stage traces a pixel's
    samples in one draw it continues from the probes' sums, the compute path adds to them, so
    the masks differ by rounding. Spread over lanes (a GPU's default), each lane sums its own samples and the
    texel's first lane adds the lanes up: the same rays, summed in another order (through
    alpha-cut casters each ray's transmittance too), so they differ by rounding; the noise
    check's estimate from those sums moves in its fourth digit, which the filter of its second
    round carries a little further."""
    scene = loaded(name)
    paths["compute"].set_scene(scene)
    for lanes in (False, True):
        for mode in SOFT_MODES:
            got = soft_frames(paths, scene, mode, lanes)
            c, f = got["compute"], got["fragment"]
            assert c.stats["trace_path"] == "compute" and c.stats["dispatches"] > 0, mode
            assert ("HS_QUEUE_LANES" in " ".join(c.stats["defines"])) == lanes
            for li in c.lights:
                a, b = c.mask_array(li), f.mask_array(li)
                d = np.abs(np.nan_to_num(a) - np.nan_to_num(b))
                what = f"{name} {mode} lanes={lanes}: light {scene.lights[li].name}"
                if not lanes and mode == "noise_check":
                    assert differing(a, b) == 0, f"{what}: {differing(a, b)} pixels differ"
                elif mode == "noise_check":
                    assert d.mean() < 1e-5 and d.max() < 0.05, f"{what}: off by {d.max()} (mean {d.mean()})"
                else:
                    assert d.max() < 5e-5, f"{what}: off by {d.max()}"


def test_soft_budget_slices_give_the_whole_mask(paths, loaded):
    """A final render's budget slices the soft lights' queues too, lanes and packets: the masks
    are those of whole dispatches."""
    scene = loaded("soft_lights")
    pipe = paths["compute"]
    pipe.set_scene(scene)
    rt = pipe.shadow_pass("raytrace")
    settings = Settings(samples=24, light_grid=False, trace_path="compute")
    try:
        for lanes in (True, False):
            rt.options = dataclasses.replace(rt.options, soft_lanes=lanes)
            frame = pipe.render(scene, settings, 160, 120)
            whole = {li: frame.mask_array(li) for li in frame.lights}  # (before the next frame reuses the targets)
            budget = pipe.gpu.budget
            budget.reset_stats()
            sliced = pipe.render(scene, settings, 160, 120, max_draw_ms=0.5)
            assert budget.tiles > 2 * len(sliced.lights)
            for li, mask in whole.items():
                assert differing(mask, sliced.mask_array(li)) == 0, (lanes, scene.lights[li].name)
    finally:
        rt.options = dataclasses.replace(rt.options, soft_lanes=None)
