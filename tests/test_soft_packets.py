"""Soft-shadow packets (``shaders/common/scene_packet.glsl``): a pixel's rays towards an extended
light walk the two-level BVH together, bounded by a cone, and each leaf triangle is tested
against every ray of the packet with shared-origin edge planes. Every ray must get the answer it
gets traced alone (``hs_occluded``), so the masks equal the ray-by-ray masks (without their early
stop, which packets do not take) but for rays that graze an edge or the receiver within float32
error.

Scenes: the soft-light test scene and stiff scenes whose lights are made extended here
(non-uniformly scaled and sheared instances, 100 km from the origin, sub-pixel casters,
coincident faces, analytic spheres), so the cone is carried into odd model spaces as well, and
alpha-cut casters (a packet's rays keep a transmittance each).
"""
from dataclasses import replace

import numpy as np
import pytest

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu, pytest.mark.slow]

W, H = 160, 120


def extended(scene, area: bool = False):
    """``scene`` with every light given a size: a 3° sun, 0.25 m point/spot radii, 1 m area
    lights; with ``area``, point lights become tilted 2 x 0.7 m rectangle area lights (the
    packets of rectangle and ellipse lights are bounded by the pyramid over the light as well,
    whose planes are carried into each instance's model space)."""
    for light in scene.lights:
        if light.type == "SUN":
            light.angle = np.radians(3.0)
        elif light.type == "POINT" and area:
            from tests.helpers.scenes import trs
            m = trs(light.position, rot_z=0.5, rot_x=0.45)
            light.type, light.area_shape, light.size, light.size_y, light.matrix = "AREA", "RECTANGLE", 2.0, 0.7, m
        elif light.type in ("POINT", "SPOT"):
            light.radius = 0.25
        else:
            light.size = light.size_y = 1.0
    return scene


def masks(pipe, scene, packets: bool, samples: int = 32):
    rt = pipe.shadow_pass("raytrace")
    kept = rt.options
    # (a packet traces all of a refined pixel's samples: so does the reference)
    rt.options = replace(kept, packets=packets, early_stop=packets)
    pipe.set_scene(scene, "bvh")
    pipe.reset_history()
    try:
        # (noise_target 1: the packets take the noise check's path, keeping their first half's sums
        # apart, and no light doubles its samples, so both paths trace the same rays)
        f = pipe.render(scene, Settings(mode="raytrace", quality="high", samples=samples, noise_target=1.0), W, H)
    finally:
        rt.options = replace(kept, packets=True, early_stop=True)
    return f, [f.mask_array(i) for i in range(len(scene.lights))]


def agree(a, b, share: float = 0.999) -> list:
    """Packet masks ``a`` against ray-by-ray masks ``b``: the same covered pixels, equal within
    float32 error on more than ``share`` of them (the reference adds its samples' sums in draws of
    at most CHUNK_RAYS: another order of the float additions than one packet's), and about
    equal on average. Returns each light's count of partly lit pixels of ``b``."""
    partial = []
    for li, (x, y) in enumerate(zip(a, b)):
        fin = np.isfinite(y)
        np.testing.assert_array_equal(np.isfinite(x), fin)
        d = np.abs(x - y)[fin]
        assert (d <= 1e-5).mean() > share, f"light {li}: {(d > 1e-5).sum()} pixels differ"
        assert d.mean() < 1e-4, f"light {li}: mean difference {d.mean():.2e}"
        partial.append(int(((y > 0.02) & (y < 0.98)).sum()))
    return partial


@pytest.fixture(scope="module")
def pipe(gl_ctx):
    p = Pipeline(gl_ctx)
    yield p
    p.release()


@pytest.mark.parametrize("spec, samples", [("soft_lights", 32), ("soft_lights", 64), ("stiff/instance_scales", 32),
                                           ("stiff/instance_scales:area", 32), ("stiff/far_away", 32),
                                           ("stiff/far_away:area", 32), ("stiff/thin", 32), ("stiff/degenerate", 32)])
def test_packets_give_each_ray_its_own_answer(pipe, spec, samples):
    """(64 samples: a packet of 60 rays, both halves of its 64-bit masks; ``:area``: the point
    lights become rectangle area lights, over mirrored, squashed and rotated instances: carrying
    the pyramid's planes into model space with L instead of L^-T makes 76 pixels differ there)"""
    from hybrid_shadow_addon.blender.load import load_scene

    spec, _, area = spec.partition(":")
    scene = load_scene(spec)
    if not spec.startswith("soft"):
        scene = extended(scene, area=bool(area))
    f1, a = masks(pipe, scene, packets=True, samples=samples)
    f0, b = masks(pipe, scene, packets=False, samples=samples)
    assert "HS_SOFT_PACKET=1" in f1.stats["defines"] and "HS_SOFT_PACKET=1" not in f0.stats["defines"]
    assert sum(agree(a, b)) > 200, "the scene should show penumbrae"


def test_packets_through_analytic_spheres(pipe):
    from tests.helpers.scenes import LIGHTS, basic_scene, soft_scene

    scene = basic_scene(lights=soft_scene(LIGHTS).lights, with_sphere=True)
    f1, a = masks(pipe, scene, packets=True)
    f0, b = masks(pipe, scene, packets=False)
    assert "HS_HAS_SPHERES=1" in f1.stats["defines"] and "HS_SOFT_PACKET=1" in f1.stats["defines"]
    # (the reference's 31 rays after the probe take two draws of at most CHUNK_RAYS)
    assert sum(agree(a, b)) > 200


@pytest.mark.parametrize("spec", ["alpha_scene", "alpha_cards"])
def test_packets_through_alpha_cut_casters(pipe, spec):
    """A packet's ray that hits an alpha-cut triangle keeps the transmittance at its UV (the
    barycentrics from the edge products) and goes on, blocked only below HS_VIS_MIN, as the ray
    traced alone: the masks equal the ray-by-ray ones. The test scene's cards (6° sun) and
    ``alpha_cards`` with its lights made extended; with its own loop-budget check."""
    from hybrid_shadow_addon.blender.load import load_scene
    from tests.helpers.scenes import alpha_scene

    if spec == "alpha_scene":
        scene = alpha_scene(lights=("sun",))
        scene.lights[0].angle = np.radians(6.0)
    else:
        scene = extended(load_scene(spec))
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, loop_check=True)
    try:
        f1, a = masks(pipe, scene, packets=True, samples=64)
    finally:
        rt.options = replace(rt.options, loop_check=False)
    f0, b = masks(pipe, scene, packets=False, samples=64)
    assert "HS_HAS_ALPHA=1" in f1.stats["defines"] and "HS_SOFT_PACKET=1" in f1.stats["defines"]
    assert "HS_SOFT_PACKET=1" not in f0.stats["defines"]
    for li, x in enumerate(a):
        assert not (np.nan_to_num(x) < -0.5).any(), f"light {li}: pixels spent the loop budget"
    assert sum(agree(a, b)) > 300, "the cards should cast partial shadows"


@pytest.mark.parametrize("packets, samples", [(True, 64), (True, 256), (False, 64), (False, 128)])
def test_no_pixel_spends_llvmpipe_loop_budget(pipe, packets, samples):
    """llvmpipe stops every loop of a shader invocation once all its loops together have run
    65535 iterations: a pixel whose rays spend that budget keeps the rays it traced so far and
    looks plausible. On ``forest`` (a million triangles, palms over hills under a dawn sun) 64
    rays one by one spent it on 1 in 7 of the sun's penumbra pixels, and so did 64-ray packets
    while each triangle looped over its rays one at a time. The refinement now traces at most
    CHUNK_RAYS rays per draw; HS_LOOP_CHECK marks a spent pixel (a loop over u_samples that
    ends early) with a negative mask."""
    from hybrid_shadow_addon.blender.load import load_scene

    rt = pipe.shadow_pass("raytrace")
    scene = load_scene("forest")
    rt.options = replace(rt.options, loop_check=True)
    try:
        f, ms = masks(pipe, scene, packets=packets, samples=samples)
    finally:
        rt.options = replace(rt.options, loop_check=False)
    assert ("HS_SOFT_PACKET=1" in f.stats["defines"]) == packets
    for li, m in enumerate(ms):
        assert not (np.nan_to_num(m) < -0.5).any(), \
            f"light {li}: {(np.nan_to_num(m) < -0.5).sum()} pixels spent the budget"
    assert ((ms[0] > 0.02) & (ms[0] < 0.98)).sum() > 300, "the sun should show penumbrae"


def pegs_scene():
    """A board of 10 x 10 small cubes (one model, a tree several levels deep) placed twice with
    strongly non-uniform, sheared and mirrored transforms over a ground plane, under a tilted
    1.2 x 0.4 m rectangle area light and a 1 x 0.5 m ellipse light, whose packets are bounded by
    the planes of the pyramid over the light, carried into each instance's model space."""
    from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Model, Scene
    from tests.helpers.scenes import cube_model, look_at, plane_model, trs

    cube = cube_model()
    vs, ts = [], []
    for i in range(10):
        for j in range(10):
            ts.append(cube.triangles + len(vs) * 8)
            vs.append(cube.vertices * np.float32(0.03)
                      + np.array([-0.65 + 0.13 * i, -0.65 + 0.13 * j, 0.0], np.float32))
    pegs = Model("pegs", np.concatenate(vs), np.concatenate(ts).astype(np.uint32))
    shear = np.eye(4)
    shear[0, 1], shear[2, 0] = 0.6, 0.3
    mats = [trs((0, 0, 0), scale=(6, 6, 1)),
            trs((0.3, -0.2, 1.0), rot_z=0.7, rot_x=0.2, scale=(1.6, 0.7, 2.5)) @ shear,
            trs((-1.3, 1.2, 0.7), rot_z=-0.4, rot_x=-0.3, scale=(-1.2, 0.8, 2.0)) @ shear.T]
    inst = Instances(names=["ground", "pegs", "mirrored"], model_ids=[0, 1, 1], matrices=np.array(mats),
                     base_color=[(0.8, 0.8, 0.8, 1)] * 3, specular=[0.5] * 3, roughness=[0.5] * 3,
                     sphere=[False] * 3)
    rect = trs((0.2, 0.0, 2.6), rot_z=0.5, rot_x=0.3)
    ell = trs((-1.0, 0.8, 2.4), rot_z=-0.3, rot_x=-0.3)
    lights = [Light("rect", "AREA", power=500.0, matrix=rect, size=1.2, size_y=0.4, area_shape="RECTANGLE"),
              Light("ellipse", "AREA", power=500.0, matrix=ell, size=1.0, size_y=0.5, area_shape="ELLIPSE")]
    cam = Camera(matrix=look_at((1.0, -2.5, 6.0), (-0.4, 0.3, 0.0)), type="PERSP", lens=30.0)
    return Scene(models=[plane_model(), pegs], instances=inst, lights=lights, camera=cam,
                 world_color=(0.05, 0.06, 0.08), resolution=(W, H))


def test_packet_pyramid_planes_in_odd_model_spaces(pipe):
    """Rectangle and elongated ellipse lights bound a packet by the four planes of the pyramid
    over the light as well as by its cone; under sheared, squashed and mirrored instances the masks equal the
    ray-by-ray ones (one plane turned the wrong way: 846 of the rectangle light's pixels differ)."""
    scene = pegs_scene()
    f1, a = masks(pipe, scene, packets=True)
    f0, b = masks(pipe, scene, packets=False)
    assert "HS_SOFT_PACKET=1" in f1.stats["defines"] and "HS_PACKET_PLANES=1" in f1.stats["defines"]
    # (a ray that grazes a peg's edge within float32 error may answer otherwise, and the
    # penumbra filter spreads that pixel over its 3x3 neighbours: 27 of the ellipse light's
    # pixels, three such rays, with or without the planes)
    assert min(agree(a, b, share=0.998)) > 1000, "the pegs should cast penumbrae"


def test_pyramid_bounds_only_where_the_cone_is_loose():
    """Rectangles and ellipses at least 1.5 times as long as wide take the pyramid's planes; a
    disk, whose cone already fits it, a sun and a sphere light do not."""
    from hybrid_shadow_addon.core.gpu.lights import soft_shape
    from hybrid_shadow_addon.core.gpu.passes.trace import pyramid_bounds
    from hybrid_shadow_addon.core.scene import Light

    def area(shape, sx, sy):
        return soft_shape(Light("a", "AREA", size=sx, size_y=sy, area_shape=shape))

    assert pyramid_bounds(area("RECTANGLE", 2.0, 1.9)) and pyramid_bounds(area("SQUARE", 1.0, 0.0))
    assert pyramid_bounds(area("ELLIPSE", 2.0, 1.0)) and not pyramid_bounds(area("ELLIPSE", 2.0, 1.5))
    assert not pyramid_bounds(area("DISK", 1.0, 0.0))
    assert not pyramid_bounds(soft_shape(Light("s", "SUN", angle=0.1)))
    assert not pyramid_bounds(soft_shape(Light("p", "POINT", radius=0.3)))


def test_chunk_draws_end_on_aligned_blocks():
    """A refinement of more rays than one draw takes (CHUNK_RAYS) is cut where the sequence
    reaches a multiple of 64, as the shader cuts its packets: 128 samples after the probe take
    draws of 63 and 64 (not 64 and 63, whose first would walk the scene twice)."""
    from hybrid_shadow_addon.core.gpu.passes.soft import CHUNK_RAYS, SOFT_PROBES, chunk_spans

    step = CHUNK_RAYS["packets"]
    assert step == 64 and SOFT_PROBES == 1
    assert chunk_spans(0, SOFT_PROBES, 128, step) == [(1, 63), (64, 64)]
    assert chunk_spans(0, 2, 256, step) == [(2, 62), (64, 64), (128, 64), (192, 64)]
    assert chunk_spans(16, 0, 4, step) == [(0, 4)]                 # a viewport frame
    assert chunk_spans(60, 0, 8, step) == [(0, 4), (4, 4)]         # one across a border
    assert chunk_spans(0, 2, 100, step) == [(2, 62), (64, 36)]
    spans = chunk_spans(5, 3, 200, 28)                             # ray by ray
    assert sum(n for _, n in spans) == 197 and all(n <= 28 for _, n in spans)
    assert all((5 + s + n) % 28 == 0 for s, n in spans[:-1])


def test_rays_cut_short_by_the_loop_budget_are_dropped(pipe, monkeypatch, samples=700):
    """Draws of more rays than llvmpipe's loop budget lets a pixel trace (``CHUNK_RAYS`` raised
    to 512, ray by ray on ``forest``: thousands of refined pixels spend it, as ``HS_LOOP_CHECK``
    shows). Without the guard, the ray whose walk the budget cut counts as lit: the penumbrae
    come out too lit (a mean bias) against the masks of draws within the budget. With it
    (``RaytraceOptions.loop_guard``, on by default on a software rasteriser) that ray is dropped
    and the pixel's share comes from the rays it traced in full (700 samples: two draws; one of
    512 measured the same, BENCHMARKS.md)."""
    from hybrid_shadow_addon.blender.load import load_scene
    from hybrid_shadow_addon.core.gpu.passes import soft

    scene = load_scene("forest")
    rt = pipe.shadow_pass("raytrace")
    assert rt.options.loop_guard is None
    _, ref = masks(pipe, scene, packets=False, samples=samples)
    sun = ref[0]
    pen = np.isfinite(sun) & (sun > 0.02) & (sun < 0.98)
    monkeypatch.setattr(soft, "CHUNK_RAYS", {"rays": 512, "packets": 512})
    out = {}
    try:
        for name, opts in (("check", dict(loop_check=True)), ("off", dict(loop_guard=False)),
                           ("guard", dict(loop_guard=True))):
            rt.options = replace(rt.options, **opts)
            out[name] = masks(pipe, scene, packets=False, samples=samples)[1][0]
            rt.options = replace(rt.options, loop_check=False, loop_guard=None)
    finally:
        rt.options = replace(rt.options, loop_check=False, loop_guard=None)
    assert (np.nan_to_num(out["check"]) < -0.5).sum() > 1000
    bias = {k: float(np.mean(out[k][pen] - sun[pen])) for k in ("off", "guard")}
    mae = {k: float(np.mean(np.abs(out[k][pen] - sun[pen]))) for k in ("off", "guard")}
    assert bias["off"] > 0.001 and abs(bias["guard"]) < bias["off"] / 4, bias
    assert mae["guard"] <= mae["off"], mae
