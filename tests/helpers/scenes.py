"""Core scenes built in code for the tests (no bpy): transforms, small models, hand-made scenes
with every light kind, alpha-cut cards, soft lights, and seeded random and adversarial scenes."""
import math

import numpy as np

from hybrid_shadow_addon.core.bake import BakeConfig, GridConfig, bake_scene
from hybrid_shadow_addon.core.scene import Camera, Image, Instances, Light, Material, Model, Scene


def plane_model(size=1.0):
    """A square of half-width ``size`` at z = 0 (two triangles)."""
    v = np.array([[-size, -size, 0], [size, -size, 0], [size, size, 0], [-size, size, 0]], np.float32)
    return Model("plane", v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32))


def cube_model():
    """The [-1, 1] cube, twelve outward triangles."""
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return Model("cube", v, np.array(tris, np.uint32))


def trs(t=(0, 0, 0), rot_z=0.0, rot_x=0.0, scale=(1, 1, 1)):
    """A 4x4 world matrix: scale, then rotation about x, then about z, then translation ``t``."""
    cz, sz, cx, sx = math.cos(rot_z), math.sin(rot_z), math.cos(rot_x), math.sin(rot_x)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    m = np.eye(4)
    m[:3, :3] = rz @ rx @ np.diag(scale)
    m[:3, 3] = t
    return m


def look_at(eye, target, up=(0, 0, 1)):
    """A camera or light matrix at ``eye`` looking at ``target`` (-z forward, Blender's convention)."""
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


def all_lights():
    """One light of each type (sun, point, spot, area) around ``basic_scene``."""
    return [Light("sun", "SUN", power=3.0, matrix=look_at((-3, 6, 7), (0, 0, 0))),
            Light("point", "POINT", power=500.0, matrix=trs((1.5, -2.0, 3.5))),
            Light("spot", "SPOT", power=800.0, matrix=look_at((-2.5, -2.0, 5.0), (0.5, 0.5, 0.0)), spot_size=1.2),
            Light("area", "AREA", power=300.0, matrix=look_at((0.5, -3.0, 4.0), (0, 0, 0)), size=0.5)]


#: the UVs of ``quad``'s two triangles
QUAD_UV = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)


def quad(name, size=1.0, uv_scale=1.0):
    v = np.array([[-size, -size, 0], [size, -size, 0], [size, size, 0], [-size, size, 0]], np.float32)
    return Model(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), uvs=QUAD_UV * uv_scale)


def leaf_alpha(n=64):
    """A soft-edged leaf: alpha falls from 1 to 0 across an ellipse's rim, with a round hole."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n * 2 - 1
    r = np.sqrt((x / 0.9) ** 2 + (y / 0.55) ** 2)
    a = np.clip((1.0 - r) * 6.0, 0, 1) * (np.hypot(x - 0.3, y) > 0.18)
    px = np.zeros((n, n, 4), np.uint8)
    px[..., 1] = 160
    px[..., 3] = np.round(a * 255)
    return px


def checker(n=8):
    a = ((np.arange(n)[:, None] + np.arange(n)[None, :]) % 2 * 255).astype(np.uint8)
    px = np.full((n, n, 4), 200, np.uint8)
    px[..., 3] = a
    return px


def colour_image(n=32):
    y, x = np.mgrid[0:n, 0:n]
    px = np.zeros((n, n, 4), np.uint8)
    px[..., 0] = x * 255 // (n - 1)
    px[..., 1] = y * 255 // (n - 1)
    px[..., 2] = ((x // 4 + y // 4) % 2) * 200
    px[..., 3] = 255
    return px


def alpha_scene(lights=("sun",), card_materials=(0, 1, 2, 3)):
    """A textured ground, four cards above it: a Closest checker (BLEND), a Linear soft leaf
    (BLEND), two stacked alpha-0.5 cards, a CLIP leaf; an opaque cube as a plain caster."""
    images = [Image("checker", checker(), interpolation="Closest"), Image("leaf", leaf_alpha()),
              Image("ground", colour_image(), extension="REPEAT")]
    materials = [Material("checker", alpha_image=0), Material("leaf", alpha_image=1),
                 Material("half", alpha=0.5), Material("clip", alpha_image=1, alpha_mode="CLIP", alpha_threshold=0.7),
                 Material("ground", color_image=2, uv_transform=np.float32([[3, 0, 0.1], [0, 3, 0]]))]
    cube_v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube = Model("cube", cube_v,
                 np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.uint32))
    models = [quad("ground", 6.0), quad("card"), cube]
    mats = [trs((0, 0, 0)), trs((-2.2, 1.5, 1.4), rot_z=0.3, rot_x=0.2), trs((1.8, 1.6, 1.3), rot_z=-0.4),
            trs((-1.8, -1.8, 1.0), scale=(0.8, 0.8, 1)), trs((-1.8, -1.8, 1.5), scale=(0.8, 0.8, 1)),
            trs((2.0, -1.5, 1.2), rot_x=-0.3), trs((0.2, 0.0, 0.4), scale=(0.3, 0.3, 0.4))]
    mids = [0, 1, 1, 1, 1, 1, 2]
    cm = list(card_materials)
    material_ids = [4, cm[0], cm[1], cm[2], cm[2], cm[3], -1]
    inst = Instances(names=["ground", "checker", "leaf", "half_a", "half_b", "clip", "cube"], model_ids=mids,
                     matrices=np.array(mats), material_ids=material_ids, base_color=[(1, 1, 1, 1)] * 7)
    ls = []
    if "sun" in lights:
        ls.append(Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=0.7, rot_x=0.45)))
    if "point" in lights:
        ls.append(Light("point", "POINT", power=800.0, matrix=trs((0.5, 0.8, 5.0))))
    cam = Camera(matrix=look_at((0.5, -7.5, 8.5), (0, 0, 0.3)), lens=30.0)
    return Scene(models=models, instances=inst, lights=ls, camera=cam, resolution=(200, 150),
                 materials=materials, images=images).validate()


#: one extended light of each kind: a wide sun, a sphere light, square / rectangle / disk area lights
LIGHTS = [
    Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=2.6, rot_x=0.9), angle=np.radians(15)),
    Light("ball", "POINT", power=500.0, matrix=trs((1.5, -1.0, 3.5)), radius=0.4),
    Light("square", "AREA", power=500.0, matrix=trs((-1.0, 1.0, 3.0), rot_x=0.3), size=0.9, area_shape="SQUARE"),
    Light("rect", "AREA", power=500.0, matrix=trs((1.0, 1.5, 3.0), rot_z=0.4), size=1.2, size_y=0.5,
          area_shape="RECTANGLE"),
    Light("disk", "AREA", power=500.0, matrix=trs((0.5, -0.5, 3.2)), size=1.0, area_shape="DISK"),
]


def soft_scene(lights=LIGHTS):
    """``basic_scene`` under copies of ``lights`` (extended lights by default)."""
    return basic_scene(lights=[Light(light.name, light.type, power=light.power, matrix=light.matrix.copy(),
                                     radius=light.radius, angle=light.angle, size=light.size,
                                     size_y=light.size_y, area_shape=light.area_shape, spread=light.spread,
                                     spot_size=light.spot_size, spot_blend=light.spot_blend)
                               for light in lights])


def blob_model(rng, n_tri, name="blob", size=1.0):
    """Random triangles in a box (overlapping soup: stresses the BVH)."""
    c = rng.uniform(-size, size, (n_tri, 1, 3))
    v = (c + rng.normal(scale=0.3 * size, size=(n_tri, 3, 3))).reshape(-1, 3)
    return Model(name, v, np.arange(3 * n_tri).reshape(-1, 3))


def terrain_model(n=158, name="terrain"):
    """A bumpy 20 m height field of 2 n^2 triangles (n = 158: 49,928) around the origin."""
    xs = np.linspace(-10, 10, n + 1)
    X, Y = np.meshgrid(xs, xs)
    v = np.stack([X.ravel(), Y.ravel(), (0.2 * np.sin(X) * np.cos(Y)).ravel()], 1)
    i = np.arange(n)
    a = (i[None, :] + (n + 1) * i[:, None]).ravel()
    tris = np.concatenate([np.stack([a, a + 1, a + n + 2], 1), np.stack([a, a + n + 2, a + n + 1], 1)])
    return Model(name, v, tris)


def plate_model(n=4, name="plate"):
    """A watertight-ish n x n grid of quads in the unit square at z = 0 (shared edges)."""
    xs = np.linspace(-1, 1, n + 1)
    X, Y = np.meshgrid(xs, xs)
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    tris = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            tris += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return Model(name, v, np.array(tris))


def random_matrices(rng, n, area=30.0, zrange=(0, 4), scale=(0.3, 2.0), negative=True):
    """``n`` random rotations, scales (some negative) and translations over an area."""
    M = np.tile(np.eye(4), (n, 1, 1))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    S = rng.uniform(*scale, (n, 3))
    if negative:
        S *= rng.choice([-1.0, 1.0], (n, 3), p=[0.25, 0.75])
    M[:, :3, :3] = R * S[:, None, :]
    M[:, 0, 3] = rng.uniform(-area, area, n)
    M[:, 1, 3] = rng.uniform(-area, area, n)
    M[:, 2, 3] = rng.uniform(*zrange, n)
    return M


def random_scene(rng, n_inst=200, spheres=0.25, area=30.0, tri_counts=(1, 12, 60, 300), casters=0.9):
    """Random blobs, plates and spheres (some not casting) over an area, seeded by ``rng``."""
    models = [blob_model(rng, k, f"blob{k}") for k in tri_counts] + [plate_model(4)]
    n = n_inst
    inst = Instances(names=[f"o{i}" for i in range(n)], model_ids=rng.integers(0, len(models), n),
                     matrices=random_matrices(rng, n, area), sphere=rng.random(n) < spheres,
                     casts_shadow=rng.random(n) < casters)
    return Scene(models=models, instances=inst)


def adversarial_scene(rng):
    """Objects straddling node borders and levels, a node with thousands of objects, and rays
    on node borders, along axes, from outside the grid and from above."""
    models = [plate_model(2), blob_model(rng, 20),
              Model("tiny", [[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0.02]], [[0, 1, 2]])]
    parts = []
    # a lattice of plates exactly on integer positions (borders of a unit grid)
    g = np.arange(-8, 9, 2.0)
    X, Y = np.meshgrid(g, g)
    n1 = X.size
    M1 = np.tile(np.eye(4), (n1, 1, 1))
    M1[:, 0, 3], M1[:, 1, 3] = X.ravel(), Y.ravel()
    M1[:, 2, 3] = rng.uniform(0, 2, n1)
    M1[:, :3, :3] *= rng.choice([-1.0, 1.0], (n1, 1, 3)) * rng.uniform(0.3, 1.2, (n1, 1, 3))
    parts.append(Instances(names=[f"p{i}" for i in range(n1)], model_ids=np.zeros(n1), matrices=M1))
    # 3000 tiny objects in one small region (thousands in a node)
    n2 = 3000
    M2 = np.tile(np.eye(4), (n2, 1, 1))
    M2[:, :3, 3] = rng.uniform([3.1, 3.1, 0.0], [3.9, 3.9, 1.0], (n2, 3))
    parts.append(Instances(names=[f"t{i}" for i in range(n2)], model_ids=np.full(n2, 2), matrices=M2,
                           sphere=rng.random(n2) < 0.5))
    # big objects spanning many nodes (go to high levels)
    M3 = random_matrices(rng, 6, area=6, scale=(3, 6))
    parts.append(Instances(names=[f"b{i}" for i in range(6)], model_ids=np.ones(6), matrices=M3,
                           sphere=np.array([0, 1, 0, 1, 0, 1], bool)))
    scene = Scene(models=models, instances=Instances.concatenate(parts))
    baked = bake_scene(scene, BakeConfig(structure="grid", grid=GridConfig(base_node_size=1.0)))
    lay = baked.accel.layout
    n = 6000
    o = rng.uniform(-10, 10, (n, 3))
    o[:, 2] = rng.uniform(-1, 4, n)
    # origins exactly on node borders of random levels
    lv = rng.integers(0, lay.levels, n)
    s = lay.node_sizes[lv]
    on = rng.random(n) < 0.5
    o[on, 0] = lay.origin[0] + np.round((o[on, 0] - lay.origin[0]) / s[on]) * s[on]
    on = rng.random(n) < 0.5
    o[on, 1] = lay.origin[1] + np.round((o[on, 1] - lay.origin[1]) / s[on]) * s[on]
    tgt = scene.instances.matrices[rng.integers(0, len(scene.instances), n), :3, 3]
    d = tgt - o + rng.normal(scale=0.2, size=(n, 3))
    axis = rng.random(n) < 0.4
    comp = rng.integers(0, 3, n)
    dd = np.zeros((n, 3))
    dd[np.arange(n), comp] = rng.choice([-1.0, 1.0], n)
    two = rng.random(n) < 0.5
    dd[two] += np.where(rng.random((two.sum(), 3)) < 0.5, 0, rng.choice([-1.0, 1.0], (two.sum(), 3)))
    d[axis] = dd[axis]
    d[(d == 0).all(axis=1)] = [0, 0, 1]
    far = rng.random(n) < 0.1  # outside the grid
    o[far, :2] *= 5
    t = rng.choice([np.inf, 1.0, 5.0], n)
    return scene, o, d, t


#: the size ``variant_scene`` renders at
VARIANT_SIZE = (64, 48)


def variant_scene(lights=("SUN",), meshes=True, spheres=False, spread=1.0):
    """A scene with just the optional features asked for: a ground and a box (``meshes``), a ball
    (``spheres``; a big sphere as the ground without meshes), far-apart boxes (``spread``: several
    grid levels), one light of each type in ``lights``."""
    models = [Model("plane", [[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], [[0, 1, 2], [0, 2, 3]]),
              Model("box", np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (0, 1)]),
                    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])]
    names, mids, mats, sph = [], [], [], []
    if meshes:
        names += ["ground", "box"]
        mids += [0, 1]
        mats += [np.eye(4), np.eye(4)]
        sph += [False, False]
    if spheres:
        m = np.eye(4)
        m[:3, 3] = (1.5, 1.0, 0.6)
        names.append("ball")
        mids.append(1)
        mats.append(m)
        sph.append(True)
        if not meshes:  # something to receive shadows: a big sphere as the ground
            g = np.diag([20.0, 20.0, 1.0, 1.0])
            g[2, 3] = -1.0
            names.append("ground ball")
            mids.append(1)
            mats.append(g)
            sph.append(True)
    if spread > 1.0:  # far-apart objects: several grid levels
        for i, x in enumerate((-spread, spread)):
            m = np.eye(4)
            m[0, 3] = x
            names.append(f"far{i}")
            mids.append(1)
            mats.append(m)
            sph.append(spheres and not meshes)
    inst = Instances(names=names, model_ids=mids, matrices=np.array(mats), sphere=np.array(sph, bool))
    cam = np.eye(4)
    cam[:3, 3] = (0, -8, 5)
    a = np.radians(58)
    cam[:3, :3] = [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]
    ls = []
    for t in lights:
        m = np.eye(4)
        m[:3, 3] = (1, -1, 4)
        ls.append(Light(t, t, matrix=m, power=500.0, spot_size=np.radians(120)))
    return Scene(models=models, instances=inst, lights=ls, camera=Camera(matrix=cam), resolution=VARIANT_SIZE)


def pane_scene(alphas=(0.3, 0.7), stacked=False, sun_rot=(2.6, 0.7), pane_x=0.0, panes=True):
    """See-through panes (Principled Alpha, no image, BLEND) level above a patterned ground lit by
    a sun, with an opaque cube casting a shadow under each (instances: the ground, the cubes,
    the panes); ``stacked``: a second pane of each
    alpha 0.3 m above the first. The panes are horizontal like the ground, so a sun lights both
    alike and Cycles' per-light visibility through a pane is the alpha-weighted mean. ``pane_x``
    moves the panes along x (far: out of view); ``panes=False`` leaves them out (what lies
    behind them)."""
    images = [Image("ground", colour_image(), extension="REPEAT")]
    materials = [Material("ground", color_image=0, uv_transform=np.float32([[3, 0, 0.1], [0, 3, 0]]))]
    materials += [Material(f"pane{int(round(a * 100))}", alpha=a) for a in alphas]
    cube = Model("cube", np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32),
                 np.array([t for q in [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
                                       (1, 5, 7, 3)] for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.uint32))
    models = [quad("ground", 6.0), quad("pane"), cube]
    names, mids, mats, mat_ids, colours = ["ground"], [0], [trs()], [0], [(1, 1, 1, 1)]
    for k in range(len(alphas)):  # an opaque cube under each pane
        names.append(f"cube{k}")
        mids.append(2)
        mats.append(trs((pane_x - 1.6 + 3.2 * k, 0.3, 0.5), scale=(0.4, 0.4, 0.5)))
        mat_ids.append(-1)
        colours.append((0.8, 0.3, 0.2, 1))
    layers = (0.0, 0.3) if stacked else (0.0,)
    for k, a in enumerate(alphas if panes else ()):
        for j, dz in enumerate(layers):
            names.append(f"pane{int(round(a * 100))}_{j}")
            mids.append(1)
            mats.append(trs((pane_x - 1.6 + 3.2 * k, 0.0, 1.6 + dz), scale=(1.4, 1.8, 1)))
            mat_ids.append(1 + k)
            colours.append((0.2, 0.5, 0.9, 1))
    inst = Instances(names=names, model_ids=mids, matrices=np.array(mats), material_ids=mat_ids,
                     base_color=colours)
    sun = Light("sun", "SUN", power=3.0, matrix=trs((0, 0, 10), rot_z=sun_rot[0], rot_x=sun_rot[1]))
    cam = Camera(matrix=look_at((0.0, -6.5, 7.0), (0, 0.3, 0.6)), lens=32.0)
    return Scene(models=models, instances=inst, lights=[sun], camera=cam, resolution=(160, 120),
                 materials=materials, images=images, world_color=(0.05, 0.05, 0.05)).validate()
