"""Curves and point clouds as the scene model draws them: strands (points, a radius per point,
offsets into the points per strand) become one tube mesh per object; points become sphere
primitives of one unit model.

Cycles renders strands as round "3D curves": the sweep of a disc whose radius is interpolated
along a Catmull-Rom spline through the points. Here each strand is sampled along the same spline
(:func:`catmull_rom`) and swept as a prism of ``sides`` sides whose circumradius is widened so
that its mean silhouette width over all viewing directions equals the curve's diameter
(:func:`prism_scale`); the ends are closed flat.
"""
from __future__ import annotations

import numpy as np

from .models import Model

#: sides of the tube's cross-section for small and large strand counts (odd sides: the
#: silhouette width varies least with the direction: 5 sides within 2.5%, 3 within 8%)
SIDES = 5
SIDES_LARGE = 3
#: segments above which an object's tubes take ``SIDES_LARGE`` sides
LARGE_SEGMENTS = 400_000


def tube_sides(segments: int) -> int:
    """Sides of the tubes of an object with this many spline-sampled segments."""
    return SIDES if segments <= LARGE_SEGMENTS else SIDES_LARGE


def prism_scale(sides: int) -> float:
    """Circumradius of a regular ``sides``-gon whose mean width over all directions is 2 (the
    mean width of a convex polygon is its perimeter over pi)."""
    return float(np.pi / (sides * np.sin(np.pi / sides)))


def strand_ids(offsets: np.ndarray) -> np.ndarray:
    """Per point, the index of its strand."""
    counts = np.diff(offsets)
    return np.repeat(np.arange(len(counts)), counts)


def catmull_rom(points: np.ndarray, radii: np.ndarray, offsets: np.ndarray, subdivisions: int):
    """Sample each strand's uniform Catmull-Rom spline (end points repeated, as Cycles does)
    ``subdivisions`` times per segment: ``(points, radii, offsets)`` of the sampled strands.
    Radii follow the same spline, clamped at 0."""
    offsets = np.asarray(offsets, np.int64)
    counts = np.diff(offsets)
    if subdivisions <= 1 or not len(points):
        return points, radii, offsets
    data = np.concatenate([points, radii[:, None]], axis=1).astype(np.float64)
    sid = strand_ids(offsets)
    last = offsets[1:] - 1
    seg = np.flatnonzero(np.arange(len(points)) < last[sid])  # segment i: point i to i + 1
    s_sid = sid[seg]
    k0 = np.maximum(seg - 1, offsets[:-1][s_sid])
    k3 = np.minimum(seg + 2, last[s_sid])
    t = (np.arange(subdivisions) / subdivisions)[None, :, None]
    p0, p1, p2, p3 = (data[k][:, None] for k in (k0, seg, seg + 1, k3))
    t2, t3 = t * t, t * t * t
    sampled = 0.5 * ((2 * p1) + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t2
                     + (3 * p1 - p0 - 3 * p2 + p3) * t3)  # (S, sub, 4)
    new_counts = np.maximum(counts - 1, 0) * subdivisions + (counts > 0)
    new_offsets = np.concatenate([[0], np.cumsum(new_counts)])
    out = np.empty((new_offsets[-1], 4))
    strand_start = new_offsets[:-1][s_sid] + (seg - offsets[:-1][s_sid]) * subdivisions
    out[(strand_start[:, None] + np.arange(subdivisions)).ravel()] = sampled.reshape(-1, 4)
    ends = counts > 0
    out[new_offsets[1:][ends] - 1] = data[last[ends]]
    return out[:, :3], np.maximum(out[:, 3], 0.0), new_offsets


def _frames(points: np.ndarray, offsets: np.ndarray):
    """Per point: unit tangent and two unit normals, with one reference axis per strand so the
    cross-sections do not twist between points."""
    sid = strand_ids(offsets)
    first, last = offsets[:-1][sid], offsets[1:][sid] - 1
    i = np.arange(len(points))
    tangent = points[np.minimum(i + 1, last)] - points[np.maximum(i - 1, first)]
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.where(length > 0, tangent / np.maximum(length, 1e-30), (0.0, 0.0, 1.0))
    chord = points[offsets[1:] - 1] - points[offsets[:-1]]
    axis = np.argmin(np.abs(chord), axis=1)
    ref = np.eye(3)[axis][sid]
    n = ref - np.sum(ref * tangent, axis=1, keepdims=True) * tangent
    nl = np.linalg.norm(n, axis=1, keepdims=True)
    fallback = np.eye(3)[np.argmin(np.abs(tangent), axis=1)]
    fallback = fallback - np.sum(fallback * tangent, 1, keepdims=True) * tangent
    n = np.where(nl > 1e-6, n / np.maximum(nl, 1e-30), fallback)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return tangent, n, np.cross(tangent, n)


def tube_model(name: str, points, radii, offsets, sides: int | None = None, subdivisions: int = 1) -> Model | None:
    """One model of the tubes around every strand (``points`` (P, 3), ``radii`` (P,),
    ``offsets`` (C + 1,)), each sampled ``subdivisions`` times per segment along its Catmull-Rom
    spline; None when no strand has a segment. ``sides`` None: :data:`SIDES`, or
    :data:`SIDES_LARGE` past :data:`LARGE_SEGMENTS` segments."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    radii = np.asarray(radii, np.float64).reshape(-1)
    offsets = np.asarray(offsets, np.int64).reshape(-1)
    counts = np.diff(offsets)
    keep = counts >= 2
    if not keep.any():
        return None
    if not keep.all():  # drop strands of fewer than two points
        idx = np.concatenate([np.arange(offsets[c], offsets[c + 1]) for c in np.flatnonzero(keep)])
        points, radii = points[idx], radii[idx]
        offsets = np.concatenate([[0], np.cumsum(counts[keep])])
    points, radii, offsets = catmull_rom(points, radii, offsets, subdivisions)
    if sides is None:
        sides = tube_sides(len(points) - (len(offsets) - 1))
    _, n, b = _frames(points, offsets)
    a = 2 * np.pi * np.arange(sides) / sides
    radial = np.cos(a)[None, :, None] * n[:, None] + np.sin(a)[None, :, None] * b[:, None]  # (P, S, 3)
    ring = points[:, None] + radial * (radii * prism_scale(sides))[:, None, None]
    n_pts = len(points)
    caps = np.concatenate([points[offsets[:-1]], points[offsets[1:] - 1]])  # centre of each end
    verts = np.concatenate([ring.reshape(-1, 3), caps])
    normals_v = np.concatenate([radial.reshape(-1, 3), np.zeros((len(caps), 3))])
    sid = strand_ids(offsets)
    seg = np.flatnonzero(np.arange(n_pts) < (offsets[1:] - 1)[sid])
    j = np.arange(sides)
    j1 = (j + 1) % sides
    a0 = seg[:, None] * sides + j
    a1 = seg[:, None] * sides + j1
    b0, b1 = a0 + sides, a1 + sides
    quads = np.stack([np.stack([a0, a1, b1], -1), np.stack([a0, b1, b0], -1)], axis=2).reshape(-1, 3)
    n_strands = len(offsets) - 1
    root_c = n_pts * sides + np.arange(n_strands)
    tip_c = root_c + n_strands
    root = offsets[:-1, None] * sides
    tip = (offsets[1:, None] - 1) * sides
    cap_tris = np.concatenate([
        np.stack([np.broadcast_to(root_c[:, None], (n_strands, sides)), root + j1, root + j], -1).reshape(-1, 3),
        np.stack([np.broadcast_to(tip_c[:, None], (n_strands, sides)), tip + j, tip + j1], -1).reshape(-1, 3),
    ])
    tris = np.concatenate([quads, cap_tris]).astype(np.uint32)
    corner_n = normals_v[tris]
    cap_rows = slice(len(quads), None)
    c0, c1, c2 = (verts[tris[cap_rows, k]] for k in range(3))
    fn = np.cross(c1 - c0, c2 - c0)
    fl = np.linalg.norm(fn, axis=1, keepdims=True)
    corner_n[cap_rows] = (fn / np.maximum(fl, 1e-30))[:, None]
    return Model(name=name, vertices=verts, triangles=tris, normals=corner_n)


def unit_sphere_model(name: str = "point-cloud sphere", segments: int = 12, rings: int = 6) -> Model:
    """A UV sphere of radius 1 around the origin: the model of sphere-primitive points (they are
    traced as its bounding sphere, radius 1)."""
    th = np.pi * np.arange(1, rings) / rings
    ph = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                     np.broadcast_to(np.cos(th)[:, None], (rings - 1, segments))], -1).reshape(-1, 3)
    verts = np.concatenate([ring, [(0, 0, 1), (0, 0, -1)]])
    top, bottom = len(ring), len(ring) + 1
    j = np.arange(segments)
    j1 = (j + 1) % segments
    tris = [np.stack([np.full(segments, top), j, j1], -1)]
    for r in range(rings - 2):
        a, b = r * segments, (r + 1) * segments
        tris += [np.stack([a + j, b + j, b + j1], -1), np.stack([a + j, b + j1, a + j1], -1)]
    last = (rings - 2) * segments
    tris.append(np.stack([np.full(segments, bottom), last + j1, last + j], -1))
    return Model(name=name, vertices=verts, triangles=np.concatenate(tris),
                 bounds_min=np.full(3, -1.0), bounds_max=np.full(3, 1.0),
                 sphere_center=np.zeros(3), sphere_radius=1.0)


def sphere_matrices(world: np.ndarray, positions, radii) -> np.ndarray:
    """World matrices (N, 4, 4) placing the unit sphere at each point (object space) of an
    object with matrix ``world``, scaled by the point's radius."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    local = np.zeros((len(positions), 4, 4))
    local[:, 0, 0] = local[:, 1, 1] = local[:, 2, 2] = np.asarray(radii, np.float64).reshape(-1)
    local[:, :3, 3] = positions
    local[:, 3, 3] = 1.0
    return np.matmul(world, local)
