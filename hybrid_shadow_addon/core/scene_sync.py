"""Keep a pipeline's bake in step with a scene that changes from frame to frame.

:func:`sync_scene` compares the previous frame's :class:`~.scene.Scene` with the next one and
applies the difference to the pipeline's bake: moved (or re-flagged) instances become
``move_instances``, edited or added meshes ``update_model``; what the bake cannot update in
place (instances added or removed, renamed ones, changed textured materials or images) is a full
bake. Camera, light and flat-colour changes need no bake; a pipeline that reuses visibility
forgets the history of changed lights only (:func:`forget_changed_lights`), another one all.

Instances are matched by name (``Instances.names``), models by name and content. The next scene
is aligned to the previous one in place, as the bake's indices require: its instance rows in the
previous order, its models in the previous ids (unchanged meshes keep the previous ``Model``
object, so the GPU's vertex buffers are reused), new meshes appended.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .bake.materials import material_signature
from .scene import Scene
from .scene.lights import changed_shadows

FULL, INCREMENTAL, NONE = "full", "incremental", "none"

#: models no instance uses any more (kept at their ids) beyond this share: bake afresh
STALE_MODEL_FRACTION = 0.5


@dataclass
class SyncReport:
    """What :func:`sync_scene` did: ``kind`` (``full``, ``incremental`` or ``none``), the
    instance rows and model ids it updated, the bake or update time and why it baked in full."""

    kind: str
    moved: list = field(default_factory=list)
    models: list = field(default_factory=list)
    ms: float = 0.0
    reason: str = ""


def same_model(a, b) -> bool:
    """Same mesh content (shapes first, then the arrays)."""
    if a is b:
        return True
    if a.vertices.shape != b.vertices.shape or a.triangles.shape != b.triangles.shape:
        return False
    if (a.normals is None) != (b.normals is None) or (a.uvs is None) != (b.uvs is None):
        return False
    return (np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)
            and (a.normals is None or np.array_equal(a.normals, b.normals))
            and (a.uvs is None or np.array_equal(a.uvs, b.uvs)))


def _align_instances(prev: Scene, scene: Scene) -> bool:
    """Reorder ``scene``'s instance rows to ``prev``'s names; False when the names differ
    (added, removed or duplicate names)."""
    old, new = prev.instances.names, scene.instances.names
    if old == new:
        return True
    if len(old) != len(new):
        return False
    pos = {n: i for i, n in enumerate(new)}
    if len(pos) != len(new):
        return False
    try:
        order = np.fromiter((pos[n] for n in old), np.int64, len(old))
    except KeyError:
        return False
    scene.instances = scene.instances.take(order)
    return True


def _align_models(prev: Scene, scene: Scene):
    """Give ``scene``'s models ``prev``'s ids (unchanged ones: ``prev``'s objects); returns the
    ids whose mesh changed or is new, in ascending order."""
    by_name: dict = {}
    for i, m in enumerate(prev.models):
        by_name.setdefault(m.name, []).append(i)
    models = list(prev.models)  # ids of meshes gone stay, unused
    taken = set()
    remap = np.empty(len(scene.models), np.int64)
    changed = []
    for j, m in enumerate(scene.models):
        cands = [i for i in by_name.get(m.name, ()) if i not in taken]
        hit = next((i for i in cands if same_model(prev.models[i], m)), None)
        if hit is not None:
            remap[j] = hit  # the previous object: its bake and vertex buffers still hold
        elif cands:
            remap[j] = hit = cands[0]
            models[hit] = m
            changed.append(hit)
        else:
            remap[j] = hit = len(models)
            models.append(m)
            changed.append(hit)
        taken.add(int(hit))
    scene.models = models
    if len(scene.instances):
        scene.instances.model_ids = remap[scene.instances.model_ids].astype(np.int32)
    return sorted(changed)


def forget_changed_lights(pipeline, prev: Scene, scene: Scene) -> None:
    """History after an update: a pipeline that reuses visibility (``Pipeline.reuse``) forgets
    only the lights that changed (its edits and camera it follows itself); another one, all."""
    changed = changed_shadows(prev.lights, scene.lights)
    if not getattr(pipeline, "reuse", False) or changed is None:
        pipeline.reset_history()
        return
    for i in changed:
        pipeline.reset_light(i)


def _bake(pipeline, scene, reason: str, structure) -> SyncReport:
    return SyncReport(FULL, ms=pipeline.set_scene(scene, structure), reason=reason)


def sync_scene(pipeline, prev: Scene | None, scene: Scene, *, bake: bool = True,
               structure: str | None = None) -> SyncReport:
    """Bring ``pipeline``'s bake from ``prev`` (what it holds; None: nothing) to ``scene``
    (aligned to ``prev`` in place, see the module). ``bake=False`` (a mode without ray tracing):
    no bake is made or updated, but an existing one is dropped when the geometry changed.
    ``structure``: the acceleration structure wanted (``Settings.structure``); a bake of
    another one is made afresh."""
    if not bake:
        if pipeline.baked is not None and (prev is None or _geometry_changed(prev, scene)):
            pipeline.baked = None  # stale: the next ray-traced frame bakes afresh
        pipeline.reset_history()
        return SyncReport(NONE)
    if prev is None or pipeline.baked is None:
        return _bake(pipeline, scene, "first frame", structure)
    if structure is not None and getattr(pipeline.baked, "structure", structure) != structure:
        return _bake(pipeline, scene, f"acceleration structure changed to {structure}", structure)
    if not _align_instances(prev, scene):
        return _bake(pipeline, scene, "instances added, removed or renamed", structure)
    if material_signature(prev) != material_signature(scene) or (
            len(scene.instances) and (prev.instances.material_ids != scene.instances.material_ids).any()):
        return _bake(pipeline, scene, "materials or images changed", structure)
    t0 = time.perf_counter()
    changed = _align_models(prev, scene)
    stale = len(scene.models) - len(set(scene.instances.model_ids.tolist()) if len(scene.instances) else set())
    if stale > STALE_MODEL_FRACTION * max(len(scene.models), 1) and stale > 4:
        return _bake(pipeline, scene, "most meshes are gone", structure)
    a, b = prev.instances, scene.instances
    moved = np.zeros(len(b), bool)
    if len(b):
        moved = ((a.matrices != b.matrices).any(axis=(1, 2)) | (a.casts_shadow != b.casts_shadow)
                 | (a.sphere != b.sphere) | (a.model_ids != b.model_ids))
    if changed and len(b):
        moved &= ~np.isin(b.model_ids, changed)  # update_model re-places its users
    for m in changed:
        pipeline.update_model(scene, m)
    idx = np.nonzero(moved)[0]
    if idx.size:
        pipeline.move_instances(scene, idx)
    forget_changed_lights(pipeline, prev, scene)
    if not changed and not idx.size:
        return SyncReport(NONE)
    return SyncReport(INCREMENTAL, moved=idx.tolist(), models=list(changed), ms=(time.perf_counter() - t0) * 1e3)


def _geometry_changed(prev: Scene, scene: Scene) -> bool:
    a, b = prev.instances, scene.instances
    if a.names != b.names or len(prev.models) != len(scene.models):
        return True
    if not all(same_model(x, y) for x, y in zip(prev.models, scene.models)):
        return True
    return bool(len(b) and ((a.matrices != b.matrices).any() or (a.casts_shadow != b.casts_shadow).any()
                            or (a.sphere != b.sphere).any() or (a.model_ids != b.model_ids).any()))
