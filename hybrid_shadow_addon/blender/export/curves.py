"""Reading strands and points from Blender as Cycles reads them: Curves data (``position``,
``radius``, curve offsets), particle hair (the evaluated paths ``ParticleSystem.co_hair`` gives,
with the particle settings' root/tip radius and shape) and point clouds (``position``,
``radius``). Strands become tubes and points sphere primitives (:mod:`...core.scene.curves`)."""
from __future__ import annotations

import numpy as np

from ...core.scene.curves import tube_sides
from .common import warn_export

#: Cycles' radius of a Curves point without a ``radius`` attribute
CURVES_DEFAULT_RADIUS = 0.005
#: Cycles' radius of a point-cloud point without a ``radius`` attribute
POINTS_DEFAULT_RADIUS = 0.01
#: samples per control-point segment along the Catmull-Rom spline of a strand
SUBDIVISIONS = 2
#: Blender's ``curve_type`` value of poly (straight) curves
POLY = 1


def _attribute(data, name: str, n: int, width: int, dtype=np.float32, prop: str = "value"):
    """Attribute ``name`` of ``data`` (``n`` elements of ``width`` values), None when absent."""
    attr = data.attributes.get(name)
    if attr is None:
        return None
    out = np.empty(n * width, dtype)
    attr.data.foreach_get(prop, out)
    return out.reshape(n, width) if width > 1 else out


def curves_strands(curves):
    """``(points (P, 3) object space, radii (P,), offsets (C + 1,), subdivisions)`` of a Curves
    data-block; poly curves are straight between their points, others follow the spline."""
    n = len(curves.points)
    points = _attribute(curves, "position", n, 3, prop="vector")
    if points is None:
        points = np.zeros((0, 3), np.float32)
    radii = _attribute(curves, "radius", n, 1)
    if radii is None:
        radii = np.full(n, CURVES_DEFAULT_RADIUS, np.float32)
    offsets = np.empty(len(curves.curves) + 1, np.int32)
    if len(curves.curves):
        curves.curve_offset_data.foreach_get("value", offsets)
    else:
        offsets[:] = 0
    types = _attribute(curves, "curve_type", len(curves.curves), 1, np.int8)
    poly = types is not None and len(types) and bool(np.all(types == POLY))
    return points, radii, offsets, 1 if poly else SUBDIVISIONS


def shape_radius(shape: float, root: float, tip: float, time: np.ndarray) -> np.ndarray:
    """The radius Cycles gives a particle-hair key at ``time`` (0 root, 1 tip, along the length)."""
    r = 1.0 - time
    if shape < 0.0:
        r = np.power(r, 1.0 + shape)
    elif shape > 0.0:
        r = np.power(r, 1.0 / (1.0 - shape))
    return r * (root - tip) + tip


def hair_systems(ob):
    """The particle systems of evaluated object ``ob`` that Cycles draws as strands."""
    out = []
    for ps in getattr(ob, "particle_systems", ()):
        s = ps.settings
        if s.type == "HAIR" and s.render_type == "PATH":
            out.append(ps)
    return out


def particle_strands(ob, ps, render: bool):
    """``(points (P, 3) in ``ob``'s space, radii, offsets)`` of particle system ``ps`` of evaluated
    object ``ob`` as Cycles exports them (``blender/curves.cpp``): the children when there are
    any (Cycles leaves the parents out then, whatever Blender's Parents display option), else the
    parents; ``2 ** steps + 1`` keys each, plus a spiral kink's extra steps; repeated keys skipped
    (zero-length segments draw nothing)."""
    s = ps.settings
    n_parents = len(ps.particles)
    n_children = len(ps.child_particles)
    if not render:
        n_children = int(n_children * s.display_percentage / 100.0)
    if s.child_type != "NONE" and n_children:
        ids = list(range(n_parents, n_parents + n_children))
    else:
        ids = list(range(n_parents))
    steps = 2 ** (s.render_step if render else s.display_step)
    if s.kink == "SPIRAL":
        steps += s.kink_extra_steps
    flat = [c for p in ids for k in range(steps + 1) for c in ps.co_hair(ob, particle_no=p, step=k)]
    world = np.array(flat, np.float64).reshape(len(ids), steps + 1, 3)
    inv = np.linalg.inv(np.array(ob.matrix_world, np.float64))
    local = world @ inv[:3, :3].T + inv[:3, 3]
    step_len = np.linalg.norm(np.diff(local, axis=1), axis=2)
    keep = np.concatenate([np.ones((len(ids), 1), bool), step_len > 0], axis=1)
    arc = np.concatenate([np.zeros((len(ids), 1)), np.cumsum(np.where(keep[:, 1:], step_len, 0.0), axis=1)], 1)
    total = arc[:, -1:]
    time = np.where(total > 0, arc / np.where(total > 0, total, 1.0), 0.0)
    scale = s.radius_scale * 0.5
    radii = shape_radius(s.shape, scale * s.root_radius, scale * s.tip_radius, time)
    if s.use_close_tip:
        last = keep.shape[1] - 1 - np.argmax(keep[:, ::-1], axis=1)
        radii[np.arange(len(ids)), last] = 0.0
    counts = keep.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    return local[keep], radii[keep], offsets


def pointcloud_points(pc):
    """``(positions (N, 3) object space, radii (N,))`` of a PointCloud data-block."""
    n = len(pc.points)
    points = _attribute(pc, "position", n, 3, prop="vector")
    if points is None:
        points = np.zeros((0, 3), np.float32)
    radii = _attribute(pc, "radius", n, 1)
    if radii is None:
        radii = np.full(n, POINTS_DEFAULT_RADIUS, np.float32)
    return points, radii


def report_tubes(label: str, n_strands: int, n_segments: int, scene) -> None:
    """Say once per object how its strands are drawn, against Cycles' curve shape (its rounded
    ribbons face each ray, as wide as round curves from every direction, but they do not shadow
    their own far side as tubes do)."""
    sides = tube_sides(n_segments)
    shape = getattr(getattr(scene, "cycles_curves", None), "shape", "THICK")
    cycles = "round 3D curves"
    if shape == "RIBBONS":
        cycles = "rounded ribbons facing each ray, which do not shadow themselves"
    warn_export(f"{label}: {n_strands} strands drawn as {sides}-sided tubes along their splines "
                f"(Cycles: {cycles})")
