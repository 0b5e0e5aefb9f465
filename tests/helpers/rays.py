"""Rays for the tests: seeded random and border-hugging rays, an exact float64 ray caster, the
shadow rays of a frame's G-buffer, the pixels whose camera ray crosses fractional alpha, and the
pixels away from silhouettes."""
import numpy as np


def terrain_rays(rng, n=300, spread=0.6):
    """``n`` rays down from 3 m over the helpers' terrain (``terrain_model``), their directions
    tilted by normal draws of ``spread``."""
    o = np.stack([rng.uniform(-9, 9, n), rng.uniform(-9, 9, n), np.full(n, 3.0)], 1)
    d = np.stack([rng.normal(scale=spread, size=n), rng.normal(scale=spread, size=n), -np.ones(n)], 1)
    return o, d


def random_rays(rng, scene, n, targeted=0.5, axis=0.2):
    """Mix of rays aimed at instance centres (hits likely), random rays and axis-aligned rays."""
    c = scene.instances.matrices[:, :3, 3]
    lo, hi = scene.world_bounds()
    lo, hi = lo - 3, hi + 3
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    k = int(n * targeted)
    tgt = c[rng.integers(0, len(c), k)] + rng.normal(scale=0.5, size=(k, 3))
    d[:k] = tgt - o[:k]
    a = rng.random(n) < axis
    # axis-aligned: keep 1 or 2 components, the others exactly 0
    keep = rng.random((n, 3)) < 0.5
    keep[np.arange(n), rng.integers(0, 3, n)] = True
    d[a] = np.where(keep[a], d[a], 0.0)
    t = rng.choice([np.inf, 0.5, 1.0, 1.5, 20.0], n)
    return o, d, t


#: axis-aligned and diagonal directions with exact zero components
AXIS_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                      [1, 1, 0], [1, 0, -1], [0, -1, 1], [-1, 1, -1]], float)


def border_rays(rng, layout, per_level: int):
    """Rays along axes (components exactly 0) from ``per_level`` node corners of every grid
    level, half of them infinite: ``(origins, dirs, tmax)``."""
    pts = []
    for lvl in range(layout.levels):
        s = layout.node_sizes[lvl]
        nx, ny = layout.dims[lvl]
        X, Y = np.meshgrid(layout.origin[0] + s * np.arange(nx + 1), layout.origin[1] + s * np.arange(ny + 1))
        P = np.stack([X.ravel(), Y.ravel(), rng.uniform(-1, 5, X.size)], 1)
        pts.append(P[rng.permutation(len(P))[:per_level]])
    P = np.concatenate(pts).astype(np.float32).astype(np.float64)  # (exact in float32 too)
    o = np.repeat(P, len(AXIS_DIRS), axis=0)
    d = np.tile(AXIS_DIRS, (len(P), 1))
    return o, d, np.where(rng.random(len(o)) < 0.5, np.inf, 3.0)


def world_triangles(scene):
    """(T, 3, 3) float64 world triangles of the non-sphere instances, and each one's instance."""
    tris, owner = [], []
    inst = scene.instances
    for i in range(len(inst)):
        if inst.sphere[i]:
            continue
        m = scene.models[inst.model_ids[i]]
        v = m.vertices.astype(np.float64) @ inst.matrices[i, :3, :3].T + inst.matrices[i, :3, 3]
        tris.append(v[m.triangles.astype(np.int64)])
        owner += [i] * m.triangle_count
    return np.concatenate(tris), np.array(owner)


def ray_cast(scene, origins, dirs, casters_only=False, tmin=0.0, tmax=None):
    """Closest hits of rays (..., 3) float64 against the scene: t (inf = miss), instance, face.

    face = triangle index (spheres: -1). Möller–Trumbore in float64, vectorised over triangles.
    """
    shape = origins.shape[:-1]
    o = origins.reshape(-1, 3)
    d = dirs.reshape(-1, 3)
    n = len(o)
    best = np.full(n, np.inf)
    inst_id = np.full(n, -1)
    face = np.full(n, -1)
    tri, owner = world_triangles(scene)
    tm = np.inf if tmax is None else np.asarray(tmax, np.float64).reshape(-1)
    for k in range(len(tri)):
        if casters_only and not scene.instances.casts_shadow[owner[k]]:
            continue
        v0, v1, v2 = tri[k]
        e1, e2 = v1 - v0, v2 - v0
        p = np.cross(d, e2)
        det = p @ e1
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - v0
        u = (s * p).sum(1) * inv
        q = np.cross(s, e1)
        v = (d * q).sum(1) * inv
        t = (q @ e2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tmin) & (t < best) & (t < tm)
        best[hit], inst_id[hit], face[hit] = t[hit], owner[k], k
    inst = scene.instances
    for i in np.nonzero(inst.sphere)[0]:
        if casters_only and not inst.casts_shadow[i]:
            continue
        m = scene.models[inst.model_ids[i]]
        inv = inst.inverse[i]
        mo = o @ inv[:3, :3].T + inv[:3, 3] - m.sphere_center
        md = d @ inv[:3, :3].T
        a = (md * md).sum(1)
        b = (mo * md).sum(1)
        c = (mo * mo).sum(1) - m.sphere_radius ** 2
        disc = b * b - a * c
        sq = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - sq) / a, (-b + sq) / a
        t = np.where(t0 > tmin, t0, t1)
        hit = (disc >= 0) & (t > tmin) & (t < best) & (t < tm)
        best[hit], inst_id[hit], face[hit] = t[hit], i, -1 - i
    return best.reshape(shape), inst_id.reshape(shape), face.reshape(shape)


def interior(labels):
    """(H, W) bool: pixels whose 8 neighbours carry the same label (no silhouettes/creases)."""
    lab = np.pad(labels, 1, mode="edge")
    h, w = labels.shape
    ok = np.ones((h, w), bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            ok &= lab[dy:dy + h, dx:dx + w] == labels
    return ok


def shadow_rays(frame, scene, li):
    """Origins (a little off the surface along the normal) and directions to light ``li`` of
    every covered pixel, row order of ``mask_array``."""
    pos = frame.gbuffer.read("position")
    nrm = frame.gbuffer.read("normal")
    ok = pos[..., 3] > 0
    p = pos[..., :3][ok].astype(np.float64)
    n = nrm[..., :3][ok].astype(np.float64)
    light = scene.lights[li]
    o = p + n * 2e-4
    if light.type == "SUN":
        d = np.broadcast_to(-light.direction, o.shape)
        tmax = np.full(len(o), np.inf)
    else:
        d = light.position - o
        tmax = np.ones(len(o))
    facing = (n * d).sum(axis=1) > 0
    return ok, o, d, tmax, facing


def mixed_pixels(scene, frame) -> np.ndarray:
    """(H, W) bool, row 0 = top: covered pixels whose camera ray (camera to the G-buffer's
    surface point at the pixel centre) crosses a surface of fractional alpha before it, or whose
    surface itself has alpha < 1 there: where Cycles blends two surfaces into the pixel. From the
    numpy oracle (``visibility_brute``: the product of the transmittances the ray crosses)."""
    from hybrid_shadow_addon.core.oracle.tracer import visibility_brute

    pos = frame.gbuffer.read("position")
    cov = pos[..., 3] > 0.5
    p = pos[..., :3][cov].astype(np.float64)
    cam = np.broadcast_to(scene.camera.matrix[:3, 3].astype(np.float64), p.shape)
    front = visibility_brute(scene, cam, p - cam, 1.0 - 1e-4)  # surfaces before the point
    through = visibility_brute(scene, cam, p - cam, 1.0 + 1e-4)  # ... and the point's own
    own_alpha = np.where(front > 0, 1.0 - through / np.maximum(front, 1e-12), 1.0)
    out = np.zeros(cov.shape, bool)
    out[cov] = (front < 0.999) | (own_alpha < 0.999)
    return out


def random_triangle_rays(rng, n):
    """``n`` random triangles ``v`` (n, 3, 3) and rays ``o``, ``d``, ``tmax`` in float64, with the
    float64 Moller-Trumbore answer ``ref`` and each case's distance from the test's boundaries
    (barycentrics, t and tmax: ``margin``)."""
    v = rng.normal(size=(n, 3, 3))
    o = rng.normal(size=(n, 3)) * 2
    d = rng.normal(size=(n, 3))
    tmax = rng.uniform(0.1, 5, n)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    p = np.cross(d, e2)
    det = (e1 * p).sum(1)
    s = o - v[:, 0]
    u = (s * p).sum(1) / det
    q = np.cross(s, e1)
    w = (d * q).sum(1) / det
    t = (e2 * q).sum(1) / det
    ref = (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0) & (t < tmax)
    margin = np.minimum.reduce([np.abs(u), np.abs(w), np.abs(1 - u - w), np.abs(t), np.abs(tmax - t)])
    return v, o, d, tmax, ref, margin
