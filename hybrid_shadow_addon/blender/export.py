"""Export an evaluated depsgraph to the bpy-free scene model.

:func:`export_depsgraph` reads what Blender renders: modifiers applied, every instance (linked
duplicates, collection instances, particles, geometry-nodes instances) placed as an instance of
one shared :class:`~hybrid_shadow_addon.core.scene.Model` per evaluated mesh datablock.

Two paths feed the instances, and each instance goes through exactly one of them:

- ``depsgraph.object_instances`` for everything, one Python step per instance;
- geometry-nodes instances of a mesh object whose instance tree holds only meshes and objects
  are read from its evaluated :class:`bpy.types.GeometrySet` with ``foreach_get`` (100k
  instances in milliseconds); that object's duplis are then skipped in the iterator.

Blender 4.5 yields the evaluated mesh of curve, text, surface and metaball objects as a separate
``MESH`` instance of the object, so only ``MESH`` instances carry geometry; ``to_mesh()`` is used
only for a non-mesh object whose evaluated geometry has no mesh component.

A ``RENDER`` depsgraph (a render engine's) already holds exactly the renderable objects. A
``VIEWPORT`` depsgraph (``Context.evaluated_depsgraph_get()``) also holds objects hidden from
render; they are dropped here (``hide_render`` of the object or of all its collections, checked
on top-level objects and instancers), but objects hidden in the viewport are simply absent from
it, and modifiers use their viewport settings.
"""
from __future__ import annotations

import itertools

import bpy
import numpy as np

from ..core.errors import SceneError
from ..core.scene import Camera, Instances, Light, Model, Scene, affine_inverse

#: Object types whose evaluated geometry can be a mesh.
GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
#: Custom object property marking an analytic sphere primitive.
SPHERE_PROPERTY = "hybrid_sphere"

_GREY = (0.8, 0.8, 0.8, 1.0)
_WHITE = (1.0, 1.0, 1.0, 1.0)


def export_depsgraph(depsgraph, *, resolution=None, render_visibility: bool | None = None) -> Scene:
    """The scene of an evaluated depsgraph at its current frame.

    ``render_visibility``: drop what is hidden from render (default: for a viewport depsgraph,
    so that it exports what F12 renders); False keeps what the viewport shows, as Cycles' and
    EEVEE's rendered viewports do.

    ``resolution``: ``(width, height)`` overriding the render settings (default: resolution x/y
    times the percentage). Raises :class:`SceneError` naming the object for a NaN or infinite
    transform (``Scene.check_transforms``); the remaining checks are ``Scene.validate``'s.
    """
    return _Exporter(depsgraph, render_visibility).run(resolution)


# --------------------------------------------------------------------------------------------
# Helpers reading bpy data
# --------------------------------------------------------------------------------------------
def _matrix(m) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 numpy array (rows as in Blender)."""
    return np.array([tuple(row) for row in m], np.float64)


def _matrices(ms: list) -> np.ndarray:
    """A list of mathutils 4x4 matrices as an (N, 4, 4) float64 array."""
    flat = itertools.chain.from_iterable(itertools.chain.from_iterable(ms))
    return np.fromiter(flat, np.float64, count=16 * len(ms)).reshape(-1, 4, 4)


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
    loops = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return corner.reshape(-1, 3)[loops].reshape(-1, 3, 3)


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float32 and loop triangles (T, 3) uint32 of a mesh, via ``foreach_get``."""
    verts = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", verts)
    tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", tris)
    return verts.reshape(-1, 3), tris.view(np.uint32).reshape(-1, 3)


def principled_node(tree):
    """The Principled BSDF feeding the material output, else the tree's first one, else None."""
    out = tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BSDF_PRINCIPLED":
            return node
    return next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None)


def material_surface(material, object_color=_WHITE) -> tuple:
    """``(rgba, specular, roughness)`` of a material (its Principled BSDF's unlinked input values,
    else its viewport settings). Without a material: the object's colour when it is not the
    default white, else Blender's 0.8 grey; specular and roughness 0.5."""
    if material is None:
        rgba = tuple(object_color) if tuple(object_color) != _WHITE else _GREY
        return rgba, 0.5, 0.5
    node = principled_node(material.node_tree) if material.use_nodes and material.node_tree else None
    if node is not None:
        rgb = tuple(node.inputs["Base Color"].default_value)[:3]
        rgba = rgb + (float(node.inputs["Alpha"].default_value),)
        spec = float(node.inputs["Specular IOR Level"].default_value)
        rough = float(node.inputs["Roughness"].default_value)
    else:
        rgba = tuple(material.diffuse_color)
        spec, rough = float(material.specular_intensity), float(material.roughness)
    return rgba, min(max(spec, 0.0), 1.0), min(max(rough, 0.0), 1.0)


def world_background(world):
    """The Background node the world's output uses (else the tree's first), or None."""
    if world is None or not world.use_nodes or not world.node_tree:
        return None
    out = world.node_tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BACKGROUND":
            return node
    return next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)


def world_color(world) -> np.ndarray:
    """Linear RGB of the world: its Background node's colour × strength, else ``world.color``."""
    if world is None:
        return np.zeros(3, np.float32)
    bg = world_background(world)
    if bg is not None:
        rgb = np.array(bg.inputs["Color"].default_value[:3], np.float32)
        return rgb * np.float32(bg.inputs["Strength"].default_value)
    return np.array(world.color[:3], np.float32)


def is_sphere_primitive(ob) -> bool:
    """The object's "Sphere Primitive" setting: the add-on's property when registered, else the
    ``hybrid_sphere`` custom property (scene scripts set that one)."""
    value = getattr(ob, SPHERE_PROPERTY, None)
    if value is None:
        value = ob.get(SPHERE_PROPERTY, False)
    return bool(value)


def render_resolution(scene) -> tuple[int, int]:
    """The render size in pixels, as Blender computes it (integer percentage scaling)."""
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100,
            r.resolution_y * r.resolution_percentage // 100)


def export_lights(depsgraph, render_visibility: bool | None = None) -> list:
    """The lights of a depsgraph that ``export_depsgraph`` would list, without reading any
    geometry."""
    ex = _Exporter(depsgraph, render_visibility)
    lights = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type != "LIGHT":
            continue
        if inst.is_instance:
            parent = inst.parent
            if not ex._renderable(parent.original):
                continue
            name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
        else:
            if not ex._renderable(ob.original):
                continue
            name = ob.name
        lights.append(export_light(ob, _matrix(inst.matrix_world), name))
    return lights


def light_color(d) -> tuple:
    """Linear RGB of a light datablock: its colour, times its blackbody colour when Blender has
    ``use_temperature`` (4.5+) and it is on (as Cycles and EEVEE multiply them)."""
    rgb = np.array(d.color[:3], np.float64)
    if getattr(d, "use_temperature", False):
        rgb = rgb * np.array(d.temperature_color[:3], np.float64)
    return tuple(float(c) for c in rgb)


def light_power(d) -> float:
    """Power (W) or sun strength (W/m²) as Cycles emits it: ``energy * 2^exposure`` (Blender
    4.0+), and for an area light whose ``normalize`` is off (4.2+), times its area (the power is
    then per square metre)."""
    power = float(d.energy) * 2.0 ** float(getattr(d, "exposure", 0.0))
    if d.type == "AREA" and not getattr(d, "normalize", True):
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        area = float(d.size) * float(size_y) * (np.pi / 4 if d.shape in ("DISK", "ELLIPSE") else 1.0)
        power *= area
    return power


def export_light(ob, matrix: np.ndarray, name: str) -> Light:
    """A light object (evaluated) at world ``matrix``. An area light's ``size_y`` is its actual
    extent: ``size`` for square and disk shapes."""
    d = ob.data
    kw = dict(name=name, type=d.type, color=light_color(d), power=light_power(d), matrix=matrix,
              use_shadow=bool(d.use_shadow))
    if d.type == "SUN":
        kw["angle"] = float(d.angle)
    elif d.type in ("POINT", "SPOT"):
        kw["radius"] = float(d.shadow_soft_size)
    if d.type == "SPOT":
        kw.update(spot_size=float(d.spot_size), spot_blend=float(d.spot_blend))
    elif d.type == "AREA":
        size_y = d.size_y if d.shape in ("RECTANGLE", "ELLIPSE") else d.size
        kw.update(size=float(d.size), size_y=float(size_y), area_shape=d.shape)
    return Light(**kw)


def export_camera(depsgraph) -> Camera | None:
    """The scene camera (evaluated at the depsgraph's frame), or None when the scene has none."""
    ob = depsgraph.scene.camera
    if ob is None:
        return None
    ob = ob.evaluated_get(depsgraph)
    if ob.type != "CAMERA":
        raise SceneError(f"the scene camera '{ob.name}' is a {ob.type.lower()} object, not a camera")
    d = ob.data
    return Camera(name=ob.name, matrix=_matrix(ob.matrix_world), type=d.type, lens=d.lens,
                  sensor_width=d.sensor_width, sensor_height=d.sensor_height,
                  sensor_fit=d.sensor_fit, ortho_scale=d.ortho_scale, shift_x=d.shift_x,
                  shift_y=d.shift_y, clip_start=d.clip_start, clip_end=d.clip_end)


# --------------------------------------------------------------------------------------------
# The exporter
# --------------------------------------------------------------------------------------------
class _Exporter:
    def __init__(self, depsgraph, render_visibility: bool | None = None):
        self.dg = depsgraph
        self.check_render_visibility = (depsgraph.mode != "RENDER" if render_visibility is None
                                        else bool(render_visibility) and depsgraph.mode != "RENDER")
        self.models: list[Model] = []
        self.model_of: dict = {}  # geometry key -> model id, -1 for geometry without triangles
        self.attrs: list[tuple] = []  # (casts_shadow, sphere, rgba, specular, roughness)
        self.attr_of: dict = {}
        self.surface_of: dict = {}  # material pointer -> material_surface()
        self.renderable_of: dict = {}  # original object pointer -> bool
        self.hidden_collections = None
        # one row per instance found by the iterator
        self.names: list[str] = []
        self.model_ids: list[int] = []
        self.matrices: list = []
        self.attr_ids: list[int] = []
        self.parts: list[Instances] = []  # vectorised geometry-nodes instances
        self.lights: list[Light] = []
        self.keep: list = []  # GeometrySets own the meshes they reference: alive while exporting

    # -- entry --------------------------------------------------------------------------------
    def run(self, resolution) -> Scene:
        scene = self.dg.scene_eval
        self._walk()
        instances = Instances.concatenate([self._iterated_instances()] + self.parts)
        camera = export_camera(self.dg)
        result = Scene(name=scene.name, models=self.models, instances=instances,
                       lights=self.lights, camera=camera, world_color=world_color(scene.world),
                       resolution=render_resolution(scene) if resolution is None else resolution,
                       frame=scene.frame_current)
        return result.check_transforms()

    def _walk(self) -> None:
        vectorised = set()  # evaluated instancers whose instances came from their GeometrySet
        iterated = set()  # evaluated instancers with duplis taken from the iterator
        for inst in self.dg.object_instances:
            if inst.is_instance:
                parent = inst.parent
                pptr = parent.as_pointer()
                if pptr in vectorised:
                    continue
                iterated.add(pptr)
                ob = inst.object
                if not self._renderable(parent.original):
                    continue
                name = ob.name if ob.name == parent.name else f"{parent.name}/{ob.name}"
            else:
                ob = inst.object
                if not self._renderable(ob.original):
                    continue
                name = ob.name
                if (ob.type == "MESH" and ob.as_pointer() not in iterated
                        and any(m.type == "NODES" for m in ob.modifiers)
                        and self._vectorise(ob)):
                    vectorised.add(ob.as_pointer())
            kind = ob.type
            if kind == "MESH":
                self._add_mesh_instance(ob, ob.data, ob.data.as_pointer(), inst.matrix_world, name)
            elif kind == "LIGHT":
                self.lights.append(export_light(ob, _matrix(inst.matrix_world), name))
            elif kind in GEOMETRY_TYPES and bpy.types.GeometrySet.from_evaluated_object(ob).mesh is None:
                self._add_converted_instance(ob, inst.matrix_world, name)

    # -- visibility ---------------------------------------------------------------------------
    def _renderable(self, ob) -> bool:
        """For a viewport depsgraph: the original object is not hidden from render, itself or
        through all of its collections."""
        if not self.check_render_visibility:
            return True
        key = ob.as_pointer()
        ok = self.renderable_of.get(key)
        if ok is None:
            if self.hidden_collections is None:
                self.hidden_collections = set()
                for coll in self.dg.scene.collection.children_recursive:
                    if coll.hide_render:
                        self.hidden_collections.add(coll.as_pointer())
                        self.hidden_collections.update(c.as_pointer() for c in coll.children_recursive)
            colls = [c.as_pointer() for c in ob.users_collection]
            ok = not ob.hide_render and not (colls and all(c in self.hidden_collections for c in colls))
            self.renderable_of[key] = ok
        return ok

    # -- models and per-instance attributes ---------------------------------------------------
    def _model(self, key, mesh, name: str) -> int:
        mid = self.model_of.get(key)
        if mid is None:
            verts, tris = mesh_arrays(mesh)
            mid = -1
            if len(tris):
                mid = len(self.models)
                self.models.append(Model(name=name, vertices=verts, triangles=tris, normals=smooth_normals(mesh)))
            self.model_of[key] = mid
        return mid

    def _attributes(self, ob, material) -> int:
        """Row in ``self.attrs`` for an (evaluated) object showing ``material``."""
        key = (ob.original.as_pointer(), None if material is None else material.as_pointer())
        aid = self.attr_of.get(key)
        if aid is None:
            skey = key[1]
            surface = self.surface_of.get(skey) if skey is not None else None
            if surface is None:
                surface = material_surface(material, ob.color)
                if skey is not None:
                    self.surface_of[skey] = surface
            aid = len(self.attrs)
            self.attrs.append((bool(ob.visible_shadow), is_sphere_primitive(ob)) + surface)
            self.attr_of[key] = aid
        return aid

    @staticmethod
    def _first_material(ob):
        slots = ob.material_slots
        return slots[0].material if len(slots) else None

    @staticmethod
    def _model_name(ob, mesh) -> str:
        """The mesh's name, or the object's when the mesh is a modifier or conversion result."""
        return mesh.name if mesh.name == getattr(ob.original.data, "name", None) else ob.original.name

    def _add_mesh_instance(self, ob, mesh, key, matrix, name) -> None:
        mid = self._model(key, mesh, self._model_name(ob, mesh))
        if mid < 0:
            return
        self.names.append(name)
        self.model_ids.append(mid)
        self.matrices.append(matrix.copy())
        self.attr_ids.append(self._attributes(ob, self._first_material(ob)))

    def _add_converted_instance(self, ob, matrix, name) -> None:
        """A non-mesh object without a mesh component: its ``to_mesh()`` triangles, if any."""
        key = ("to_mesh", ob.original.as_pointer())
        if key not in self.model_of:
            mesh = ob.to_mesh()
            try:
                self._model(key, mesh, ob.original.name)
            finally:
                ob.to_mesh_clear()
        if self.model_of[key] < 0:
            return
        self.names.append(name)
        self.model_ids.append(self.model_of[key])
        self.matrices.append(matrix.copy())
        self.attr_ids.append(self._attributes(ob, self._first_material(ob)))

    def _iterated_instances(self) -> Instances:
        if not self.names:
            return Instances()
        attrs = [self.attrs[i] for i in self.attr_ids]
        return Instances(
            names=self.names,
            model_ids=np.array(self.model_ids, np.int32),
            matrices=(m := _matrices(self.matrices)),
            inverse=affine_inverse(m),
            casts_shadow=np.array([a[0] for a in attrs], bool),
            sphere=np.array([a[1] for a in attrs], bool),
            base_color=np.array([a[2] for a in attrs], np.float32),
            specular=np.array([a[3] for a in attrs], np.float32),
            roughness=np.array([a[4] for a in attrs], np.float32),
        )

    # -- geometry-nodes instances, vectorised -------------------------------------------------
    def _vectorise(self, ob) -> bool:
        """Read the geometry-nodes instances of mesh object ``ob`` from its GeometrySet into
        ``self.parts``. False (nothing added) when its instance tree holds anything but meshes
        and plain mesh objects (collections, curves, ...): the iterator then takes them."""
        groups = _flatten(bpy.types.GeometrySet.from_evaluated_object(ob), self.dg, self.keep)
        if groups is None:
            return False
        world = _matrix(ob.matrix_world)
        for source, mesh, label, local, index in groups:
            matrices = np.matmul(world, local)
            if source is None:  # realised geometry made by ob's node tree
                key = mesh.as_pointer()
                mid = self._model(key, mesh, f"{ob.name}/{label}")
                aid = self._attributes(ob, mesh.materials[0] if len(mesh.materials) else None)
            else:  # an object instanced as a whole
                mid = self._model(mesh.as_pointer(), mesh, self._model_name(source, mesh))
                aid = self._attributes(source, self._first_material(source))
            if mid < 0:
                continue
            n = len(index)
            shadow, sphere, rgba, spec, rough = self.attrs[aid]
            prefix = f"{ob.name}/{label}"
            self.parts.append(Instances(
                names=[f"{prefix}[{i}]" for i in index.tolist()],
                model_ids=np.full(n, mid, np.int32),
                matrices=matrices,
                inverse=affine_inverse(matrices),
                casts_shadow=np.full(n, shadow),
                sphere=np.full(n, sphere),
                base_color=np.tile(np.float32(rgba), (n, 1)),
                specular=np.full(n, spec, np.float32),
                roughness=np.full(n, rough, np.float32),
            ))
        return True


def _flatten(gs, depsgraph, keep: list):
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
            sub = _flatten(r, depsgraph, keep)
            if sub is None:
                return None
            for source, mesh, label, sub_m, _ in sub:
                placed = np.matmul(m[:, None], sub_m[None]).reshape(-1, 4, 4)
                out.append((source, mesh, label, placed, np.repeat(index, len(sub_m))))
        else:
            return None
    return out
