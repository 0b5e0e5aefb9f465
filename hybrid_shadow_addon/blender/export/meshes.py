"""Evaluated meshes as models: vertex and triangle arrays, corner normals and UVs read with
``foreach_get``, and the split of a mesh by material slot.

A mesh whose loop triangles use one slot (``material_index``, clamped to the slots as Blender
renders) is one model. A mesh whose triangles use several slots becomes one model per used slot
(that slot's triangles, their own vertices, normals and, for a textured material, UVs). Names,
stable from frame to frame since the scene sync and the viewport match instances by name:

- instances: the lowest used slot keeps the instance's name (``"Tree"``, ``"Forest/Tree[12]"``),
  every other used slot ``k`` is ``"<name> [slot k]"`` (``"Tree [slot 1]"``,
  ``"Forest/Tree[12] [slot 1]"``); :func:`slot_owner` strips it;
- models: a mesh split by slot is ``"<mesh> [slot k]"`` for every used slot ``k``, 0 included;
  an unsplit mesh keeps the mesh's name, unless the one slot its triangles use is not slot 0
  (``"<mesh> [slot k]"`` again). A model named without the suffix thus always shows slot 0,
  which the viewport's single-model rebuild relies on.
"""
from __future__ import annotations

import numpy as np

from ...core.scene import Model

_SLOT_SUFFIX = " [slot "


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float32 and loop triangles (T, 3) uint32 of a mesh, via ``foreach_get``:
    the triangles' corners mapped through the mesh's corner-to-vertex attribute where it has one
    (one raw read; the triangles' own ``vertices`` are read item by item, a long call that holds
    Python's lock)."""
    verts = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", verts)
    corner_vert = _corner_verts(mesh)
    if corner_vert is not None:
        tris = corner_vert[_triangle_loops(mesh)]
    else:
        tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
    return verts.reshape(-1, 3), tris.view(np.uint32).reshape(-1, 3)


def _corner_verts(mesh) -> np.ndarray | None:
    """(L,) vertex of each face corner from the mesh's ``.corner_vert`` attribute (Blender 4 and
    later), None without it."""
    attr = mesh.attributes.get(".corner_vert") if hasattr(mesh, "attributes") else None
    if attr is None or attr.domain != "CORNER" or attr.data_type != "INT" or len(attr.data) != len(mesh.loops):
        return None
    out = np.empty(len(mesh.loops), np.int32)
    attr.data.foreach_get("value", out)
    return out


def _triangle_loops(mesh) -> np.ndarray:
    """(T * 3,) loop index of each loop triangle's corners."""
    loops = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return loops


def smooth_normals(mesh) -> np.ndarray | None:
    """(T, 3, 3) float32 shading normals of each loop triangle's corners (Blender's corner
    normals: smooth faces, sharp edges and custom normals included), or None when every face is
    flat (the face normals then suffice)."""
    n_poly = len(mesh.polygons)
    if not n_poly or not len(mesh.loop_triangles):
        return None
    smooth = np.empty(n_poly, bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    if not smooth.any():
        return None
    corner = np.empty(len(mesh.loops) * 3, np.float32)
    mesh.corner_normals.foreach_get("vector", corner)
    return corner.reshape(-1, 3)[_triangle_loops(mesh)].reshape(-1, 3, 3)


def mesh_uv_layer(mesh, name: str = ""):
    """The UV layer named ``name``, or ("") the active render one (else the active, else the
    first); None when the mesh has no such layer."""
    layers = mesh.uv_layers
    if not len(layers):
        return None
    if name:
        return layers.get(name)
    return next((layer for layer in layers if layer.active_render), None) or layers.active or layers[0]


def mesh_uvs(mesh, layer) -> np.ndarray:
    """(T, 3, 2) float32 UVs of each loop triangle's corners from ``layer``, via ``foreach_get``."""
    buf = np.empty(len(mesh.loops) * 2, np.float32)
    if hasattr(layer, "uv"):
        layer.uv.foreach_get("vector", buf)
    else:
        layer.data.foreach_get("uv", buf)
    return buf.reshape(-1, 2)[_triangle_loops(mesh)].reshape(-1, 3, 2)


def slot_name(name: str, slot: int) -> str:
    """The name of the instance or model holding slot ``slot`` of ``name``'s mesh."""
    return f"{name}{_SLOT_SUFFIX}{slot}]"


def slot_owner(name: str) -> str:
    """The instance name without a ``" [slot k]"`` suffix (:func:`slot_name`'s inverse)."""
    i = name.rfind(_SLOT_SUFFIX)
    if i >= 0 and name.endswith("]") and name[i + len(_SLOT_SUFFIX):-1].isdigit():
        return name[:i]
    return name


def slot_triangles(mesh, n_slots: int) -> list | None:
    """``[(slot, loop triangle indices)]`` of a mesh with ``n_slots`` material slots: its
    triangles grouped by ``material_index`` (clamped to ``[0, n_slots - 1]``, as Blender renders
    an out-of-range index), one entry per used slot, ascending. None when there are fewer than
    two slots (every triangle shows slot 0) or no triangles."""
    n = len(mesh.loop_triangles)
    if n_slots < 2 or not n:
        return None
    index = np.empty(n, np.int32)
    mesh.loop_triangles.foreach_get("material_index", index)
    np.clip(index, 0, n_slots - 1, out=index)
    counts = np.bincount(index, minlength=n_slots)
    used = np.flatnonzero(counts)
    if len(used) == 1:
        return [(int(used[0]), None)]
    order = np.argsort(index, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    return [(int(k), order[bounds[k]:bounds[k + 1]]) for k in used]


def used_slots(mesh, n_slots: int) -> list:
    """The material slots a mesh's triangles use (``[0]`` with fewer than two slots)."""
    groups = slot_triangles(mesh, n_slots)
    return [0] if groups is None else [k for k, _ in groups]


def _slot_model(label: str, verts: np.ndarray, tris: np.ndarray, normals, idx: np.ndarray) -> Model:
    """The model of the loop triangles ``idx`` of a mesh, with only the vertices they use."""
    sub = tris[idx]
    keep = np.zeros(len(verts), bool)
    keep[sub] = True
    remap = np.cumsum(keep, dtype=np.int64) - 1
    return Model(name=label, vertices=verts[keep], triangles=remap[sub].astype(np.uint32),
                 normals=None if normals is None else normals[idx])


class ModelTable:
    """The models of one export, each geometry read once: ``models`` in order of first use,
    ``models_of`` a geometry key -> ``[(material slot, model id)]`` (one model per used slot,
    [] without triangles), ``model_tris`` a slot model's id -> the mesh's loop triangles it holds."""

    def __init__(self):
        self.models: list[Model] = []
        self.models_of: dict = {}
        self.model_tris: dict = {}

    def slot_models(self, key, mesh, name: str, n_slots: int) -> list:
        """``[(slot, model id)]`` of the geometry ``key`` (read from ``mesh`` the first time): one
        model named ``name`` when its triangles use one of its ``n_slots`` slots, else one per
        used slot (:func:`slot_triangles`) with the vertices its triangles use; [] without
        triangles. Model names: see the module docstring."""
        got = self.models_of.get(key)
        if got is not None:
            return got
        verts, tris = mesh_arrays(mesh)
        got = []
        if len(tris):
            normals = smooth_normals(mesh)
            groups = slot_triangles(mesh, n_slots) or [(0, None)]
            for k, idx in groups:
                label = name if k == 0 and idx is None else slot_name(name, k)
                if idx is None:
                    model = Model(name=label, vertices=verts, triangles=tris, normals=normals)
                else:
                    model = _slot_model(label, verts, tris, normals, idx)
                    self.model_tris[len(self.models)] = idx
                got.append((k, len(self.models)))
                self.models.append(model)
        self.models_of[key] = got
        return got
