"""The shadow configurations ``compare`` and ``bench`` run: named :class:`Variant` objects
(``raytrace-high`` ... ``shadowmap-4096``, ``none``), groups of them, and the parsing of
``--modes``."""
from __future__ import annotations

import re
from dataclasses import dataclass

from ..core.errors import HybridShadowError
from ..core.settings import Settings


@dataclass(frozen=True)
class Variant:
    name: str
    label: str
    settings: Settings


# ``compare`` measures against hard Cycles references (every light made hard): its variants
# render every light hard too
HARD = {"hard": True}


def _variants() -> dict:
    out = {}
    for q in ("high", "medium", "low"):
        out[f"raytrace-{q}"] = Variant(f"raytrace-{q}", f"raytrace {q}", Settings(mode="raytrace", quality=q, **HARD))
    out["raytrace-interlaced"] = Variant("raytrace-interlaced", "raytrace high interlaced",
                                         Settings(mode="raytrace", quality="high", interlace=True, **HARD))
    for s in (512, 1024, 2048, 4096):
        out[f"shadowmap-{s}"] = Variant(f"shadowmap-{s}", f"shadowmap {s}",
                                        Settings(mode="shadowmap", shadowmap_size=s, **HARD))
    out["none"] = Variant("none", "none", Settings(mode="none", **HARD))
    return out


VARIANTS = _variants()
GROUPS = {"raytrace": [k for k in VARIANTS if k.startswith("raytrace")],
          "shadowmap": [k for k in VARIANTS if k.startswith("shadowmap")],
          "all": list(VARIANTS)}


def resolve_variants(names=None) -> list:
    """Variant names (or groups ``raytrace``, ``shadowmap``, ``all``; ``shadowmap-N`` for any
    size N) to :class:`Variant` objects, in the canonical order, without duplicates."""
    if not names:
        names = ["all"]
    picked = []
    for n in names:
        for part in str(n).split(","):
            part = part.strip().lower()
            if not part:
                continue
            if part in GROUPS:
                picked.extend(VARIANTS[k] for k in GROUPS[part])
            elif part in VARIANTS:
                picked.append(VARIANTS[part])
            elif re.fullmatch(r"shadowmap-\d+", part):
                size = int(part.split("-")[1])
                try:
                    picked.append(Variant(part, f"shadowmap {size}",
                                          Settings(mode="shadowmap", shadowmap_size=size, **HARD)))
                except ValueError as e:
                    raise HybridShadowError(f"--modes {part}: {e}") from None
            else:
                raise HybridShadowError(f"unknown mode '{part}': use {', '.join(list(VARIANTS) + list(GROUPS))} "
                                        f"or shadowmap-N")
    seen, out = set(), []
    order = list(VARIANTS)
    for v in sorted(picked, key=lambda v: (order.index(v.name) if v.name in order else len(order), v.name)):
        if v.name not in seen:
            seen.add(v.name)
            out.append(v)
    return out


def as_variants(variants) -> list:
    """:func:`resolve_variants` of names; a list of :class:`Variant` objects as it is."""
    if not variants or isinstance(variants[0], str):
        return resolve_variants(variants)
    return list(variants)
