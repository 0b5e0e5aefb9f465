"""Walking an evaluated depsgraph: every rendered object and instance placed as an instance of one
shared model per evaluated mesh, with its slots' materials, plus the lights.

Two paths feed the instances, and each instance goes through exactly one of them:

- ``depsgraph.object_instances`` for everything, one Python step per instance;
- geometry-nodes instances of a mesh object whose instance tree holds only meshes and objects
  are read from its evaluated :class:`bpy.types.GeometrySet` with ``foreach_get``; that object's
  duplis are then skipped in the iterator.

Blender yields the evaluated mesh of curve, text, surface and metaball objects as a separate
``MESH`` instance of the object, so only ``MESH`` instances carry geometry; ``to_mesh()`` is used
only for a non-mesh object whose evaluated geometry has no mesh component.

A ``RENDER`` depsgraph (a render engine's) holds exactly the renderable objects. A ``VIEWPORT``
depsgraph also holds objects hidden from render, dropped here (:class:`RenderVisibility`, checked
on top-level objects and instancers); objects hidden in the viewport are absent from it, and
modifiers use their viewport settings.

Each instance shows one model per used material slot (:mod:`.meshes` names them), with the
evaluated object's ``material_slots[k].material`` (object- and data-linked slots both work; a
realised geometry-nodes mesh: ``mesh.materials[k]``), the same matrix and shadow flag.
"""
from __future__ import annotations

import time

import bpy
import numpy as np

from ...core.errors import Cancelled
from ...core.scene import Instances, Scene, affine_inverse
from ...core.scene.curves import sphere_matrices, unit_sphere_model
from .camera import export_camera, render_resolution
from .common import GEOMETRY_TYPES, collect_report, to_matrices, to_matrix
from .curves import (
    TUBES,
    curves_strands,
    hair_systems,
    particle_strands,
    pointcloud_points,
    report_tubes,
    view_layer_hair,
)
from .dropped import report_dropped
from .lights import export_light, is_portal
from .linking import apply_linking
from .meshes import ModelTable, slot_name
from .ray_visibility import DEFAULT, RayVisibility
from .shading import ShadingTable
from .visibility import RenderVisibility
from .world import world_color

#: Object types drawn as tubes or sphere primitives
STRAND_TYPES = ("CURVES", "POINTCLOUD")


#: the longest stretch an export holds Python's lock between two objects (seconds)
YIELD_S = 0.002


class SceneExporter:
    """One export of a depsgraph: the instance rows found by the iterator, the vectorised
    geometry-nodes parts, the lights, and the model and shading tables they index."""

    def __init__(self, depsgraph, render_visibility: bool | None = None, should_stop=None):
        self.dg = depsgraph
        self.should_stop = should_stop  # () -> bool, asked before each row: True cancels
        self.renderable = RenderVisibility(depsgraph, render_visibility)
        self.rays = RayVisibility(depsgraph, self.renderable.check)
        self.row_flags = DEFAULT  # the RayFlags of the depsgraph row being walked
        self.use_hair = view_layer_hair(depsgraph)  # the view layer's Hair filter
        self.model_table = ModelTable()
        self.models = self.model_table.models
        self.shading = ShadingTable(self.model_table)
        # one row per instance found by the iterator
        self.names: list[str] = []
        self.model_ids: list[int] = []
        self.matrices: list = []
        self.attr_ids: list[int] = []
        self.emission: list[tuple] = []
        self.flags: list = []  # RayFlags per row
        self.parts: list[Instances] = []  # vectorised geometry-nodes instances
        self.sources: list[str] = []  # per iterated row: the object it instances (light linking)
        self.part_sources: list[str] = []  # per part: likewise
        self.lights: list = []
        self.keep: list = []  # GeometrySets own the meshes they reference: alive while exporting

    def run(self, resolution) -> Scene:
        scene = self.dg.scene_eval
        with collect_report() as report:
            self._walk()
            instances = Instances.concatenate([self._iterated_instances()] + self.parts)
            apply_linking(self.lights, instances, self.sources + [
                name for part, name in zip(self.parts, self.part_sources) if len(part) for _ in range(len(part))])
            camera = export_camera(self.dg)
            world = world_color(scene.world)
        result = Scene(name=scene.name, models=self.models, instances=instances,
                       lights=self.lights, camera=camera, world_color=world,
                       resolution=render_resolution(scene) if resolution is None else resolution,
                       frame=scene.frame_current, materials=self.shading.materials,
                       images=self.shading.images, report=report)
        return result.check_transforms()

    def _walk(self) -> None:
        vectorised = set()  # evaluated instancers whose instances came from their GeometrySet
        iterated = set()  # evaluated instancers with duplis taken from the iterator
        last = time.perf_counter()
        for inst in self.dg.object_instances:
            if self.should_stop is not None and self.should_stop():
                raise Cancelled()
            if time.perf_counter() - last > YIELD_S:  # (an export off the main thread lets it run)
                time.sleep(0)
                last = time.perf_counter()
            if inst.is_instance:
                parent = inst.parent
                pptr = parent.as_pointer()
                if pptr in vectorised and inst.object.type not in STRAND_TYPES:
                    continue  # strands and points are components the GeometrySet path leaves
                iterated.add(pptr)
                ob = inst.object
                if not self.renderable(parent.original):
                    continue
                name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
                self.row_flags = self.rays.flags(ob, parent)
            else:
                ob = inst.object
                if not self.renderable(ob.original):
                    continue
                name = ob.name
                self.row_flags = self.rays.flags(ob)
                for ps in hair_systems(ob):
                    self._add_hair(ob, ps, inst.matrix_world, name)
                if (ob.type == "MESH" and ob.as_pointer() not in iterated
                        and any(m.type == "NODES" for m in ob.modifiers)
                        and self._vectorise(ob)):
                    vectorised.add(ob.as_pointer())
                if ob.type != "LIGHT" and not self.rays.shows_self(inst):
                    continue  # an emitter or instancer with Show Instancer off: its instances only
                self.row_flags = self.rays.flags(ob)
            kind = ob.type
            if kind == "MESH":
                self._add_mesh_instance(ob, ob.data, ob.data.as_pointer(), inst.matrix_world, name)
            elif kind == "LIGHT" and not is_portal(ob):
                self.lights.append(export_light(ob, to_matrix(inst.matrix_world), name))
            elif kind == "CURVES":
                self._add_curves(ob, inst.matrix_world, name)
            elif kind == "POINTCLOUD":
                self._add_points(ob, inst.matrix_world, name)
            elif kind in GEOMETRY_TYPES and bpy.types.GeometrySet.from_evaluated_object(ob).mesh is None:
                self._add_converted_instance(ob, inst.matrix_world, name)
            report_dropped(ob, name, inst.is_instance)

    # -- instances found by the iterator ------------------------------------------------------
    @staticmethod
    def _slot_material(slots, k: int):
        """The material of slot ``k`` (a ``material_slots`` or ``materials`` collection), None
        without slots."""
        if not len(slots):
            return None
        m = slots[k]
        return m.material if isinstance(m, bpy.types.MaterialSlot) else m

    @staticmethod
    def _model_name(ob, mesh) -> str:
        """The mesh's name, or the object's when the mesh is a modifier or conversion result."""
        return mesh.name if mesh.name == getattr(ob.original.data, "name", None) else ob.original.name

    def _add_mesh_instance(self, ob, mesh, key, matrix, name) -> None:
        slots = ob.material_slots
        models = self.model_table.slot_models(key, mesh, self._model_name(ob, mesh), len(slots))
        if models:
            self._add_rows(ob, slots, models, matrix.copy(), name, mesh)

    def _add_rows(self, ob, slots, models, matrix, name, mesh) -> None:
        """One iterated instance per ``(slot, model id)`` of ``models`` (named as :mod:`.meshes`
        says), each with its slot's material; ``mesh``: where UVs are read (None: they are read
        already)."""
        for j, (k, mid) in enumerate(models):
            self.names.append(name if j == 0 else slot_name(name, k))
            self.sources.append(ob.original.name)
            self.model_ids.append(mid)
            self.matrices.append(matrix)
            material = self._slot_material(slots, k)
            aid = self.shading.attributes(ob, material)
            self.attr_ids.append(self.shading.checked(aid, mid, mesh, name))
            self.emission.append(self.shading.emission(ob, material))
            self.flags.append(self.row_flags)

    def _add_converted_instance(self, ob, matrix, name) -> None:
        """A non-mesh object without a mesh component: its ``to_mesh()`` triangles, if any."""
        key = ("to_mesh", ob.original.as_pointer())
        slots = ob.material_slots
        models = self.model_table.models_of.get(key)
        if models is None or any(
                self.shading.needs_uvs(self.shading.attributes(ob, self._slot_material(slots, k)), mid)
                for k, mid in models):
            mesh = ob.to_mesh()
            try:
                models = self.model_table.slot_models(key, mesh, ob.original.name, len(slots))
                self._add_rows(ob, slots, models, matrix.copy(), name, mesh)
            finally:
                ob.to_mesh_clear()
        else:  # UVs already read (or found missing)
            self._add_rows(ob, slots, models, matrix.copy(), name, None)

    # -- strands and points -------------------------------------------------------------------
    def _tube_rows(self, ob, key, label: str, strands, material_index: int, matrix, name) -> None:
        """One iterated row of the tube model of ``strands`` (``(points, radii, offsets,
        subdivisions)``, read once per ``key``) with material slot ``material_index``; the model
        comes from :data:`.curves.TUBES` when these strands were exported before."""
        models = self.model_table.models_of.get(key)
        if models is None:
            points, radii, offsets, sub = strands()
            model = TUBES.model(key, label, points, radii, offsets, sub)
            models = []
            if model is not None:
                report_tubes(label, len(offsets) - 1, (len(points) - len(offsets) + 1) * sub, self.dg.scene_eval)
                models = [(material_index, len(self.models))]
                self.models.append(model)
            self.model_table.models_of[key] = models
        if models:
            self._add_rows(ob, ob.material_slots, models, matrix.copy(), name, None)

    def _add_curves(self, ob, matrix, name) -> None:
        """A Curves object (or instance): its strands as one tube model (none when the view
        layer's Hair filter is off)."""
        if not self.use_hair:
            return
        self._tube_rows(ob, ("curves", ob.data.as_pointer()), f"Curves object '{ob.original.name}'",
                        lambda: curves_strands(ob.data), 0, matrix, name)

    def _add_hair(self, ob, ps, matrix, name) -> None:
        """Particle hair ``ps`` of evaluated object ``ob``: its strands as one tube model (none
        when the view layer's Hair filter is off)."""
        if not self.use_hair:
            return
        render = self.dg.mode == "RENDER"
        for m in ob.modifiers:
            if m.type == "PARTICLE_SYSTEM" and m.particle_system.name == ps.name:
                if not (m.show_render if render else m.show_viewport):
                    return
        slot = max(ps.settings.material - 1, 0)
        if slot >= len(ob.material_slots):
            slot = 0
        self._tube_rows(ob, ("hair", ob.original.as_pointer(), ps.name),
                        f"particle hair '{ps.name}' of object '{ob.original.name}'",
                        lambda: particle_strands(ob, ps, render) + (2,), slot, matrix, f"{name}/{ps.name}")

    def _add_points(self, ob, matrix, name) -> None:
        """A point cloud: one sphere primitive of a shared unit model per point."""
        positions, radii = pointcloud_points(ob.data)
        n = len(positions)
        if not n:
            return
        key = "unit sphere"
        if key not in self.model_table.models_of:
            self.model_table.models_of[key] = [(0, len(self.models))]
            self.models.append(unit_sphere_model())
        mid = self.model_table.models_of[key][0][1]
        material = self._slot_material(ob.material_slots, 0)
        aid = self.shading.checked(self.shading.attributes(ob, material), mid, None, name)
        shadow, _, rgba, spec, rough, material_id, _, terminator = self.shading.attrs[aid]
        matrices = sphere_matrices(to_matrix(matrix), positions, radii)
        rays = self.row_flags
        self.part_sources.append(ob.original.name)
        self.parts.append(Instances(
            names=[f"{name}[{i}]" for i in range(n)], model_ids=np.full(n, mid, np.int32),
            matrices=matrices, inverse=affine_inverse(matrices),
            casts_shadow=np.full(n, shadow and rays.shadow), sphere=np.ones(n, bool),
            base_color=np.tile(np.float32(rgba), (n, 1)), specular=np.full(n, spec, np.float32),
            roughness=np.full(n, rough, np.float32), material_ids=np.full(n, material_id, np.int32),
            terminator=np.full(n, terminator, np.float32),
            emission=np.tile(np.float32(self.shading.emission(ob, material)), (n, 1)),
            visible_camera=np.full(n, rays.camera), holdout=np.full(n, rays.holdout)))

    def _iterated_instances(self) -> Instances:
        if not self.names:
            return Instances()
        attrs = [self.shading.attrs[i] for i in self.attr_ids]
        flags = self.flags
        return Instances(
            names=self.names,
            model_ids=np.array(self.model_ids, np.int32),
            matrices=(m := to_matrices(self.matrices)),
            inverse=affine_inverse(m),
            casts_shadow=np.array([a[0] and f.shadow for a, f in zip(attrs, flags)], bool),
            sphere=np.array([a[1] for a in attrs], bool),
            base_color=np.array([a[2] for a in attrs], np.float32),
            specular=np.array([a[3] for a in attrs], np.float32),
            roughness=np.array([a[4] for a in attrs], np.float32),
            material_ids=np.array([a[5] for a in attrs], np.int32),
            terminator=np.array([a[7] for a in attrs], np.float32),
            emission=np.array(self.emission, np.float32).reshape(-1, 3),
            visible_camera=np.array([f.camera for f in flags], bool),
            holdout=np.array([f.holdout for f in flags], bool),
        )

    # -- geometry-nodes instances, vectorised -------------------------------------------------
    def _vectorise(self, ob) -> bool:
        """Read the geometry-nodes instances of mesh object ``ob`` from its GeometrySet into
        ``self.parts``. False (nothing added) when its instance tree holds anything but meshes
        and plain mesh objects (collections, curves, ...): the iterator then takes them."""
        groups = flatten_instances(bpy.types.GeometrySet.from_evaluated_object(ob), self.dg, self.keep)
        if groups is None:
            return False
        world = to_matrix(ob.matrix_world)
        for source, mesh, label, local, index in groups:
            matrices = np.matmul(world, local)
            inverse = None
            prefix = f"{ob.name}/{label}"
            if source is None:  # realised geometry made by ob's node tree
                owner, slots = ob, mesh.materials
                models = self.model_table.slot_models(mesh.as_pointer(), mesh, prefix, len(slots))
            else:  # an object instanced as a whole
                owner, slots = source, source.material_slots
                models = self.model_table.slot_models(mesh.as_pointer(), mesh, self._model_name(source, mesh),
                                                      len(slots))
            n = len(index)
            rays = self.rays.flags(ob) if source is None else self.rays.flags(source, ob)
            for j, (k, mid) in enumerate(models):
                aid = self.shading.attributes(owner, self._slot_material(slots, k))
                aid = self.shading.checked(aid, mid, mesh, source.name if source is not None else prefix)
                shadow, sphere, rgba, spec, rough, material_id, _, terminator = self.shading.attrs[aid]
                if inverse is None:
                    inverse = affine_inverse(matrices)
                suffix = "" if j == 0 else slot_name("", k)
                self.part_sources.append((source if source is not None else ob).original.name)
                self.parts.append(Instances(
                    names=[f"{prefix}[{i}]{suffix}" for i in index.tolist()],
                    model_ids=np.full(n, mid, np.int32),
                    matrices=matrices,
                    inverse=inverse,
                    casts_shadow=np.full(n, shadow and rays.shadow),
                    sphere=np.full(n, sphere),
                    base_color=np.tile(np.float32(rgba), (n, 1)),
                    specular=np.full(n, spec, np.float32),
                    roughness=np.full(n, rough, np.float32),
                    material_ids=np.full(n, material_id, np.int32),
                    terminator=np.full(n, terminator, np.float32),
                    emission=np.tile(np.float32(self.shading.emission(owner, self._slot_material(slots, k))), (n, 1)),
                    visible_camera=np.full(n, rays.camera),
                    holdout=np.full(n, rays.holdout),
                ))
        return True


def flatten_instances(gs, depsgraph, keep: list):
    """The instances of a GeometrySet, flattened: a list of ``(source_object or None, mesh,
    label, local matrices (k, 4, 4), top-level instance indices (k,))``, or None when the tree
    holds something this path does not read (collections, non-mesh objects, instances of
    objects that have instances themselves). The GeometrySets owning the meshes go to ``keep``."""
    keep.append(gs)
    pc = gs.instances_pointcloud()
    if pc is None:
        return []
    attrs = pc.attributes
    if "instance_transform" not in attrs or ".reference_index" not in attrs:
        return None
    n = len(pc.points)
    raw = np.empty(n * 16, np.float32)
    attrs["instance_transform"].data.foreach_get("value", raw)
    local = raw.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)  # stored column-major
    ref = np.empty(n, np.int32)
    attrs[".reference_index"].data.foreach_get("value", ref)
    refs = gs.instance_references()
    order = np.argsort(ref, kind="stable")
    bounds = np.searchsorted(ref[order], np.arange(len(refs) + 1))
    out = []
    for k, r in enumerate(refs):
        index = order[bounds[k]:bounds[k + 1]]
        if not len(index) or r is None:
            continue
        m = local[index]
        if isinstance(r, bpy.types.Object):
            ob = r if r.is_evaluated else r.evaluated_get(depsgraph)
            if ob.type != "MESH" or bpy.types.GeometrySet.from_evaluated_object(ob).instances_pointcloud() is not None:
                return None
            out.append((ob, ob.data, ob.name, m, index))
        elif isinstance(r, bpy.types.GeometrySet):
            if r.curves is not None or r.pointcloud is not None or r.volume is not None or r.grease_pencil is not None:
                return None
            if r.mesh is not None:
                out.append((None, r.mesh, r.name or r.mesh.name, m, index))
            sub = flatten_instances(r, depsgraph, keep)
            if sub is None:
                return None
            for source, mesh, label, sub_m, _ in sub:
                placed = np.matmul(m[:, None], sub_m[None]).reshape(-1, 4, 4)
                out.append((source, mesh, label, placed, np.repeat(index, len(sub_m))))
        else:
            return None
    return out
