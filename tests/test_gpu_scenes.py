"""Scenes built with core.scene directly, and an exact float64 numpy ray caster (test helpers)."""
import math

import numpy as np

from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Model, Scene


def plane_model(size=1.0):
    v = np.array([[-size, -size, 0], [size, -size, 0], [size, size, 0], [-size, size, 0]], np.float32)
    return Model("plane", v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32))


def cube_model():
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return Model("cube", v, np.array(tris, np.uint32))


def trs(t=(0, 0, 0), rot_z=0.0, rot_x=0.0, scale=(1, 1, 1)):
    cz, sz, cx, sx = math.cos(rot_z), math.sin(rot_z), math.cos(rot_x), math.sin(rot_x)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    m = np.eye(4)
    m[:3, :3] = rz @ rx @ np.diag(scale)
    m[:3, 3] = t
    return m


def look_at(eye, target, up=(0, 0, 1)):
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    upv = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, upv, back, eye
    return m


def basic_scene(offset=(0.0, 0.0, 0.0), camera_type="PERSP", lights=None, with_sphere=False):
    """A 10 m plane, a cube resting on it, a rotated/scaled box, optionally a sphere primitive."""
    off = np.asarray(offset, np.float64)
    names = ["ground", "cube", "box"]
    mats = [trs(off + (0, 0, 0), scale=(5, 5, 1)), trs(off + (0, 0, 1)),
            trs(off + (2.5, -1.5, 0.8), rot_z=0.6, rot_x=0.4, scale=(0.5, 1.2, 0.7))]
    mids = [0, 1, 1]
    colors = [(0.8, 0.8, 0.8, 1), (0.8, 0.2, 0.1, 1), (0.1, 0.3, 0.8, 1)]
    if with_sphere:
        names.append("ball")
        mats.append(trs(off + (-2.5, 2.0, 0.7), scale=(0.7, 0.7, 0.7)))
        mids.append(1)
        colors.append((0.2, 0.8, 0.2, 1))
    n = len(names)
    inst = Instances(names=names, model_ids=mids, matrices=np.array(mats), base_color=colors,
                     specular=np.linspace(0.2, 0.8, n), roughness=np.linspace(0.3, 0.7, n),
                     sphere=[False, False, False, True][:n])
    cam = Camera(matrix=look_at(off + (4.0, -5.5, 3.5), off + (0.3, 0.6, 0.3)), type=camera_type,
                 ortho_scale=7.0, lens=35.0, shift_x=0.03, shift_y=-0.02)
    if lights is None:
        lights = [Light("sun", "SUN", power=3.0, matrix=trs(off + (0, 0, 10), rot_z=0.5, rot_x=0.6))]
    return Scene(models=[plane_model(), cube_model()], instances=inst, lights=lights, camera=cam,
                 world_color=(0.05, 0.06, 0.08), resolution=(160, 120))


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


def test_ray_cast_helper_hits_the_cube_top():
    scene = basic_scene()
    t, i, f = ray_cast(scene, np.array([[0.0, 0.0, 10.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert i[0] == 1 and abs(t[0] - 8.0) < 1e-12
