"""Array coercion and limits shared by the scene dataclasses."""
from __future__ import annotations

import numpy as np

#: transforms with a value this large are rejected (Blender stores an infinite scale as FLT_MAX)
MAX_COORD = 1e18


def as_f32(a, shape_tail=None) -> np.ndarray:
    """``a`` as a contiguous float32 array, reshaped to ``(-1, *shape_tail)`` when given."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    if shape_tail is not None:
        a = a.reshape((-1,) + tuple(shape_tail))
    return a
