"""The scene: models, instances, lights, camera, materials and images, with its validation."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from .arrays import MAX_COORD, as_f32
from .camera import Camera
from .instances import Instances, max_scale
from .lights import LIGHT_TYPES


@dataclass
class Scene:
    """Everything the engine renders: the models and their instances, lights, camera, materials and
    images, the world colour and the render resolution, and the export's report of what it
    approximated; :meth:`validate` rejects unusable values."""

    name: str = "Scene"
    models: list = field(default_factory=list)  # list[Model]
    instances: Instances = field(default_factory=Instances)
    lights: list = field(default_factory=list)  # list[Light]
    camera: Camera | None = None
    world_color: np.ndarray = field(default_factory=lambda: np.float32([0.05, 0.05, 0.05]))
    resolution: tuple = (1920, 1080)
    frame: int = 1
    materials: list = field(default_factory=list)  # list[Material], see Instances.material_ids
    images: list = field(default_factory=list)  # list[Image], see Material
    #: What the export approximated or left out, one line each ("material 'Skin': Subsurface
    #: read as Diffuse"): shown by the CLI, ``--stats`` (``warnings``), Blender and ``compare``
    report: list = field(default_factory=list)  # list[str]

    def __post_init__(self):
        self.world_color = as_f32(self.world_color).reshape(3)
        self.resolution = (int(self.resolution[0]), int(self.resolution[1]))

    # -- counts -------------------------------------------------------------------------------
    @property
    def triangle_count(self) -> int:
        """Triangles placed in the world (instanced triangles counted once per instance)."""
        if not len(self.instances):
            return 0
        per_model = np.array([m.triangle_count for m in self.models], np.int64)
        return int(per_model[self.instances.model_ids].sum())

    @property
    def unique_triangle_count(self) -> int:
        """Triangles of the models, each model counted once."""
        return int(sum(m.triangle_count for m in self.models))

    def lights_by_type(self) -> dict:
        """Number of lights of each type in ``LIGHT_TYPES``."""
        out = {t: 0 for t in LIGHT_TYPES}
        for light in self.lights:
            out[light.type] = out.get(light.type, 0) + 1
        return out

    def alpha_models(self) -> np.ndarray:
        """(M,) bool: models shown by at least one shadow-casting instance whose material cuts
        its shadow (alpha below 1 somewhere, transparent shadows on): their triangles need UVs
        and the any-hit alpha test. An opaque scene has none."""
        out = np.zeros(len(self.models), bool)
        inst = self.instances
        if not len(inst) or not self.materials:
            return out
        cuts = np.array([m.has_alpha and m.transparent_shadow for m in self.materials] + [False])
        rows = cuts[inst.material_ids] & inst.casts_shadow & ~inst.sphere
        out[np.unique(inst.model_ids[rows])] = True
        return out

    def instance_spheres(self, idx=None):
        """World bounding spheres of instances ``idx`` (all when None): centres (N, 3) and radii
        (N,), float64."""
        inst = self.instances
        mids, mats = (inst.model_ids, inst.matrices) if idx is None else (inst.model_ids[idx], inst.matrices[idx])
        if len(mids) == 0 or not self.models:
            return np.zeros((len(mids), 3)), np.zeros(len(mids))
        centers_m = np.array([m.sphere_center for m in self.models], np.float64).reshape(-1, 3)
        radii_m = np.array([m.sphere_radius for m in self.models], np.float64)
        centers = np.einsum("nij,nj->ni", mats[:, :3, :3], centers_m[mids]) + mats[:, :3, 3]
        radii = radii_m[mids] * max_scale(mats)
        return centers, radii

    def world_bounds(self):
        """(min, max) of the world-space boxes of all instances (exact box transform), or
        ``None`` for an empty scene."""
        inst = self.instances
        if not len(inst):
            return None
        bmin = np.array([m.bounds_min for m in self.models], np.float64).reshape(-1, 3)[inst.model_ids]
        bmax = np.array([m.bounds_max for m in self.models], np.float64).reshape(-1, 3)[inst.model_ids]
        center = (bmin + bmax) * 0.5
        half = (bmax - bmin) * 0.5
        R = inst.matrices[:, :3, :3]
        wc = np.einsum("nij,nj->ni", R, center) + inst.matrices[:, :3, 3]
        wh = np.einsum("nij,nj->ni", np.abs(R), half)
        return (wc - wh).min(axis=0), (wc + wh).max(axis=0)

    # -- validation ---------------------------------------------------------------------------
    def check_transforms(self) -> Scene:
        """Raise :class:`SceneError` naming the first object, light or camera with a NaN or
        infinite transform (what the export rejects at once; :meth:`validate` checks the rest)."""
        inst = self.instances
        if len(inst):
            bad = ~np.isfinite(inst.matrices).all(axis=(1, 2))
            if bad.any():
                raise SceneError(f"object '{inst.names[int(np.argmax(bad))]}' has a NaN or infinite transform")
        for light in self.lights:
            if not np.isfinite(light.matrix).all():
                raise SceneError(f"light '{light.name}' has a NaN or infinite transform")
        if self.camera is not None and not np.isfinite(self.camera.matrix).all():
            raise SceneError(f"camera '{self.camera.name}' has a NaN or infinite transform")
        return self

    def validate(self, require_camera: bool = True) -> Scene:
        """Raise :class:`SceneError` naming the first unusable object; return self."""
        for m in self.models:
            m.validate()
        inst = self.instances
        n = len(inst)
        if n:
            if inst.model_ids.min() < 0 or inst.model_ids.max() >= len(self.models):
                bad = int(np.nonzero((inst.model_ids < 0) | (inst.model_ids >= len(self.models)))[0][0])
                raise SceneError(f"object '{inst.names[bad]}' refers to a missing mesh")
        self.check_transforms()
        if n:
            huge = (np.abs(inst.matrices) >= MAX_COORD).any(axis=(1, 2))
            if huge.any():  # Blender clamps an infinite scale/location to FLT_MAX: still unusable
                raise SceneError(f"object '{inst.names[int(np.argmax(huge))]}' has an infinite or absurd transform "
                                 f"(a value beyond {MAX_COORD:.0e})")
            bad_i = ~np.isfinite(inst.inverse).all(axis=(1, 2))
            if bad_i.any():
                raise SceneError(f"object '{inst.names[int(np.argmax(bad_i))]}' has a zero scale "
                                 "(its transform cannot be inverted)")
            if inst.material_ids.min() < -1 or inst.material_ids.max() >= len(self.materials):
                bad = int(np.nonzero((inst.material_ids < -1) | (inst.material_ids >= len(self.materials)))[0][0])
                raise SceneError(f"object '{inst.names[bad]}' refers to a missing material")
            for label, arr in (("colour", inst.base_color), ("specular", inst.specular)):
                bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
                if bad.any():
                    raise SceneError(f"object '{inst.names[int(np.argmax(bad))]}' has a NaN or infinite {label}")
        for img in self.images:
            img.validate()
        for mat in self.materials:
            mat.validate(len(self.images))
        if n and self.materials:
            for m in np.unique(inst.model_ids[inst.material_ids >= 0]).tolist():
                rows = np.nonzero((inst.model_ids == m) & (inst.material_ids >= 0))[0]
                if self.models[m].uvs is None and any(self.materials[k].textured
                                                      for k in inst.material_ids[rows].tolist()):
                    raise SceneError(f"object '{inst.names[int(rows[0])]}' has a textured material but its mesh "
                                     f"'{self.models[m].name}' has no UV map")
        for light in self.lights:
            light.validate()
        if self.camera is None:
            if require_camera:
                raise SceneError(f"scene '{self.name}' has no camera")
        else:
            self.camera.validate()
        if not np.isfinite(self.world_color).all():
            raise SceneError(f"scene '{self.name}' has a NaN or infinite world colour")
        w, h = self.resolution
        if w <= 0 or h <= 0:
            raise SceneError(f"scene '{self.name}' has resolution {w}x{h}; both sides must be at least 1")
        return self

    # -- summary (CLI `info`) -----------------------------------------------------------------
    def summary(self) -> dict:
        """Counts, bounds and camera as plain JSON-ready values (the CLI's ``info``)."""
        b = self.world_bounds()
        return {
            "scene": self.name,
            "frame": self.frame,
            "resolution": list(self.resolution),
            "instances": len(self.instances),
            "shadow_casters": int(self.instances.casts_shadow.sum()) if len(self.instances) else 0,
            "sphere_primitives": int(self.instances.sphere.sum()) if len(self.instances) else 0,
            "models": len(self.models),
            "triangles": self.triangle_count,
            "unique_triangles": self.unique_triangle_count,
            "lights": self.lights_by_type(),
            "shadowed_lights": sum(1 for light in self.lights if light.use_shadow),
            "materials": len(self.materials),
            "images": len(self.images),
            "alpha_models": int(self.alpha_models().sum()),
            "camera": None if self.camera is None else {"name": self.camera.name, "type": self.camera.type},
            "world_bounds": None if b is None else {"min": [float(x) for x in b[0]], "max": [float(x) for x in b[1]]},
        }
