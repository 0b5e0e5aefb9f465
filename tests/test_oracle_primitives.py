"""The oracle's float32 primitives (``core/oracle/tracer/primitives.py``) against closed forms:
watertight triangles, the sphere test and its pre-test, the slab test, ray preparation."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.oracle.tracer.primitives import (
    SLAB_BIG,
    prepare_rays,
    ragged_pairs,
    slab_hit,
    slab_inv,
    sphere_hit,
    sphere_pretest,
    transform_rays,
    woop_hit,
    woop_hit_bary,
    woop_setup,
)
from tests.helpers.rays import random_triangle_rays

F = np.float32


def _hit(o, d, v, tmax, floor=False):
    """woop_hit of rays (N, 3) against one triangle ``v`` (3, 3) each, or per-ray triangles (N, 3, 3)."""
    o, d = np.asarray(o, F).reshape(-1, 3), np.asarray(d, F).reshape(-1, 3)
    v = np.broadcast_to(np.asarray(v, F), (len(o), 3, 3))
    tm = np.broadcast_to(np.asarray(tmax, F), (len(o),))
    return woop_hit(o, woop_setup(d), v[:, 0], v[:, 1], v[:, 2], tm, floor)


def _jittered_mesh(rng, n=12):
    """A tessellated square (n x n quads, two triangles each) with jittered interior vertices:
    every interior edge is shared by two triangles, as in a closed mesh."""
    g = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    jit = rng.uniform(-0.3, 0.3, (n + 1, n + 1, 2)) * (2.0 / n)
    jit[[0, -1], :, :] = 0
    jit[:, [0, -1], :] = 0
    verts = np.stack([x + jit[..., 0], y + jit[..., 1], rng.uniform(-0.01, 0.01, x.shape)], -1).astype(F)
    verts = verts.reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    i = i.reshape(-1)
    tris = np.concatenate([np.stack([i, i + n + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + 1], 1)])
    return verts, tris


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_watertight_on_shared_edges_and_vertices(seed):
    """Rays through points on shared edges and on shared vertices hit at least one of the
    triangles around them (no ray leaks through a closed surface), from oblique directions."""
    rng = np.random.default_rng(seed)
    verts, tris = _jittered_mesh(rng)
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e = np.sort(edges, axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    inner = uniq[count == 2]
    s = rng.uniform(0, 1, (len(inner), 1)).astype(F)
    on_edge = (verts[inner[:, 0]] * (1 - s) + verts[inner[:, 1]] * s).astype(F)
    boundary = np.unique(uniq[count == 1])
    on_vertex = verts[np.setdiff1d(np.unique(inner), boundary)]
    for targets in (on_edge, on_vertex):
        n = len(targets)
        d = rng.normal(size=(n, 3)) * 0.5
        d[:, 2] = -1.0  # towards the surface from above, never grazing it
        d = d.astype(F)
        o = (targets - 3.0 * d).astype(F)
        rays = np.repeat(np.arange(n), len(tris))
        tri = np.tile(np.arange(len(tris)), n)
        h = _hit(o[rays], d[rays], verts[tris[tri]], F(10.0)).reshape(n, len(tris))
        assert h.any(axis=1).all()


def test_triangle_t_range_and_both_sides():
    """Hit iff the plane's t lies in (0, tmax), from either side (double-sided)."""
    v = np.array([[-1, -1, 0], [2, -1, 0], [-1, 2, 0]], F)
    down = _hit([[0, 0, 2], [0, 0, 2], [0, 0, 2], [0, 0, -2]], [[0, 0, -1], [0, 0, -1], [0, 0, 1], [0, 0, 1]],
                v, [2.5, 1.5, 10.0, 2.5])
    assert down.tolist() == [True, False, False, True]
    # t in units of |d|: a direction twice as long reaches the plane at t = 1
    assert _hit([[0, 0, 2]], [[0, 0, -2]], v, 1.01).tolist() == [True]
    assert _hit([[0, 0, 2]], [[0, 0, -2]], v, 0.99).tolist() == [False]
    # beside the triangle (outside the hypotenuse): no hit at any t
    assert _hit([[0.8, 0.8, 2]], [[0, 0, -1]], v, 10.0).tolist() == [False]


def test_floor_skips_the_surface_itself():
    """With ``floor`` rays leaving a huge tilted triangle's surface (at least 15 degrees off it)
    never hit it, where without the floor the float32 error of t makes many of them hit; a hit
    farther away than that error is kept."""
    rng = np.random.default_rng(9)
    big = np.array([[-1e4, -1e4, -1e4], [3e4, -1e4, 3e4], [-1e4, 3e4, -1e4]], F)  # the plane z = x
    normal = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)
    d = rng.normal(size=(8000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[np.abs(d @ normal) > 0.26].astype(F)
    o = (rng.dirichlet([5, 5, 5], len(d)) @ big.astype(np.float64)).astype(F)
    assert not _hit(o, d, big, 10.0, floor=True).any()
    assert _hit(o, d, big, 10.0, floor=False).sum() > len(d) // 10
    o = np.array([[3.0, 5.0, 4.0], [3.0, 5.0, 4.0]], F)
    d = np.array([[0.0, 0.0, -1.0]] * 2, F)
    assert _hit(o, d, big, [10.0, 0.9], floor=True).tolist() == [True, False]


def test_triangle_against_float64():
    """Random rays and triangles, away from the edges, agree with float64 Moller-Trumbore."""
    rng = np.random.default_rng(3)
    v, o, d, tmax, ref, margin = random_triangle_rays(rng, 20000)
    clear = margin > 1e-3
    got = _hit(o, d, v, tmax)
    assert ref[clear].sum() > 100
    assert (got[clear] == ref[clear]).all()


def test_bary_reconstructs_the_hit_point():
    """``woop_hit_bary``: same hits as ``woop_hit``; the weights blend the corners into o + t d."""
    rng = np.random.default_rng(4)
    n = 5000
    v = rng.normal(size=(n, 3, 3)).astype(F)
    o = (rng.normal(size=(n, 3)) * 2).astype(F)
    d = rng.normal(size=(n, 3)).astype(F)
    tm = np.full(n, 5.0, F)
    setup = woop_setup(d)
    hit, bary, t = woop_hit_bary(o, setup, v[:, 0], v[:, 1], v[:, 2], tm)
    assert (hit == woop_hit(o, setup, v[:, 0], v[:, 1], v[:, 2], tm)).all() and hit.sum() > 40
    assert np.allclose(bary[hit].sum(axis=1), 1.0) and (bary[hit] >= 0).all()
    p_bary = np.einsum("pc,pcj->pj", bary[hit], v[hit].astype(np.float64))
    p_ray = o[hit].astype(np.float64) + t[hit, None] * d[hit]
    assert np.abs(p_bary - p_ray).max() < 1e-3
    assert (bary[~hit] == 0).all() and (t[~hit] == 0).all()


def test_sphere_against_closed_form():
    """Random rays against random spheres (unnormalised directions), away from tangency and
    from the t limits, agree with the float64 roots of |o + t d - c| = r."""
    rng = np.random.default_rng(5)
    n = 20000
    c = rng.normal(size=(n, 3))
    r = rng.uniform(0.2, 2.0, n)
    o = rng.normal(size=(n, 3)) * 3
    d = rng.normal(size=(n, 3)) * rng.uniform(0.1, 3.0, (n, 1))
    tmax = rng.choice([np.inf, 0.5, 2.0], n)
    f = o - c
    a = (d * d).sum(1)
    b = (f * d).sum(1)
    disc = b * b - a * ((f * f).sum(1) - r * r)
    sq = np.sqrt(np.maximum(disc, 0))
    t0, t1 = (-b - sq) / a, (-b + sq) / a
    ref = (disc >= 0) & (((t0 > 0) & (t0 < tmax)) | ((t1 > 0) & (t1 < tmax)))
    clear = (np.abs(disc) > 1e-3 * a * r * r) & (np.minimum.reduce([np.abs(t0), np.abs(t1), np.abs(t0 - tmax),
                                                                     np.abs(t1 - tmax)]) > 1e-3)
    got = sphere_hit(o.astype(F), d.astype(F), c.astype(F), r.astype(F), np.minimum(tmax, 3e38).astype(F))
    assert ref[clear].sum() > 300 and (~ref[clear]).sum() > 2000
    assert (got[clear] == ref[clear]).all()


def test_sphere_cases():
    """From inside (the far root), behind the origin, short of the surface, a zero-radius miss."""
    c = np.zeros((1, 3), F)
    one = np.ones(1, F)

    def hit(o, d, r=1.0, tmax=np.inf):
        return bool(sphere_hit(np.array([o], F), np.array([d], F), c, one * F(r), F(min(tmax, 3e38)))[0])

    assert hit([0, 0, 0], [1, 0, 0])  # inside: leaves at t = 1
    assert not hit([0, 0, 0], [1, 0, 0], tmax=0.99)
    assert hit([-3, 0, 0], [1, 0, 0], tmax=2.01) and not hit([-3, 0, 0], [1, 0, 0], tmax=1.99)
    assert not hit([3, 0, 0], [1, 0, 0])  # sphere behind the origin
    assert not hit([-3, 1.01, 0], [1, 0, 0])  # passes beside it
    assert not hit([-3, 0.01, 0], [1, 0, 0], r=0.0)


def test_sphere_pretest_is_conservative():
    """Every sphere hit passes the pre-test; segments that stay far from the sphere fail it."""
    rng = np.random.default_rng(6)
    n = 20000
    c = rng.normal(size=(n, 3)).astype(F)
    r = rng.uniform(0.1, 1.0, n).astype(F)
    o = (rng.normal(size=(n, 3)) * 3).astype(F)
    d = rng.normal(size=(n, 3)).astype(F)
    tm = rng.uniform(0.1, 4.0, n).astype(F)
    hit = sphere_hit(o, d, c, r, tm)
    pre = sphere_pretest(o, d, c, r, tm)
    assert hit.sum() > 100 and (pre[hit]).all()
    # float64 distance from the centre to the segment
    f = (o - c).astype(np.float64)
    dd = d.astype(np.float64)
    tc = np.clip(-(f * dd).sum(1) / (dd * dd).sum(1), 0, tm)
    dist = np.linalg.norm(f + tc[:, None] * dd, axis=1)
    assert not pre[dist > r * 1.01 + 1e-3].any()
    assert pre[dist < r * 0.99].all()


def test_slab_against_float64():
    """Random rays and boxes away from the box faces agree with a float64 slab test; no box the
    float64 test hits is ever missed (the test is conservative)."""
    rng = np.random.default_rng(7)
    n = 20000
    lo = rng.normal(size=(n, 3))
    hi = lo + rng.uniform(0.05, 2.0, (n, 3))
    o = rng.normal(size=(n, 3)) * 3
    d = rng.normal(size=(n, 3))
    tmax = rng.uniform(0.1, 6.0, n)
    t1, t2 = (lo - o) / d, (hi - o) / d
    tn, tf = np.minimum(t1, t2).max(1), np.maximum(t1, t2).min(1)
    ref = np.maximum(tn, 0) <= np.minimum(tf, tmax)
    clear = np.abs(np.maximum(tn, 0) - np.minimum(tf, tmax)) > 1e-3
    got = slab_hit(o.astype(F), slab_inv(d.astype(F)), lo.astype(F), hi.astype(F), tmax.astype(F))
    assert ref[clear].sum() > 100 and (~ref[clear]).sum() > 1000
    assert (got[clear] == ref[clear]).all()
    assert got[ref].all()


def test_slab_axis_parallel_rays():
    """A zero direction component (1/d = SLAB_BIG): inside that slab the box is hit, outside missed."""
    d = np.array([[1, 0, 0]] * 4, F)
    inv = slab_inv(d)
    assert (inv[:, 1:] == SLAB_BIG).all() and (inv[:, 0] == 1).all()
    o = np.array([[-5, 0.5, 0.5], [-5, 1.5, 0.5], [-5, 0.5, -0.01], [-5, 0.999, 0.001]], F)
    lo, hi = np.zeros((4, 3), F), np.ones((4, 3), F)
    assert slab_hit(o, inv, lo, hi, np.full(4, 10, F)).tolist() == [True, False, False, True]
    # the box lies beyond tmax / behind the origin
    assert slab_hit(o[:1], inv[:1], lo[:1], hi[:1], np.full(1, 4.9, F)).tolist() == [False]
    assert slab_hit(o[:1] + F(7), inv[:1], lo[:1], hi[:1], np.full(1, 10, F)).tolist() == [False]


def test_slab_is_conservative_on_box_edges():
    """Rays that only touch a box along one of its edges (entry t = exit t up to rounding) hit it."""
    rng = np.random.default_rng(10)
    n = 5000
    lo = rng.normal(size=(n, 3)).astype(F)
    hi = (lo + rng.uniform(0.1, 2.0, (n, 3))).astype(F)
    z = rng.uniform(lo[:, 2], hi[:, 2])
    edge = np.stack([hi[:, 0], hi[:, 1], z], 1).astype(np.float64)  # a point on the box's (+x, +y) edge
    d = np.stack([rng.uniform(0.2, 1, n), -rng.uniform(0.2, 1, n), rng.normal(size=n)], 1).astype(F)
    o = (edge - rng.uniform(0.5, 3.0, (n, 1)) * d).astype(F)  # outside the box before and after the edge
    got = slab_hit(o, slab_inv(d), lo, hi, np.full(n, 10, F))
    assert got.all()


def test_prepare_rays_validity():
    """Zero direction, tmax <= 0, NaN tmax and non-finite input are invalid; inf tmax is clamped."""
    o = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [np.nan, 0, 0], [0, 0, 0], [0, 0, 0]])
    d = np.array([[1, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [np.inf, 0, 0], [1, 0, 0]])
    tmax = np.array([1.0, 1.0, 0.0, np.nan, 1.0, 1.0, np.inf])
    po, pd, pt, valid = prepare_rays(o, d, tmax)
    assert po.dtype == pd.dtype == pt.dtype == F
    assert valid.tolist() == [True, False, False, False, False, False, True]
    assert np.isfinite(pt[6]) and pt[6] > 1e37 and pt[3] == 0


def test_transform_rays_matches_the_inverse_matrix():
    """Rows of the inverse world matrix map the origin as a point and the direction as a vector."""
    rng = np.random.default_rng(8)
    m = np.eye(4)
    m[:3, :3] = rng.normal(size=(3, 3))
    m[:3, 3] = rng.normal(size=3)
    inv = np.linalg.inv(m)
    o = rng.normal(size=(50, 3))
    d = rng.normal(size=(50, 3))
    rows = np.broadcast_to(inv[:3].astype(F).reshape(1, 12), (50, 12))
    om, dm = transform_rays(rows, o.astype(F), d.astype(F))
    assert om.dtype == dm.dtype == F
    assert np.allclose(om, o @ inv[:3, :3].T + inv[:3, 3], atol=1e-4)
    assert np.allclose(dm, d @ inv[:3, :3].T, atol=1e-4)


def test_ragged_pairs():
    owner, index = ragged_pairs([10, 0, 5], [2, 0, 3])
    assert owner.tolist() == [0, 0, 2, 2, 2]
    assert index.tolist() == [10, 11, 5, 6, 7]
    owner, index = ragged_pairs([3], [0])
    assert owner.size == index.size == 0
