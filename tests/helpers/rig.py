"""Runs single passes outside the pipeline (``PassRig``), each on a FrameJob built from the arguments."""
from hybrid_shadow_addon.core.gpu.context import make_current
from hybrid_shadow_addon.core.gpu.frame import FrameJob
from hybrid_shadow_addon.core.gpu.lights import select_shadowed_lights
from hybrid_shadow_addon.core.gpu.passes import GBufferPass, LightingPass, NoShadowPass, ShadowMapPass, UpsamplePass
from hybrid_shadow_addon.core.gpu.resources import GpuResources
from hybrid_shadow_addon.core.gpu.targets import read_texture
from hybrid_shadow_addon.core.settings import Settings


class PassRig:
    """Every method makes the rig's context current first, as the pipeline's entry points do: a
    test that ran the CLI (which creates its own context) before would otherwise draw into that
    one."""

    def __init__(self, ctx):
        self.ctx = ctx
        make_current(ctx)
        self.gpu = GpuResources(ctx)
        self.gbuffer_pass = GBufferPass(self.gpu)
        self.shadowmap_pass = ShadowMapPass(self.gpu)
        self.none_pass = NoShadowPass(self.gpu)
        self.lighting = LightingPass(self.gpu)
        self.upsample_pass = UpsamplePass(self.gpu)
        self._image = None

    @staticmethod
    def _job(scene, gb, settings, lights=None, masks=None):
        settings = settings or Settings()
        lights = select_shadowed_lights(scene, settings) if lights is None else list(lights)
        w, h = (gb.width, gb.height) if gb is not None else scene.resolution
        return FrameJob(scene, settings, w, h, lights=lights, gbuffer=gb, masks=dict(masks or {}))

    def gbuffer(self, scene, width, height):
        make_current(self.ctx)
        return self.gbuffer_pass.render(FrameJob(scene, Settings(), width, height))

    def shadowmap(self, scene, gb, settings, lights=None):
        make_current(self.ctx)
        return self.shadowmap_pass.render(self._job(scene, gb, settings, lights))

    def none(self, scene, gb, settings=None, lights=None):
        make_current(self.ctx)
        return self.none_pass.render(self._job(scene, gb, settings, lights))

    def light(self, scene, gb, masks=None, settings=None):
        make_current(self.ctx)
        self._image = self.lighting.render(self._job(scene, gb, settings, masks=masks))
        return self._image

    def image(self):
        make_current(self.ctx)
        return read_texture(self._image)

    def upsample(self, masks, gb, settings=None):
        make_current(self.ctx)
        job = FrameJob(None, settings, gb.width, gb.height, gbuffer=gb, masks=dict(masks))
        return self.upsample_pass.render(job)

    def release(self):
        make_current(self.ctx)
        for p in (self.gbuffer_pass, self.shadowmap_pass, self.none_pass, self.lighting, self.upsample_pass):
            p.release()
        self.gpu.release()
