"""The viewport's building blocks, apart from ``RenderEngine`` so they can be tested headless
(:mod:`.viewport_engine` drives them from the engine).

- :class:`ViewportSync`: the core scene of a viewport depsgraph, kept up to date from
  ``depsgraph.updates`` with the least work (see :meth:`ViewportSync.classify`).
- :func:`viewport_camera`: a core ``Camera`` from a 3D view's view and window matrices.
- :class:`ViewportDisplay`: numpy RGBA → ``gpu.types.GPUTexture`` → ``draw_texture_2d``.
  ``gpu`` is imported lazily: it is unavailable in background mode until Blender has a GPU
  context.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.bake.materials import material_signature
from ..core.gpu.debug_views import debug_image, grid_occupancy  # noqa: F401 - (re-exported)
from ..core.runtime.worker import writable_matrices
from ..core.scene import Camera, Model, affine_inverse
from ..core.scene.lights import changed_shadows
from . import export
from .export.common import GEOMETRY_TYPES, is_sphere_primitive, to_matrix
from .export.images import PIXELS
from .export.lights import export_lights
from .export.linking import collection_states
from .export.meshes import mesh_arrays, mesh_uv_layer, mesh_uvs, slot_owner, smooth_normals, used_slots
from .export.world import world_color

#: data-block types whose change only needs the lights re-read (nothing re-baked)
_LIGHT_TYPES = (bpy.types.Light,)
#: data-block types whose change needs a re-export of the shading (no re-bake)
_SHADING_TYPES = (bpy.types.Material, bpy.types.Image, bpy.types.ShaderNodeTree)


@dataclass
class UpdatePlan:
    """What ``depsgraph.updates`` asks for. ``full`` wins over everything else."""

    full: bool = False
    moved: set = field(default_factory=set)  # object names: transform only
    geometry: set = field(default_factory=set)  # object names: geometry edited
    lights: bool = False
    world: bool = False
    shading: bool = False  # materials, light linking, view-layer filters: re-export, bake kept if it can
    images: list = field(default_factory=list)  # images whose pixels changed (read again)
    reasons: list = field(default_factory=list)

    @property
    def nothing(self) -> bool:
        return not (self.full or self.moved or self.geometry or self.lights or self.world or self.shading)

    def need_full(self, why: str) -> None:
        self.full = True
        self.reasons.append(why)


def _object_attributes(ob) -> tuple:
    """What the exporter reads from an object besides its transform and geometry."""
    mats = tuple(None if s.material is None else s.material.as_pointer() for s in ob.material_slots)
    return (bool(ob.visible_shadow), is_sphere_primitive(ob), mats, tuple(ob.color)) + _ray_attributes(ob)


def _ray_attributes(ob) -> tuple:
    """The ray visibility the exporter reads from an object (:mod:`.export.ray_visibility`)."""
    return (bool(ob.visible_camera), bool(ob.is_holdout), bool(ob.show_instancer_for_viewport))


def _layer_state(depsgraph) -> tuple:
    """What the exporter reads from the view layer (changes to it come as a bare Scene update):
    its Hair filter and each layer collection's holdout, indirect-only and exclude states."""
    vl = depsgraph.view_layer
    out = [bool(getattr(vl, "use_strand", True))]
    stack = [vl.layer_collection]
    while stack:
        lc = stack.pop()
        out.append((lc.name, bool(lc.holdout), bool(lc.indirect_only), bool(lc.exclude)))
        stack.extend(lc.children)
    return tuple(out)


def _linking_state(depsgraph) -> tuple:
    """Every light's receiver and blocker collections with their objects' link states (a change
    of a link state comes as a bare Collection update)."""
    out = []
    for ob in depsgraph.objects:
        ll = getattr(ob, "light_linking", None) if ob.type == "LIGHT" else None
        if ll is None:
            continue
        colls = (ll.receiver_collection, ll.blocker_collection)
        if any(c is not None for c in colls):
            out.append((ob.name,) + tuple(
                None if c is None else (c.name, tuple(sorted(collection_states(c).items()))) for c in colls))
    return tuple(out)


class ViewportSync:
    """The core scene of a viewport depsgraph and the incremental updates of a pipeline.

    ``pipeline``: a :class:`~..core.gpu.pipeline.Pipeline`, or the viewport's
    :class:`~..core.runtime.worker.RenderWorker` (the same calls, queued with a copy of the scene),
    or None (change detection only, as in the tests). The bake is made lazily: only ray tracing
    needs it (:meth:`ensure_baked`)."""

    def __init__(self, pipeline=None):
        self.pipeline = pipeline
        self.scene = None
        self.rows: dict = {}  # object name -> instance rows it owns (non-instanced objects)
        self.known: set = set()  # names of every evaluated object at the last full export
        self.attributes: dict = {}  # object name -> _object_attributes
        self.baked = False  # the pipeline's bake matches self.scene
        self.log: list = []  # (action, detail) of the updates applied, newest last
        self.only = None  # local view: names of the objects it shows (None: every object)
        self.layer_state = None  # _layer_state at the last export
        self.linking_state = None  # _linking_state at the last export

    # -- full export ------------------------------------------------------------------------------
    def full_export(self, depsgraph) -> None:
        PIXELS.active = True  # (images read once, again when an update names them)
        try:
            scene = export.export_depsgraph(depsgraph, resolution=(1, 1), render_visibility=False)
        finally:
            PIXELS.active = False
        if self.only is not None:
            scene.instances = scene.instances.take([self._local(n) for n in scene.instances.names])
            scene.lights = self._local_lights(scene.lights)
        rows: dict = {}
        for i, name in enumerate(scene.instances.names):
            rows.setdefault(slot_owner(name), []).append(i)  # (a split mesh's slots: one object)
        self.rows = {k: np.array(v, np.int64) for k, v in rows.items()}
        self.known = set()
        self.attributes = {}
        for ob in depsgraph.objects:
            self.known.add(ob.name)
            if ob.name in self.rows or ob.is_instancer:
                self.attributes[ob.name] = _object_attributes(ob)
        self.layer_state = _layer_state(depsgraph)
        self.linking_state = _linking_state(depsgraph)
        if self.scene is not None:
            scene.camera = self.scene.camera
        self.scene = scene
        self.baked = False
        self.log.append(("full", len(scene.instances)))

    def _local(self, name: str) -> bool:
        """Whether the instance or light ``name`` (``object`` or ``instancer/object``) is in the
        local view (always, outside one)."""
        return self.only is None or slot_owner(name).split("/", 1)[0] in self.only

    def _local_lights(self, lights: list) -> list:
        return [light for light in lights if self._local(light.name)]

    def set_local_view(self, depsgraph, names) -> bool:
        """Enter (``names``: the objects of the local view) or leave (None) a local view;
        exports again when that changes what is shown. Returns whether it changed."""
        only = None if names is None else frozenset(names)
        if only == self.only:
            return False
        self.only = only
        self.full_export(depsgraph)
        return True

    def ensure_baked(self) -> None:
        """Bake the scene into the pipeline if it changed structurally since the last bake."""
        if self.pipeline is not None and not self.baked:
            self.pipeline.set_scene(self.scene)
            self.log.append(("bake", len(self.scene.instances)))
        self.baked = True

    # -- classification ---------------------------------------------------------------------------
    def classify(self, depsgraph) -> UpdatePlan:
        """Read ``depsgraph.updates`` into an :class:`UpdatePlan`:

        - an object whose transform changed → ``moved`` (incremental grid update);
        - an object whose geometry changed → ``geometry`` (that model is re-built);
        - a light or light data → ``lights``; a world → ``world``; a material → ``shading``;
          none of them re-bakes anything;
        - a view-layer toggle (Hair filter, a collection's holdout or indirect-only) or a light
          linking change → ``shading`` (re-export; the bake stays if the instances do);
        - a new object, an instancer (collection instances, particles, geometry-nodes instances),
          a collection change, or a change of what the exporter reads from an object (shadow
          visibility, sphere flag, material slot) → ``full``. Objects hidden from render are shown
          (as Cycles' and EEVEE's viewports do); what the viewport hides is not in its depsgraph.
        """
        plan = UpdatePlan()
        if self.scene is None:
            plan.need_full("first update")
            return plan
        updates = list(depsgraph.updates)
        # the node tree embedded in a light or world (Blender 5 updates it with its owner) is
        # part of that light or world, not a material
        owners = any(isinstance(u.id, (*_LIGHT_TYPES, bpy.types.World)) for u in updates)
        for u in updates:
            idb = u.id
            if isinstance(idb, bpy.types.Object):
                self._classify_object(u, idb, plan)
            elif isinstance(idb, _LIGHT_TYPES):
                plan.lights = True
            elif isinstance(idb, bpy.types.World):
                plan.world = True
            elif isinstance(idb, _SHADING_TYPES):
                if not (owners and isinstance(idb, bpy.types.ShaderNodeTree) and idb.is_embedded_data):
                    plan.shading = True
                if isinstance(idb, bpy.types.Image):
                    plan.images.append(idb.original)
            elif isinstance(idb, bpy.types.Collection):
                if u.is_updated_transform or u.is_updated_geometry:
                    plan.need_full(f"collection '{idb.name}' changed")
            # Scene, meshes (their objects come as well), cameras, node groups (their objects
            # come as well), ...: nothing of their own
        if not plan.full and self._layer_or_linking_changed(depsgraph, updates):
            plan.shading = True  # the instances' flags or light sets, or the strands shown
            plan.reasons.append("view layer or light linking changed")
        return plan

    def _layer_or_linking_changed(self, depsgraph, updates) -> bool:
        """Whether the view layer's toggles (they come as a Scene update) or the light linking
        (with a Collection or a light) differ from the last export's."""
        if not any(isinstance(u.id, (bpy.types.Scene, bpy.types.Collection, *_LIGHT_TYPES))
                   or isinstance(u.id, bpy.types.Object) and u.id.type == "LIGHT" for u in updates):
            return False
        return _layer_state(depsgraph) != self.layer_state or _linking_state(depsgraph) != self.linking_state

    def _classify_object(self, u, ob, plan: UpdatePlan) -> None:
        name = ob.name
        kind = ob.type
        if kind == "LIGHT":
            plan.lights = True
            return
        if kind == "CAMERA":
            return  # the viewport's own view matrices are compared in view_draw
        if name not in self.known:
            if kind in GEOMETRY_TYPES or ob.is_instancer or kind == "EMPTY" and ob.instance_type != "NONE":
                plan.need_full(f"new object '{name}'")
            return
        if ob.is_instancer and (u.is_updated_transform or u.is_updated_geometry
                                or _object_attributes(ob) != self.attributes.get(name)):
            plan.need_full(f"instancer '{name}' changed")
            return
        owned = name in self.rows
        if not owned:
            # known but exported no rows: no triangles, an empty, ...
            if kind in GEOMETRY_TYPES and u.is_updated_geometry:
                plan.need_full(f"'{name}' may have gained geometry")
            return
        if u.is_updated_geometry:
            plan.geometry.add(name)
        elif u.is_updated_transform:
            plan.moved.add(name)
        if _object_attributes(ob) != self.attributes.get(name):
            plan.need_full(f"attributes of '{name}' changed")

    # -- applying ---------------------------------------------------------------------------------
    def update(self, depsgraph) -> UpdatePlan:
        """Classify and apply ``depsgraph.updates``; returns the plan that was applied."""
        plan = self.classify(depsgraph)
        for image in plan.images:
            PIXELS.forget(image)
        if plan.nothing:
            return plan
        if plan.full:
            self.full_export(depsgraph)
            return plan
        if plan.shading:
            self._reexport_keeping_bake(depsgraph)
            return plan
        done: set = set()  # models already rebuilt (linked duplicates share one)
        for name in sorted(plan.geometry):
            if not self._update_geometry(depsgraph, name, done):
                self.full_export(depsgraph)
                return plan
        moved = sorted(plan.moved - plan.geometry)
        if moved:
            self._move(depsgraph, moved)
        if plan.lights:
            old = self.scene.lights
            sets = {light.name: (light.receiver_set, light.blocker_set) for light in old}
            self.scene.lights = self._local_lights(export_lights(depsgraph, render_visibility=False))
            for light in self.scene.lights:  # the linking did not change: the same sets
                light.receiver_set, light.blocker_set = sets.get(light.name, (-1, -1))
            self._reset_lights(old, self.scene.lights)
            self.log.append(("lights", len(self.scene.lights)))
        if plan.world:  # (the world lights, it casts no shadow: every mask stands)
            self.scene.world_color = np.asarray(world_color(depsgraph.scene_eval.world), np.float32)
            self.log.append(("world", None))
        return plan

    def _reset_lights(self, old: list, new: list) -> None:
        """Forget the history of the lights whose shadow changed (not their colour or power);
        of every light when lights came, went or changed order."""
        changed = changed_shadows(old, new)
        if changed is None:
            self._reset_history()
            return
        for i in changed:
            if self.pipeline is not None:
                self.pipeline.reset_light(i)
            self.log.append(("reset light", old[i].name))

    def _reset_history(self) -> None:
        if self.pipeline is not None:
            self.pipeline.reset_history()

    def _move(self, depsgraph, names) -> None:
        objects = depsgraph.objects
        index = []
        mats = []
        for name in names:
            ob = objects.get(name)
            if ob is None:
                continue
            rows = self.rows[name]
            m = to_matrix(ob.matrix_world)
            index.append(rows)
            mats.append(np.broadcast_to(m, (len(rows), 4, 4)))
        if not index:
            return
        idx = np.concatenate(index)
        writable_matrices(self.scene.instances)  # (the worker's snapshots share them)
        self.scene.instances.set_matrices(idx, np.concatenate(mats))
        if self.pipeline is not None and self.baked:
            self.pipeline.move_instances(self.scene, idx)
        self.log.append(("move", [str(n) for n in names]))

    def _update_geometry(self, depsgraph, name, done: set) -> bool:
        """Re-read the evaluated mesh of object ``name`` into its model; False when only a full
        export can do it (non-mesh object, several models, no triangles left, a mesh shown
        through a material slot other than 0 or split by slot, now or at the last export: the
        export names those models ``"<mesh> [slot k]"``)."""
        ob = depsgraph.objects.get(name)
        rows = self.rows[name]
        if ob is None or ob.type != "MESH" or len(rows) != 1 or ob.is_instancer:
            return False
        mid = int(self.scene.instances.model_ids[rows[0]])
        old = self.scene.models[mid]
        if slot_owner(old.name) != old.name:
            return False  # split by slot (its other slots are other rows), or not slot 0's
        n_slots = len(ob.material_slots)
        if n_slots > 1 and used_slots(ob.data, n_slots) != [0]:
            return False  # now split by slot, or showing another slot's material
        if mid in done:
            return True
        done.add(mid)
        verts, tris = mesh_arrays(ob.data)
        if not len(tris):
            return False
        uvs = None
        if old.uvs is not None:  # a textured material shows it: keep reading its UVs
            layer = mesh_uv_layer(ob.data)
            if layer is None:
                return False  # the UV map is gone: the full export decides about the material
            uvs = mesh_uvs(ob.data, layer)
        self.scene.models[mid] = Model(name=old.name, vertices=verts, triangles=tris,
                                       normals=smooth_normals(ob.data), uvs=uvs)
        writable_matrices(self.scene.instances)
        self.scene.instances.set_matrices(rows, to_matrix(ob.matrix_world)[None])
        if self.pipeline is not None and self.baked:
            self.pipeline.update_model(self.scene, mid)
        self.log.append(("model", name))
        return True

    def _reexport_keeping_bake(self, depsgraph) -> None:
        """Materials changed: re-export; the bake stays when the instances did not change."""
        old = self.scene
        baked = self.baked
        self.full_export(depsgraph)
        new = self.scene
        same = (old.instances.names == new.instances.names
                and np.array_equal(old.instances.model_ids, new.instances.model_ids)
                and np.array_equal(old.instances.matrices, new.instances.matrices)
                and np.array_equal(old.instances.casts_shadow, new.instances.casts_shadow)
                and np.array_equal(old.instances.sphere, new.instances.sphere)
                and len(old.models) == len(new.models)
                and all(a.triangle_count == b.triangle_count and np.array_equal(a.vertices, b.vertices)
                        for a, b in zip(old.models, new.models)))
        if same:
            # keep the old models (their GPU buffers stay cached) and the bake; the masks stand
            # unless what cuts shadows changed (alpha, images, transparent shadows; the pipeline
            # itself forgets them where the instances' linking, casting or materials change)
            new.models = old.models
            self.baked = baked
            if material_signature(old) != material_signature(new):
                self._reset_history()
            self.log[-1] = ("shading", len(new.instances))


# ------------------------------------------------------------------------------------------------
# Viewport camera
# ------------------------------------------------------------------------------------------------
_SENSOR = 36.0


def render_region(context, width: int, height: int):
    """``(x0, y0, w, h)`` in region pixels (bottom-up) of the 3D view's render region (View ▸
    Render Region, outside the camera view, as Cycles' viewport renders it), None without one
    (or an empty one)."""
    space, rv3d = getattr(context, "space_data", None), getattr(context, "region_data", None)
    if not getattr(space, "use_render_border", False) or getattr(rv3d, "view_perspective", "") == "CAMERA":
        return None
    x0, x1 = int(space.render_border_min_x * width), int(space.render_border_max_x * width)
    y0, y1 = int(space.render_border_min_y * height), int(space.render_border_max_y * height)
    x0, y0 = max(0, min(x0, width)), max(0, min(y0, height))
    x1, y1 = max(x0, min(x1, width)), max(y0, min(y1, height))
    if x1 - x0 < 1 or y1 - y0 < 1 or (x1 - x0, y1 - y0) == (width, height):
        return None
    return x0, y0, x1 - x0, y1 - y0


def crop_window(window_matrix, rect, width: int, height: int) -> np.ndarray:
    """The projection of the ``rect`` (``(x0, y0, w, h)`` bottom-up pixels) of a ``width`` x
    ``height`` view: its clip space scaled and moved so that the rectangle fills it."""
    P = np.array([tuple(r) for r in window_matrix], np.float64)
    x0, y0, w, h = rect
    if (x0, y0, w, h) == (0, 0, width, height):
        return P
    crop = np.eye(4)
    crop[0, 0], crop[1, 1] = width / w, height / h
    crop[0, 3] = -(2.0 * x0 + w - width) / w
    crop[1, 3] = -(2.0 * y0 + h - height) / h
    return crop @ P


def viewport_camera(view_matrix, window_matrix, width: int, height: int) -> Camera:
    """A core camera reproducing a 3D view (``RegionView3D.view_matrix`` / ``window_matrix``,
    as nested sequences or mathutils matrices) on a ``width`` x ``height`` region."""
    V = np.array([tuple(r) for r in view_matrix], np.float64)
    P = np.array([tuple(r) for r in window_matrix], np.float64)
    # (cofactors, not np.linalg.inv: LAPACK's threads can stall the draw callback on a busy machine)
    cam_to_world = affine_inverse(V[None])[0]
    w, h = float(width), float(height)
    if abs(P[3, 3]) > 0.5:  # orthographic
        near = (P[2, 3] + 1.0) / P[2, 2]
        far = (P[2, 3] - 1.0) / P[2, 2]
        # the viewport's orthographic clip range starts behind the eye: pull the camera back
        back = max(0.0, -near) + 1e-3 * max(1.0, far - near)
        m = cam_to_world.copy()
        m[:3, 3] += m[:3, 2] / np.linalg.norm(m[:3, 2]) * back
        return Camera(name="Viewport", matrix=m, type="ORTHO", sensor_fit="HORIZONTAL",
                      sensor_width=_SENSOR, sensor_height=_SENSOR, ortho_scale=2.0 / P[0, 0],
                      shift_x=-P[0, 3] / 2.0, shift_y=-P[1, 3] * h / (2.0 * w),
                      clip_start=near + back, clip_end=far + back)
    near = P[2, 3] / (P[2, 2] - 1.0)
    far = P[2, 3] / (P[2, 2] + 1.0)
    return Camera(name="Viewport", matrix=cam_to_world, type="PERSP", sensor_fit="HORIZONTAL",
                  sensor_width=_SENSOR, sensor_height=_SENSOR, lens=P[0, 0] * _SENSOR / 2.0,
                  shift_x=P[0, 2] / 2.0, shift_y=P[1, 2] * h / (2.0 * w), clip_start=near, clip_end=far)


# ------------------------------------------------------------------------------------------------
# Display through Blender's gpu module
# ------------------------------------------------------------------------------------------------
@dataclass
class DisplayImage:
    """A frame ready for the display: rows bottom-up as half floats, and the ``gpu.types.Buffer``
    of its float32 values made where the frame arrived (None: made at upload). The texture is
    RGBA32F: Blender's ``GPUTexture`` takes float32 data only, and a float32 texture takes it
    without a conversion on the drawing thread."""

    width: int
    height: int
    array: np.ndarray
    buffer: object = None

    def image(self) -> np.ndarray:
        """The frame as float32 (H, W, 4), row 0 = top (for tests and debugging)."""
        return self.array[::-1].astype(np.float32)


def prepare_display(array: np.ndarray) -> DisplayImage:
    """A renderer process's frame (:func:`~..core.runtime.render_server.encode_image`) as a
    :class:`DisplayImage`; made on the thread that receives frames, so the draw callback only
    uploads it."""
    h, w = array.shape[:2]
    out = DisplayImage(w, h, array)
    try:
        out.buffer = _gpu_buffer(out)
    except Exception:  # (no gpu module in background mode before Blender has a GPU context)
        pass
    return out


def _gpu_buffer(img: DisplayImage):
    import gpu

    data = img.array.astype(np.float32)  # (numpy's cast runs without Python's lock)
    return gpu.types.Buffer("FLOAT", img.width * img.height * 4, data.reshape(-1))


class ViewportDisplay:
    """Holds the last image as a ``GPUTexture`` and draws it into the bound framebuffer."""

    def __init__(self):
        self.texture = None
        self.size = (0, 0)

    def upload(self, image) -> None:
        """``image``: a :class:`DisplayImage`, or float32 (H, W, 4) with row 0 = top (encoded
        here, as the in-process worker's frames are)."""
        import gpu

        if not isinstance(image, DisplayImage):
            from ..core.runtime.render_server import encode_image

            image = DisplayImage(image.shape[1], image.shape[0], encode_image(image))
        buf = image.buffer if image.buffer is not None else _gpu_buffer(image)
        self.texture = gpu.types.GPUTexture((image.width, image.height), format="RGBA32F", data=buf)
        self.size = (image.width, image.height)

    def draw(self, scene, width: int, height: int, engine=None, origin=(0, 0)) -> None:
        """Draw the texture over ``width`` x ``height`` pixels from ``origin`` (a render region's
        corner), alpha premultiplied, through the scene's view transform
        (``engine.bind_display_space_shader``; without an engine, as in the headless tests, the
        plain image shader draws it)."""
        import gpu
        from gpu_extras.presets import draw_texture_2d

        if self.texture is None:
            return
        gpu.state.blend_set("ALPHA_PREMULT")
        if engine is not None:
            engine.bind_display_space_shader(scene)
        try:
            draw_texture_2d(self.texture, tuple(origin), width, height)
        finally:
            if engine is not None:
                engine.unbind_display_space_shader()
            gpu.state.blend_set("NONE")
