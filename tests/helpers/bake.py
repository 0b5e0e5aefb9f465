"""Checks shared by the bake tests: the structured tracer against brute force, and an incremental
update's report against the texels it changed."""
import numpy as np

from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured


def assert_equal_tracers(scene, baked, o, d, t):
    """The structured tracer equals brute force on every ray; returns its hits."""
    a = trace_structured(baked, o, d, t)
    b = trace_brute(scene, o, d, t)
    bad = np.nonzero(a != b)[0]
    assert bad.size == 0, f"{bad.size} rays differ, first {bad[:5]}: structured {a[bad[:5]]}"
    return a


def snapshot(baked):
    """A copy of every texture's texels of ``baked``, to compare after an update."""
    return {k: t.data.copy() for k, t in baked.textures.items()}


def assert_report_covers(baked, before, rep):
    """Every texel that changed lies in a reported row range (or a resized texture)."""
    for name, tex in baked.textures.items():
        if name in rep.resized:
            continue
        old = before[name]
        assert old.shape == tex.data.shape
        diff = (old != tex.data).any(axis=(2, 3))  # (layers, height)
        covered = np.zeros_like(diff)
        for n, layer, y0, y1 in rep.ranges:
            if n == name:
                covered[layer, y0:y1] = True
        assert not (diff & ~covered).any(), f"{name}: changed rows not reported"
