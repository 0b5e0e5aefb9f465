"""G-buffer positions/normals against an exact float64 ray cast of Camera.pixel_rays."""
import numpy as np
import pytest

from tests.helpers.rays import interior, ray_cast
from tests.helpers.scenes import basic_scene, trs

pytestmark = [pytest.mark.gpu]

W, H = 160, 120


@pytest.mark.parametrize("camera_type,offset", [("PERSP", (0, 0, 0)), ("ORTHO", (0, 0, 0)),
                                                ("PERSP", (3000.0, -2000.0, 150.0))])
def test_positions_match_exact_ray_cast(pass_rig, camera_type, offset):
    scene = basic_scene(offset=offset, camera_type=camera_type, with_sphere=True)
    gb = pass_rig.gbuffer(scene, W, H)
    pos = gb.read("position")
    nrm = gb.read("normal")
    mat = gb.read("material")
    depth = gb.read("depth")
    o, d = scene.camera.pixel_rays(W, H)
    t, inst, face = ray_cast(scene, o, d)
    hit = np.isfinite(t)
    cov = pos[..., 3] > 0.5
    ok = interior(np.where(hit, face, -10**6))
    # coverage agrees away from silhouettes
    assert (cov == hit)[ok].all()
    assert ((cov != hit).sum()) < 0.01 * W * H
    sel = ok & hit
    assert sel.sum() > 0.5 * W * H
    ref = o + t[..., None] * d
    dist = np.linalg.norm(ref - scene.camera.world_matrix_normalized()[:3, 3], axis=-1)
    err = np.linalg.norm(pos[..., :3].astype(np.float64) - ref, axis=-1)
    # float32 storage of world coordinates far from the origin costs ~1 ULP of |p|
    tol = 1e-6 * dist + 2 * np.spacing(np.float32(np.abs(ref[sel]).max()))
    assert (err[sel] < tol[sel]).all(), ((err - tol)[sel].max(), (err[sel] / dist[sel]).max())
    assert (err[sel] / dist[sel]).max() < 1e-4
    # instance index and face normals
    assert (mat[..., 2][sel].round().astype(int) == inst[sel]).all()
    assert (mat[..., 2][~cov] == 0).all() and (pos[~cov] == 0).all()
    # normals: unit, facing the camera, perpendicular to the hit triangle
    n = nrm[..., :3]
    assert np.allclose(np.linalg.norm(n[cov], axis=-1), 1, atol=1e-5)
    assert ((n * d).sum(-1)[sel] < 0).all()
    # view depth
    cam = scene.camera.world_matrix_normalized()
    ref_depth = -((ref - cam[:3, 3]) @ cam[:3, 2])
    assert np.allclose(depth[sel], ref_depth[sel], rtol=1e-5, atol=1e-4)
    assert (depth[~cov] == 0).all()
    # albedo follows the instance colours
    alb = gb.read("albedo")
    assert np.allclose(alb[sel], scene.instances.base_color[inst[sel]], atol=2e-3)


def test_top_row_is_top_and_moving_reuses_model_buffers(pass_rig):
    scene = basic_scene()
    gb = pass_rig.gbuffer(scene, W, H)
    pos = gb.read("position")
    # the camera looks down: the bottom rows are the ground nearest the camera
    cov = pos[..., 3] > 0.5
    assert cov[-1].all()
    vbos = pass_rig.gpu.models.buffer_ids()
    scene.instances.set_matrices([1], trs((1.0, 1.0, 1.0))[None])
    gb = pass_rig.gbuffer(scene, W, H)
    assert pass_rig.gpu.models.buffer_ids() == vbos
    assert pass_rig.gbuffer_pass.draw_calls == 2  # one per model
    pos2 = gb.read("position")
    assert not np.array_equal(pos, pos2)


@pytest.mark.parametrize("wound", ["outwards", "inwards"])
def test_smooth_shading_normals(pass_rig, wound):
    """A model with corner normals shades smoothly (shading normal interpolated); flat models keep
    shading == geometric normal. A ball wound inwards (the camera sees its triangles' backs) with
    outward corner normals gets them turned over with the geometric normal, as Cycles turns N
    and Ng of a back-facing hit: they point into the ball."""
    from hybrid_shadow_addon.core.scene import Model

    scene = basic_scene()
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25)[:-1], np.linspace(0.15, np.pi - 0.15, 12))
    verts = np.stack([np.sin(v) * np.cos(u), np.sin(v) * np.sin(u), np.cos(v)], -1).reshape(-1, 3)
    i = np.arange(11)[:, None] * 24 + np.arange(24)[None, :]
    j = np.arange(11)[:, None] * 24 + (np.arange(24)[None, :] + 1) % 24
    quads = np.stack([i, j, j + 24, i + 24], -1).reshape(-1, 4)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    if wound == "outwards":
        tris = tris[:, ::-1]
    ball = Model("smooth ball", verts, tris, normals=verts[tris])
    scene.models.append(ball)
    scene.instances.model_ids[2] = 2  # the rotated box becomes a smooth ball
    scene.instances.matrices[2] = trs((1.5, -1.5, 1.0))
    scene.instances.set_matrices([2], scene.instances.matrices[2])
    gb = pass_rig.gbuffer(scene, W, H)
    inst = gb.read("material")[..., 2]
    geo, shade = gb.read("normal")[..., :3], gb.read("shading_normal")[..., :3]
    pos = gb.read("position")[..., :3]
    ball = gb.coverage() & (np.round(inst) == 2)
    on_ball = interior(ball.astype(int)) & ball
    assert on_ball.sum() > 200
    true_n = pos[on_ball] - (1.5, -1.5, 1.0)
    true_n /= np.linalg.norm(true_n, axis=1, keepdims=True)
    sign = 1.0 if wound == "outwards" else -1.0
    err_shade = np.degrees(np.arccos(np.clip((shade[on_ball] * sign * true_n).sum(1), -1, 1)))
    err_geo = np.degrees(np.arccos(np.clip((geo[on_ball] * true_n).sum(1), -1, 1)))
    assert np.percentile(err_shade, 95) < 2.0 < np.percentile(err_geo, 95)
    flat = gb.coverage() & (np.round(inst) == 1)
    np.testing.assert_allclose(shade[flat], geo[flat], atol=2e-3)


@pytest.mark.parametrize("camera_type", ["PERSP", "ORTHO"])
def test_instances_outside_the_view_are_not_drawn_and_change_nothing(pass_rig, monkeypatch, camera_type):
    """Frustum culling leaves out the instances whose bounding sphere misses the view (behind
    the camera, beside it, beyond clip_end, a sphere primitive too) and keeps the one that
    straddles the image's edge: the G-buffer is the same, bit for bit, as drawing every one."""
    from hybrid_shadow_addon.core.gpu.passes import gbuffer as gbuffer_module
    from hybrid_shadow_addon.core.scene import Instances

    base = basic_scene(camera_type=camera_type, with_sphere=True)
    cam = base.camera.world_matrix_normalized()
    pos, right, up, back = cam[:3, 3], cam[:3, 0], cam[:3, 1], cam[:3, 2]
    o, d = base.camera.pixel_rays(W, H)
    edge = o[H // 2, 0] + 6.0 * d[H // 2, 0] - 0.4 * right  # just left of the image, 6 m out: a corner shows
    ahead = pos - 8.0 * back
    outside = [pos + 3.0 * back, ahead - 40.0 * right, ahead + 40.0 * right, ahead + 40.0 * up,
               ahead - 40.0 * up, pos - 5000.0 * back]
    where = outside + [edge, ahead - 40.0 * right]
    sphere = [False] * (len(where) - 1) + [True]
    extra = Instances(names=[f"x{i}" for i in range(len(where))], model_ids=[1] * len(where),
                      matrices=np.array([trs(tuple(p), scale=(0.5, 0.5, 0.5)) for p in where]),
                      base_color=[(0.5, 0.5, 0.5, 1)] * len(where), sphere=sphere)
    scene = base.__class__(**{**base.__dict__, "instances": Instances.concatenate([base.instances, extra])})
    n0 = len(base.instances)
    gb = pass_rig.gbuffer(scene, W, H)
    assert pass_rig.gbuffer_pass.culled == len(outside) + 1
    names = ("position", "normal", "shading_normal", "albedo", "material", "depth")
    culled = {k: gb.read(k).copy() for k in names}
    assert (culled["material"][..., 2].round() == n0 + len(outside)).any()  # the edge cube is drawn
    monkeypatch.setattr(gbuffer_module, "frustum_visible", lambda s, *a: np.ones(len(s.instances), bool))
    gb = pass_rig.gbuffer(scene, W, H)
    assert pass_rig.gbuffer_pass.culled == 0
    for k in names:
        assert np.array_equal(culled[k], gb.read(k)), k


def test_indexed_layout_keeps_every_corner_and_face():
    """The indexed buffers give back each triangle's corners (position, normal, UV) in order,
    share the corners that are equal, and give each triangle's last (provoking) corner its own
    face normal, shared only by triangles with the same one."""
    from hybrid_shadow_addon.core.gpu.geometry import face_normals, indexed_vertex_data
    from hybrid_shadow_addon.core.scene import Model

    rng = np.random.default_rng(3)
    n = 9
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2).astype(np.float32)
    verts = np.concatenate([g, rng.random((len(g), 1), np.float32)], 1)
    flat = verts.copy()
    flat[:, 2] = 0.0  # a flat grid: one face normal for all
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
    smooth = rng.normal(size=(len(verts), 3)).astype(np.float32)
    sharp = smooth[tris].copy()
    sharp[:10, 0] = sharp[10:20, 1] = (0.0, 0.0, 1.0)  # a sharp edge: vertices with two normals
    seam = verts[tris][..., :2] * 0.1
    seam[5:9, 2] = -1.0  # a UV seam
    for vv, normals, uvs in ((verts, None, None), (verts, smooth[tris], None),
                             (verts, smooth[tris], verts[tris][..., :2] * 0.1),
                             (verts, sharp, seam), (flat, None, None)):
        m = Model("grid", vv, tris, normals=normals, uvs=uvs)
        for order in (None, np.random.default_rng(1).permutation(len(tris))):
            if order is not None:  # (the same triangles in another order)
                m = Model("grid", vv, tris[order], normals=None if normals is None else normals[order],
                          uvs=None if uvs is None else uvs[order])
            vb, idx, source = indexed_vertex_data(m)
            corners = vb[idx].reshape(-1, 3, 11)
            assert np.array_equal(corners[..., :3], m.vertices[m.triangles])
            ref_n = np.zeros_like(corners[..., 3:6]) if normals is None else m.normals
            ref_uv = np.zeros_like(corners[..., 6:8]) if uvs is None else m.uvs
            assert np.array_equal(corners[..., 3:6], ref_n) and np.array_equal(corners[..., 6:8], ref_uv)
            fn = face_normals(m)
            assert np.array_equal(corners[:, 2, 8:], fn)  # the provoking corner's face normal
            # without the copies (position-only passes): the same corners, fewer vertices
            shared = source[idx]
            assert np.array_equal(vb[shared][:, :8], vb[idx][:, :8])
            assert len(np.unique(shared)) == len(np.unique(vb[idx][:, :8], axis=0)) <= len(np.unique(idx))
            # a last corner shared by two triangles carries one face normal for both
            last = idx[2::3]
            key = np.concatenate([corners[:, 2, :8], fn], 1)
            u, inv = np.unique(last, return_inverse=True)
            for k in range(len(u)):
                assert len(np.unique(key[inv.ravel() == k], axis=0)) == 1
            # no more vertices than the distinct corners plus the distinct (last corner, face normal) pairs
            distinct = len(np.unique(corners[..., :8].reshape(-1, 8), axis=0))
            assert len(vb) <= distinct + len(np.unique(key, axis=0))
            if vv is flat and normals is None:
                assert len(vb) == len(verts)  # one face normal: nothing copied
        tri = m.vertices.astype(np.float64)[m.triangles.astype(np.int64)]
        fnr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.allclose(face_normals(m), fnr / np.linalg.norm(fnr, axis=1, keepdims=True), atol=1e-7)


def test_face_normals_of_a_bumpy_grid(pass_rig):
    """A bumpy 48 x 48-quad grid (4608 triangles, each of whose provoking corners carries its
    face normal, many of them copies): every pixel's normal is its hit triangle's, the position
    the ray's."""
    from hybrid_shadow_addon.core.scene import Instances, Model, Scene

    n = 49
    rng = np.random.default_rng(5)
    xy = np.stack(np.meshgrid(np.linspace(-3, 3, n), np.linspace(-3, 3, n), indexing="ij"), -1).reshape(-1, 2)
    verts = np.concatenate([xy, 0.15 * rng.random((len(xy), 1))], 1).astype(np.float32)
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
    base = basic_scene()
    scene = Scene(models=[Model("bumps", verts, tris)],
                  instances=Instances(names=["bumps"], model_ids=[0], matrices=trs((0.2, 0.1, 0.0), rot_z=0.3)[None],
                                      base_color=[(0.6, 0.6, 0.6, 1)]),
                  lights=base.lights, camera=base.camera, world_color=base.world_color, resolution=(96, 72))
    w, h = 96, 72
    gb = pass_rig.gbuffer(scene, w, h)
    o, d = scene.camera.pixel_rays(w, h)
    t, inst, face = ray_cast(scene, o, d)
    sel = np.isfinite(t)
    assert sel.sum() > 0.3 * w * h and (face[sel] >= 4096).sum() > 100
    m = scene.instances.matrices[0]
    wv = verts.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    tri = wv[tris.astype(np.int64)]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    ref = fn[face[sel]] * -np.sign((fn[face[sel]] * d[sel]).sum(-1, keepdims=True))
    late = face[sel] >= 4096
    for target, tol in (("normal", 1e-5), ("shading_normal", 1e-3)):  # (flat: the shading normal is
        ok = np.abs(gb.read(target)[..., :3][sel] - ref).max(-1) < tol    # the face's, in half floats)
        # (a pixel centre on a shared edge may fall to either triangle)
        assert ok.mean() > 0.97 and ok[late].mean() > 0.97, (target, ok.mean(), ok[late].mean())
    p = gb.read("position")[..., :3][sel].astype(np.float64)
    assert (np.abs(p - (o + t[..., None] * d)[sel]).max(-1) < 1e-5).mean() > 0.97


def _bumpy_grid(n, size, seed, uv=False):
    from hybrid_shadow_addon.core.scene import Model

    rng = np.random.default_rng(seed)
    xy = np.stack(np.meshgrid(np.linspace(-size, size, n), np.linspace(-size, size, n), indexing="ij"),
                  -1).reshape(-1, 2)
    verts = np.concatenate([xy, 0.2 * rng.random((len(xy), 1))], 1).astype(np.float32)
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
    normals = rng.normal(size=(len(verts), 3)).astype(np.float32)[tris]
    normals[..., 2] = np.abs(normals[..., 2]) + 2.0
    uvs = (xy.astype(np.float32)[tris] * 0.1) if uv else None
    return Model("terrain", verts, tris, normals=normals, uvs=uvs)


def test_big_models_are_drawn_by_chunks_in_view(pass_rig, monkeypatch):
    """A model of many triangles is drawn by chunks of nearby triangles, those outside the view
    left out: the G-buffer is bit-identical to the whole model drawn in its own triangle order,
    with fewer triangles drawn; each pixel's face normal is that of the triangle under it."""
    from hybrid_shadow_addon.core.gpu import geometry
    from hybrid_shadow_addon.core.scene import Instances, Scene

    base = basic_scene()
    terrain = _bumpy_grid(97, 30.0, 7)  # 18432 triangles: 9 chunks
    assert geometry.chunk_order(terrain) is not None and geometry.chunk_order(basic_scene().models[0]) is None
    mats = [trs((0.0, 0.0, -0.3)), trs((35.0, 20.0, -0.5), rot_z=0.7, scale=(0.6, 0.8, 1.0)),
            trs((0.0, 0.0, 500.0))]  # under the camera, to its side, far above it (out of view)
    scene = Scene(models=[terrain, base.models[1]],
                  instances=Instances.concatenate([
                      Instances(names=["t0", "t1", "t2"], model_ids=[0, 0, 0], matrices=np.array(mats),
                                base_color=[(0.6, 0.6, 0.6, 1)] * 3),
                      Instances(names=["cube"], model_ids=[1], matrices=trs((0, 0, 1))[None],
                                base_color=[(0.8, 0.2, 0.1, 1)])]),
                  lights=base.lights, camera=base.camera, world_color=base.world_color, resolution=(W, H))
    names = ("position", "normal", "shading_normal", "albedo", "material", "depth")
    gp = pass_rig.gbuffer_pass
    got = {}
    for key, chunked, minimum in (("chunks", True, geometry.CHUNK_MIN), ("whole", False, geometry.CHUNK_MIN),
                                  ("own order", True, 10 ** 9)):
        monkeypatch.setattr(geometry, "CHUNK_MIN", minimum)
        monkeypatch.setattr(gp, "chunked", chunked)
        pass_rig.gpu.models.prune([])
        # (a model's first frame draws it whole, in its own order: its chunks come from the next on)
        gb = pass_rig.gbuffer(scene, W, H)
        first = gp.triangles
        gb = pass_rig.gbuffer(scene, W, H)
        got[key] = ({k: gb.read(k).copy() for k in names}, gp.triangles, gp.draw_calls)
        assert first == 2 * terrain.triangle_count + 12
    (img, tris, draws), (whole, whole_tris, _), (own, own_tris, own_draws) = (got["chunks"], got["whole"],
                                                                              got["own order"])
    assert own_tris == whole_tris == 2 * terrain.triangle_count + 12 and own_draws == 2
    assert tris < 0.75 * whole_tris and draws > own_draws
    for k in names:
        assert np.array_equal(img[k], whole[k]), k
        assert np.array_equal(img[k], own[k]), k
    # the normals are those of the terrain's quad under each pixel's position: either of its two
    # triangles (a pixel centre on the diagonal may fall to either)
    sel = (img["material"][..., 2].round() == 0) & (img["position"][..., 3] > 0.5)
    assert sel.sum() > 0.3 * W * H
    p = img["position"][..., :3][sel].astype(np.float64) - mats[0][:3, 3]
    n = 97
    step = 60.0 / (n - 1)
    ij = np.clip(np.floor((p[:, :2] + 30.0) / step).astype(int), 0, n - 2)
    first = 2 * (ij[:, 0] * (n - 1) + ij[:, 1])
    tri = terrain.vertices.astype(np.float64)[terrain.triangles.astype(np.int64)]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    fn *= np.sign(fn[:, 2:])  # (the camera looks down on the terrain)
    got = img["normal"][..., :3][sel]
    ok = np.minimum(np.abs(got - fn[first]).max(-1), np.abs(got - fn[first + 1]).max(-1)) < 1e-5
    assert ok.mean() > 0.99, ok.mean()


def test_chunk_order_bounds_its_chunks():
    """Chunks are a permutation of the triangles, cut every CHUNK_TRIS; each chunk's sphere holds
    all its corners, and Morton order keeps chunks compact (far smaller than the model)."""
    from hybrid_shadow_addon.core.gpu.geometry import CHUNK_TRIS, chunk_order

    m = _bumpy_grid(129, 1000.0, 3)  # 32768 triangles, flat and wide, far from 0 in z after a shift
    m.vertices[:, 2] += 4.0e4
    order, starts, centres, radii = chunk_order(m)
    assert np.array_equal(np.sort(order), np.arange(m.triangle_count))
    assert np.array_equal(starts, np.arange(0, m.triangle_count, CHUNK_TRIS))
    v = m.vertices.astype(np.float64)
    bounds = np.append(starts, m.triangle_count)
    for k in range(len(starts)):
        pts = v[m.triangles[order[bounds[k]:bounds[k + 1]]].ravel()]
        assert (np.linalg.norm(pts - centres[k], axis=1) <= radii[k]).all()
    assert radii.max() < 0.4 * m.sphere_radius
