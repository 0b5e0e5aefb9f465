"""A Blender light: sun, point, spot or area, with Blender's parameters and units."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from .arrays import MAX_COORD, as_f32

LIGHT_TYPES = ("SUN", "POINT", "SPOT", "AREA")


@dataclass
class Light:
    """A Blender light. Lights shine along their local -Z axis.

    ``power``: watts for point/spot/area (Blender's ``energy``), irradiance in W/m^2 for a sun
    (Blender's ``energy`` of a sun is its strength). ``radius`` is ``shadow_soft_size`` (point,
    spot); ``angle`` the sun's angular diameter; ``size``/``size_y`` the area light's extent.
    ``spot_size`` is the full cone angle in radians, ``spot_blend`` 0..1. ``receiver_set`` and
    ``blocker_set``: the light set of its receiver collection and the shadow set of its blocker
    collection (light and shadow linking, :mod:`.linking`), -1 where it has none.
    """

    name: str
    type: str
    color: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    power: float = 1000.0
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    use_shadow: bool = True
    radius: float = 0.0
    angle: float = 0.0
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    size: float = 0.0
    size_y: float = 0.0
    area_shape: str = "SQUARE"
    spread: float = float(np.pi)  # area light: full angle of its emission cone (Blender's spread)
    receiver_set: int = -1
    blocker_set: int = -1

    def __post_init__(self):
        self.type = str(self.type).upper()
        self.color = as_f32(self.color).reshape(3)
        self.matrix = np.asarray(self.matrix, np.float64).reshape(4, 4)

    @property
    def position(self) -> np.ndarray:
        """World position (the matrix's translation)."""
        return self.matrix[:3, 3].copy()

    @property
    def direction(self) -> np.ndarray:
        """Unit world direction the light shines towards (local -Z)."""
        d = -self.matrix[:3, 2]
        n = np.linalg.norm(d)
        return d / n if n > 0 else np.array([0.0, 0.0, -1.0])

    def validate(self) -> None:
        """Raise :class:`SceneError` for an unknown type, non-finite values or an unusable transform."""
        if self.type not in LIGHT_TYPES:
            raise SceneError(f"light '{self.name}' has unsupported type {self.type!r}")
        for label, v in (("colour", self.color), ("transform", self.matrix), ("power", self.power),
                         ("radius", self.radius), ("spot size", self.spot_size),
                         ("spot blend", self.spot_blend), ("angle", self.angle), ("spread", self.spread)):
            if not np.isfinite(np.asarray(v, np.float64)).all():
                raise SceneError(f"light '{self.name}' has a NaN or infinite {label}")
        if (np.abs(self.matrix) >= MAX_COORD).any():
            raise SceneError(f"light '{self.name}' has an infinite or absurd transform "
                             f"(a value beyond {MAX_COORD:.0e})")
        for label, s in (("receiver", self.receiver_set), ("blocker", self.blocker_set)):
            if not -1 <= int(s) < 64:
                raise SceneError(f"light '{self.name}' has {label} set {s}; sets are 0..63 (-1: none)")
        if not np.linalg.norm(self.matrix[:3, 2]) > 0:
            raise SceneError(f"light '{self.name}' has a zero-scale matrix (no direction)")


def shadow_key(light: Light) -> tuple:
    """What a light's shadow depends on of the light itself: its colour, power and spot blend
    change no mask."""
    return (light.type, np.asarray(light.matrix, np.float64).tobytes(), float(light.radius), float(light.angle),
            float(light.spot_size), float(light.size), float(light.size_y), str(light.area_shape),
            float(light.spread), int(light.receiver_set), int(light.blocker_set), bool(light.use_shadow))


def changed_shadows(old: list[Light], new: list[Light]) -> list[int] | None:
    """The one rule for a light's stale shadow (the viewport, the scene sync and reuse follow
    it): the indices of the lights of ``new`` whose :func:`shadow_key` differs from ``old``'s;
    None where lights came, went or changed order (by name): every shadow is stale."""
    if [light.name for light in old] != [light.name for light in new]:
        return None
    return [i for i, (a, b) in enumerate(zip(old, new)) if shadow_key(a) != shadow_key(b)]
