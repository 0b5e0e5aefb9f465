"""Lights that reach no visible surface: the ray-traced pass leaves them out.

A spot light's cone (an area light's front, for a hard one) often holds none of the pixels in
view. Its trace would then write only answers known without a ray, yet cost a whole pass: on a
software rasteriser the walk's code runs for every 8-pixel group, active lanes or not.
:meth:`LightCull.prepare` draws ``shaders/light_cull.glsl`` once per frame, the boxes of the
surface points of each 4x4 block of pixels (bake space, as the rays start from; two per block,
nearer and farther than the middle of its depths, so that a block on a silhouette does not span
the gap behind it), and reads them back; :meth:`LightCull.reaches` tests a light's reach,
widened by a margin, against the bounding sphere of every box. A light it reaches nowhere has no pixel that
needs a ray, so its
mask is what every pixel gets without one (``raytrace.glsl`` HS_NO_RAYS): the same mask,
bit for bit, at the price of one cheap pass per frame for all such lights.

Only lights whose reach is a cone or a half-space are tested: spots (hard, or a sphere of radius
``r``, whose points reach a cone wider by ``asin(r / distance)``) and hard area lights.
"""
from __future__ import annotations

import moderngl
import numpy as np

from ..lights import light_cone, soft_shape
from ..targets import create_texture, set_uniforms

BLOCK = 4
#: a block's bounding sphere is widened by this share of its distance from the light, and the
#: cosine of the reach lowered by COS_MARGIN: far above the float32 error of the shader's tests
REL_MARGIN = 1.0e-4
COS_MARGIN = 1.0e-4


def cull_candidate(light, hard: bool) -> bool:
    """Whether ``light``'s reach can be tested: a spot, or a hard area light."""
    if light.type == "SPOT":
        return True
    return light.type == "AREA" and soft_shape(light, hard) is None


class LightCull:
    def __init__(self, gpu):
        self.ctx = gpu.ctx
        self.programs = gpu.programs
        self._fbo = None
        self._tex = None
        self.centres = self.radii = None  # bounding spheres of the blocks' boxes (bake space)

    def prepare(self, gbuffer, settings, cam_bake) -> None:
        """Draw and read back the blocks' boxes of this frame's G-buffer."""
        w, h = gbuffer.size
        bw, bh = -(-w // BLOCK), -(-h // BLOCK)
        if self._tex is None or self._tex[0].size != (bw, bh):
            self.release()
            self._tex = [create_texture(self.ctx, bw, bh, 4, "f4") for _ in range(4)]
            self._fbo = self.ctx.framebuffer(color_attachments=self._tex)
        defines = {"HS_CULL_BLOCK": BLOCK}
        if settings.max_distance > 0:
            defines["HS_MAX_DISTANCE"] = 1
        prog, vao = self.programs.fullscreen("light_cull", defines)
        gbuffer.bind(prog)
        set_uniforms(prog, {"u_full_size": (w, h), "u_cam_bake": tuple(float(v) for v in cam_bake),
                            "u_max_distance": float(settings.max_distance)})
        self._fbo.use()
        self.ctx.viewport = (0, 0, bw, bh)
        vao.render(moderngl.TRIANGLES, vertices=3)
        got = [np.frombuffer(self._fbo.read(components=4, dtype="f4", attachment=k), np.float32).reshape(-1, 4)
               for k in range(4)]
        lo = np.concatenate([got[0], got[2]])
        hi = np.concatenate([got[1], got[3]])
        used = lo[:, 3] > 0.5
        lo = lo[used, :3].astype(np.float64)
        hi = hi[used, :3].astype(np.float64)
        self.centres = 0.5 * (lo + hi)
        self.radii = 0.5 * np.linalg.norm(hi - lo, axis=1)

    def reaches(self, light, light_pos, hard: bool) -> bool:
        """Whether ``light`` (at ``light_pos``, bake space) may reach a visible surface point:
        False only where no pixel of the frame needs a ray of it."""
        if self.centres is None:
            return True
        if not len(self.centres):
            return False  # nothing in view within the max distance
        if not cull_candidate(light, hard):
            return True
        axis, cone = light_cone(light)
        axis = np.asarray(axis, np.float64)
        axis = axis / max(np.linalg.norm(axis), 1e-300)
        v = self.centres - np.asarray(light_pos, np.float64)
        dist = np.linalg.norm(v, axis=1)
        r = self.radii * (1.0 + REL_MARGIN) + REL_MARGIN * dist + 1e-6
        inside = dist <= r
        if inside.any():
            return True
        cos_c = np.clip((v @ axis) / dist, -1.0, 1.0)
        theta = np.arccos(cos_c) - np.arcsin(np.minimum(r / dist, 1.0))  # the sphere's nearest angle
        soft = soft_shape(light, hard)
        if soft is not None:  # a sphere light's points reach a cone wider by asin(radius / distance)
            theta -= np.arcsin(np.minimum(soft["u_light_radius"] / np.maximum(dist - r, 1e-300), 1.0))
        theta = np.maximum(theta, 0.0)
        return bool((np.cos(theta) > cone - COS_MARGIN).any())

    def release(self) -> None:
        if self._fbo is not None:
            self._fbo.release()
            self._fbo = None
        for t in self._tex or ():
            t.release()
        self._tex = None
        self.centres = self.radii = None

