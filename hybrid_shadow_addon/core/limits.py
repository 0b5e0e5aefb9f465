"""Hard limits that the scene's encodings impose whatever the GPU, checked before a bake or a
frame reaches it, each failing with one line that names the limit and the number.

The GPU's own limits (render size, texture bytes, lights) are in :mod:`.gpu.context`; the
acceleration structures' index widths next to their packing (``MAX_LEAF_TEXELS`` in
:mod:`.bake.structures.twolevel`, ``MAX_TRIANGLE_RECORDS`` in :mod:`.bake.structures.grid`).
"""
from __future__ import annotations

import os

from .errors import SceneError

#: instances a scene may hold: the G-buffer keeps each pixel's instance index in a float32
#: channel (``shaders/gbuffer.glsl``, exact integers up to 2^24; the reprojection stores it + 1)
#: and the linking membership texture holds 1024 x 16384 instances (``core/gpu/linking.py``).
#: Past it indices would round together: shadows linked to the wrong object, a reprojection
#: that takes one object for another.
MAX_INSTANCES = 1 << 24


def check_instance_count(count: int) -> None:
    """SceneError when a scene has more instances than :data:`MAX_INSTANCES`."""
    if count > MAX_INSTANCES:
        raise SceneError(f"the scene has {count:,} instances; at most {MAX_INSTANCES:,} can be rendered "
                         f"(2^24: the G-buffer keeps instance indices as floats)")


#: the bake's own peak memory per unique triangle and per instance (the two-level BVH's build
#: and its textures), lower bounds of what was measured (369 B and 1.34 KB on top of the scene:
#: ``benchmarks/find_limits.py``)
BAKE_BYTES_PER_TRIANGLE = 300
BAKE_BYTES_PER_INSTANCE = 1000


def host_memory_bytes() -> int:
    """The memory this process can have: the machine's physical memory, or the address-space
    limit (``RLIMIT_AS``) where that is lower; 0 where neither is known."""
    total = 0
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        pass
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY and soft > 0:
            total = min(total, soft) if total else soft
    except (ImportError, AttributeError, ValueError, OSError):
        pass
    return int(max(total, 0))


def process_memory_bytes(pid=None) -> int:
    """The resident memory of process ``pid`` (None: this one), from Linux's ``/proc``; 0
    elsewhere."""
    try:
        with open(f"/proc/{pid or 'self'}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def gib(n: int) -> str:
    """``n`` bytes in GiB, for the limits' messages."""
    return f"{n / 2**30:.2f} GiB"


def check_bake_memory(triangles: int, instances: int) -> None:
    """SceneError when baking ``triangles`` unique triangles and ``instances`` instances needs
    more memory than this process has left (:func:`host_memory_bytes` less what it holds): a
    bake past it is killed by the system, or fails in numpy, after minutes. The need counted is
    a lower bound (``BAKE_BYTES_PER_TRIANGLE``, ``BAKE_BYTES_PER_INSTANCE``)."""
    have = host_memory_bytes()
    if not have:
        return
    left = have - process_memory_bytes()
    need = int(triangles) * BAKE_BYTES_PER_TRIANGLE + int(instances) * BAKE_BYTES_PER_INSTANCE
    if need > left:
        raise SceneError(f"baking {triangles:,} unique triangles and {instances:,} instances needs at least "
                         f"{gib(need)} of memory; this process has {gib(max(left, 0))} left of {gib(have)}")


def out_of_memory(triangles: int, instances: int) -> SceneError:
    """The one-line error of a bake that ran out of memory all the same."""
    return SceneError(f"the bake of {triangles:,} unique triangles and {instances:,} instances ran out of memory "
                      f"(this process may have {gib(host_memory_bytes())})")
