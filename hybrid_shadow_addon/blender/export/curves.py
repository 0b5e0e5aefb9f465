"""Reading strands and points from Blender as Cycles reads them: Curves data (``position``,
``radius``, curve offsets), particle hair (the evaluated paths ``ParticleSystem.co_hair`` gives,
with the particle settings' root/tip radius and shape) and point clouds (``position``,
``radius``). Strands become tubes and points sphere primitives (:mod:`...core.scene.curves`)."""
from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

from ...core.scene.curves import tube_model, tube_sides
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


def _points_and_radii(data, default_radius: float):
    """``(positions (N, 3), radii (N,))`` of the points of a Curves or PointCloud data-block,
    ``default_radius`` where it has no ``radius`` attribute (as Cycles does)."""
    n = len(data.points)
    points = _attribute(data, "position", n, 3, prop="vector")
    if points is None:
        points = np.zeros((0, 3), np.float32)
    radii = _attribute(data, "radius", n, 1)
    if radii is None:
        radii = np.full(n, default_radius, np.float32)
    return points, radii


def curves_strands(curves):
    """``(points (P, 3) object space, radii (P,), offsets (C + 1,), subdivisions)`` of a Curves
    data-block; poly curves are straight between their points, others follow the spline."""
    points, radii = _points_and_radii(curves, CURVES_DEFAULT_RADIUS)
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


def view_layer_hair(depsgraph) -> bool:
    """Whether the depsgraph's view layer renders strands: its Hair filter (``use_strand``),
    without which Cycles draws neither particle hair nor Curves objects (point clouds stay)."""
    return bool(getattr(getattr(depsgraph, "view_layer", None), "use_strand", True))


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
    return _points_and_radii(pc, POINTS_DEFAULT_RADIUS)


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


def strands_digest(label: str, points, radii, offsets, subdivisions: int) -> bytes:
    """A digest of everything a tube model is built from (its name, the strands' points, radii,
    offsets and spline subdivisions)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{label}\0{subdivisions}".encode())
    for a in (points, radii, offsets):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data)
    return h.digest()


def _model_bytes(model) -> int:
    if model is None:
        return 0
    return sum(a.nbytes for a in (model.vertices, model.triangles, model.normals, model.uvs) if a is not None)


class TubeCache:
    """The tube models of the strand sets exported last, so that re-exporting unchanged strands
    (the viewport re-exports on unrelated changes) does not rebuild them. One entry per strand
    source (``key``): the digest of its strands and its model, rebuilt when the digest differs;
    the least recently used sources go first past ``max_entries`` or ``max_bytes``."""

    def __init__(self, max_entries: int = 8, max_bytes: int = 1 << 30):
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self.entries: OrderedDict = OrderedDict()  # key -> (digest, model or None, bytes)
        self.builds = 0  # models built (misses), for the tests

    def model(self, key, label: str, points, radii, offsets, subdivisions: int):
        """The tube model of these strands (None: no strand has a segment), built or cached."""
        digest = strands_digest(label, points, radii, offsets, subdivisions)
        entry = self.entries.get(key)
        if entry is not None and entry[0] == digest:
            self.entries.move_to_end(key)
            return entry[1]
        model = tube_model(label, points, radii, offsets, subdivisions=subdivisions)
        self.builds += 1
        self.entries[key] = (digest, model, _model_bytes(model))
        self.entries.move_to_end(key)
        while len(self.entries) > 1 and (len(self.entries) > self.max_entries or sum(
                e[2] for e in self.entries.values()) > self.max_bytes):
            self.entries.popitem(last=False)
        return model

    def clear(self) -> None:
        self.entries.clear()


#: the export's tube models, kept across exports (cleared when another file is loaded)
TUBES = TubeCache()
