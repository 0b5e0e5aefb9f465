"""Acceleration structures behind one interface (:class:`AccelerationStructure`): the registry of
the structures a bake can build and the one default.

- ``"bvh"`` :class:`TwoLevelBVH` (the default): SAH model trees under an SAH tree over instances.
- ``"grid"`` :class:`HierarchicalGrid`: the thesis' hierarchical grid over per-model BVHs.
"""
from .base import AccelerationStructure, ModelSlots
from .grid import HierarchicalGrid
from .twolevel import TwoLevelBVH

#: name -> class of every structure a bake can build
STRUCTURES: dict[str, type[AccelerationStructure]] = {cls.name: cls for cls in (HierarchicalGrid, TwoLevelBVH)}
#: the structure ``Settings``, ``BakeConfig``, the CLI and Blender use unless told otherwise
DEFAULT_STRUCTURE = TwoLevelBVH.name


def structure_class(name: str) -> type[AccelerationStructure]:
    """The structure registered as ``name``."""
    try:
        return STRUCTURES[name]
    except KeyError:
        raise ValueError(f"structure must be one of {', '.join(STRUCTURES)}, not {name!r}") from None


__all__ = ["DEFAULT_STRUCTURE", "STRUCTURES", "AccelerationStructure", "HierarchicalGrid", "ModelSlots",
           "TwoLevelBVH", "structure_class"]
