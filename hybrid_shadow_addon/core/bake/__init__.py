"""Scene -> GPU textures: hierarchical 2D grid over per-model BVHs (``structure="grid"``) or a
two-level BVH (``structure="bvh"``, twolevel.py), packed textures, incremental updates.

Public API::

    baked = bake_scene(scene, BakeConfig())          # BakedScene (BakeConfig(structure="bvh"))
    baked.textures   # grid: {'grid', 'grid_index', 'object', 'model', 'bvh', 'tri'}; bvh: {'node', 'leaf'}
    baked.defines    # #defines for shaders/common/scene_data.glsl
    baked.uniforms   # uniform values (grid origin, node sizes, dims, scene max height, ...)
    baked.samplers   # texture name -> sampler uniform name
    baked.stats      # bake ms, bytes per texture, node counts, max objects per node, ...
    report = baked.update_instances(scene, indices)   # after Instances.set_matrices
    report = baked.update_model(scene, model_id)      # edited (or appended) mesh

Texel layouts: ``shaders/common/scene_data.glsl`` (the one description packer and shader follow).
"""
from .baked import BakedScene, bake_scene
from .state import BakeConfig, UpdateReport
from .textures import TextureData

__all__ = ["BakeConfig", "BakedScene", "TextureData", "UpdateReport", "bake_scene"]
