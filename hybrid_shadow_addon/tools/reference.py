"""The reference ``compare`` measures against: what a reference renderer must provide
(:class:`ReferenceProvider`), and the on-disk cache of its renders, keyed by a hash of the scene.

The Blender side implements the provider with Cycles (``CyclesReferenceProvider`` in its
``cycles_reference`` module) and passes it in; nothing here imports bpy.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from ..core.scene import Scene


class ReferenceProvider(Protocol):
    """Per-light shadow visibility from a reference renderer.

    - ``name``: the renderer (``"Cycles"``); names the reference in progress labels and the
      default cache folder.
    - ``version``: the renderer's version string (``metrics.json``'s ``bpy_version``).
    - ``recipe_version``: bumped when the way the reference is rendered changes (an int, or any
      value that also marks the provider's options that change what it renders).

    - ``hard`` (optional, default True): the lights are made hard for the reference (point-like,
      as ``compare``'s hard variants); False keeps their sizes (soft shadows, ``compare --soft``).

    ``version``, ``recipe_version`` and ``hard`` are part of the cache key: a change of any renders
    the reference again.
    """

    name: str
    version: str
    recipe_version: object

    def light_names(self, scene: Scene) -> list:
        """Names of the lights of ``scene`` the reference can render, one at a time."""
        ...

    def visibility(self, scene: Scene, light: str, resolution: tuple, samples: int) -> tuple:
        """``(visibility, ms)``: the (H, W) float32 visibility of ``light`` alone at
        ``resolution`` (1 lit, 0 shadowed, NaN invalid) and the time it took in ms."""
        ...


# ------------------------------------------------------------------------------------------------
# Scene hash
# ------------------------------------------------------------------------------------------------
def _feed(h, obj) -> None:
    if is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in fields(obj):
            h.update(f.name.encode())
            _feed(h, getattr(obj, f.name))
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            h.update(repr(k).encode())
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"seq{len(obj)}".encode())
        for v in obj:
            _feed(h, v)
    else:
        h.update(repr(obj).encode())


def scene_hash(scene) -> str:
    """SHA-256 of everything in a core scene (geometry, instances, lights, camera), or of any
    nesting of dataclasses, arrays, dicts and sequences."""
    h = hashlib.sha256()
    _feed(h, scene)
    return h.hexdigest()


# ------------------------------------------------------------------------------------------------
# Cache
# ------------------------------------------------------------------------------------------------
def reference_key(scene, resolution, samples: int, light_names, provider: ReferenceProvider,
                  soft: bool = False) -> str:
    """The cache key of a reference: the scene, the resolution, the samples, the lights, the
    provider's recipe and version, and whether the lights kept their sizes (``soft``: a soft
    reference never answers for a hard one; hard keys are those of before soft references)."""
    h = hashlib.sha256()
    parts = [scene_hash(scene), list(resolution), int(samples), list(light_names), provider.recipe_version,
             provider.version]
    if soft:
        parts.append("soft")
    _feed(h, parts)
    return h.hexdigest()[:24]


def default_cache_dir(provider: ReferenceProvider) -> Path:
    """``$XDG_CACHE_HOME/hybrid_shadows/<renderer>`` (``~/.cache`` without the variable)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "hybrid_shadows" / (re.sub(r"[^\w.-]+", "_", provider.name.lower()) or "reference")


def load_cached(path: Path):
    """``(visibility per light, render ms per light)`` from a cache file, or None."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            vis = {n: z[f"vis{i}"].astype(np.float32) for i, n in enumerate(meta["lights"])}
        return vis, meta["render_ms"]
    except (OSError, KeyError, ValueError):
        return None


def save_cached(path: Path, visibility: dict, render_ms: dict) -> None:
    """Write a cache file atomically (a temporary file renamed into place)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(visibility)
    arrays = {f"vis{i}": visibility[n] for i, n in enumerate(names)}
    meta = json.dumps({"lights": names, "render_ms": render_ms})
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, meta=np.array(meta), **arrays)
    os.replace(tmp, path)
