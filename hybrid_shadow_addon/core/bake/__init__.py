"""Scene -> GPU textures: one acceleration structure (``structures/``: the two-level BVH, the
default, or the thesis' hierarchical grid), packed textures, incremental updates.

Public API::

    baked = bake_scene(scene, BakeConfig())          # BakedScene (BakeConfig(structure="grid"))
    baked.accel      # the AccelerationStructure (structures.TwoLevelBVH / HierarchicalGrid)
    baked.textures   # bvh: {'node', 'leaf'}; grid: {'grid', 'grid_index', 'object', 'model', 'bvh', 'tri'}
    baked.defines    # #defines for shaders/common/scene_data.glsl and the structure's include
    baked.uniforms   # uniform values (grid origin, node sizes, dims, scene max height, ...)
    baked.samplers   # texture name -> sampler uniform name
    baked.stats      # bake ms, bytes per texture, node counts, max objects per node, ...
    report = baked.update_instances(scene, indices)   # after Instances.set_matrices
    report = baked.update_model(scene, model_id)      # edited (or appended) mesh

Texel layouts: next to the GLSL that reads them (``shaders/common/scene_data.glsl`` and the
structure's ``glsl_include``), the one description packer and shader follow.
"""
from .baked import BakedScene, bake_scene
from .report import UpdateReport
from .state import BakeConfig, BVHConfig, GridConfig
from .textures import TextureData

__all__ = ["BVHConfig", "BakeConfig", "BakedScene", "GridConfig", "TextureData", "UpdateReport", "bake_scene"]
