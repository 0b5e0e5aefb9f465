"""The passes of a frame, one class each over one interface (:class:`.base.Pass`):
G-buffer, the shadow modes (ray traced, shadow maps, none), upsample, lighting."""
from .base import Pass, ShadowPass
from .gbuffer import GBufferPass
from .lighting import LightingPass
from .noshadow import NoShadowPass
from .raytrace import RaytracePass
from .shadowmap import ShadowMapPass
from .upsample import UpsamplePass

__all__ = ["Pass", "ShadowPass", "GBufferPass", "LightingPass", "NoShadowPass", "RaytracePass", "ShadowMapPass",
           "UpsamplePass"]
