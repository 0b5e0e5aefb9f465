"""The bpy-free scene model: plain dataclasses over numpy arrays.

Conventions (Blender's): right-handed, Z up, metres. Matrices are 4x4 float64, column vectors
(``p_world = M @ [x, y, z, 1]``), exactly as ``Object.matrix_world`` reads in numpy.

- :class:`Model` (:mod:`.models`): one unique mesh (model space): float32 vertices, uint32
  triangles, bounds and a bounding sphere. Many instances share one model.
- :class:`Instances` (:mod:`.instances`): every placed object as a structure of arrays (one row
  per instance), so 100k instances cost arrays, not Python objects.
- :class:`Light` (:mod:`.lights`): sun, point, spot, area (Blender's parameters and units).
- :class:`Camera` (:mod:`.camera`): perspective or orthographic with Blender's sensor fit, shift
  and clip range.
- :class:`Image`, :class:`Material` (:mod:`.materials`): textures and the alpha of
  textured/cut-out materials (foliage cards, fences), referenced by instances through
  ``Instances.material_ids``.
- :class:`Scene` (:mod:`.scene`): all of the above plus the world colour and the render resolution.

``Scene.validate()`` rejects NaN/inf (and other unusable values) with a message naming the object.
"""
from ..errors import SceneError
from .arrays import MAX_COORD
from .camera import CAMERA_TYPES, SENSOR_FITS, Camera
from .instances import Instances, affine_inverse, max_scale
from .lights import LIGHT_TYPES, Light
from .materials import ALPHA_CHANNELS, ALPHA_MODES, IMAGE_EXTENSIONS, IMAGE_INTERPOLATIONS, LUMA, Image, Material
from .models import Model
from .scene import Scene

__all__ = [
    "ALPHA_CHANNELS", "ALPHA_MODES", "CAMERA_TYPES", "IMAGE_EXTENSIONS", "IMAGE_INTERPOLATIONS", "LIGHT_TYPES",
    "LUMA", "MAX_COORD", "SENSOR_FITS", "Camera", "Image", "Instances", "Light", "Material", "Model", "Scene",
    "SceneError", "affine_inverse", "max_scale",
]
