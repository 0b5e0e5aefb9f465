"""Shadow mode ``shadowmap``: one depth map per shadowed light, then a full-screen mask per light.

- sun: orthographic map fitted to the camera frustum (far end clipped to the scene bounds and
  ``Settings.max_distance``), intersected with the scene bounds, depth range covering all
  casters;
- spot: perspective map over the cone (spots wider than 120 degrees use a cube);
- point (and area, treated as a point for now): a cube of six perspective views in a 3x2 atlas.

Maps store linear light depth (MIN blending, no depth-buffer precision issues). The mask uses
slope-scaled bias and normal offset, both in texels at the receiver, and (2r+1)^2 PCF taps.
A light with a size (``lights.soft_shape``; not with ``Settings.hard``) gets percentage-closer
soft shadows instead, the mask program's ``HS_PCSS`` variant (``shaders/shadowmap_mask.glsl``):
a blocker search, the penumbra from the mean blocker depth and ``Settings.pcss_samples`` PCF
taps shaped like the light, the kernel at most ``PCSS_MAX_KERNEL`` of the map's side in radius.
Output: ``dict[light_index, R32F texture]`` at G-buffer resolution (1 lit, 0 shadowed).
"""
from __future__ import annotations

import math
import zlib

import moderngl
import numpy as np

from ...scene.linking import blockers
from ..geometry import CasterDraws, alpha_caster_rows
from ..lights import soft_shape
from ..projection import CUBE_AXES, look_basis, ortho, perspective, view_from_rel
from ..targets import Target, TargetCache, create_texture, set_uniforms
from .base import ShadowPass

WIDE_SPOT = math.radians(120.0)
PCSS_MAX_KERNEL = 1.0 / 8.0  # largest PCSS search / filter radius, a share of a map's side


def _box_corners(bmin, bmax) -> np.ndarray:
    return np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1]) for z in (bmin[2], bmax[2])])


def frustum_corners_rel(cam, far: float) -> np.ndarray:
    """(8, 3) camera frustum corners (camera-relative world) from clip start to ``far``."""
    left, right, bottom, top = cam.viewplane
    n = cam.clip_start
    pts = []
    for z in (n, far):
        s = 1.0 if cam.ortho else z / n
        for x in (left, right):
            for y in (bottom, top):
                pts.append((x * s, y * s, -z))
    return np.array(pts) @ cam.cam_rot.T


class LightViews:
    """The views of one light's shadow map (float64, camera-relative)."""

    def __init__(self, kind, matrices, forwards, tiles, atlas_size, texel_world, light_pos_rel, light_dir,
                 depth_min=0.0):
        self.kind = kind  # 'sun' | 'spot' | 'cube'
        self.matrices = matrices  # list of (4, 4) clip_from_rel
        self.forwards = forwards  # list of (3,)
        self.tiles = tiles  # list of (x0, y0, size)
        self.atlas_size = atlas_size  # (w, h)
        self.texel_world = texel_world
        self.light_pos_rel = light_pos_rel
        self.light_dir = light_dir
        # the least "light depth" of a caster (PCSS's blocker search goes no nearer): sun, the
        # scene bounds' least depth along the light; area, their least distance in front of its
        # plane; point/spot, the light's distance to them (0 inside)
        self.depth_min = depth_min


def light_views(scene, light, cam, settings, max_texture: int = 16384) -> LightViews | None:
    """Fit the shadow-map views of ``light``; None when nothing can cast into the view."""
    bounds = scene.world_bounds()
    if bounds is None:
        return None
    corners = _box_corners(*bounds) - cam.cam_pos
    size = int(min(settings.shadowmap_size, max_texture))
    margin = 2 * (settings.pcf + 2)
    if light.type == "SUN":
        f = light.direction
        basis = look_basis(f, light.matrix[:3, 1])
        depth_view = -(corners @ cam.cam_rot[:, 2])
        far = min(float(depth_view.max()), float(scene.camera.clip_end))
        if settings.max_distance > 0:
            far = min(far, settings.max_distance)
        far = max(far, cam.clip_start * 1.001)
        fr = frustum_corners_rel(cam, far) @ basis
        sc = corners @ basis
        lo = np.maximum(fr[:, :2].min(0), sc[:, :2].min(0))
        hi = np.minimum(fr[:, :2].max(0), sc[:, :2].max(0))
        if np.any(hi <= lo):
            return None
        ext = float((hi - lo).max()) * (1 + 2 * margin / size) + 1e-6
        c = (lo + hi) / 2
        zmin, zmax = float((-sc[:, 2]).min()), float((-sc[:, 2]).max())
        pad = 1e-3 * (zmax - zmin) + 1e-4
        proj = ortho(c[0] - ext / 2, c[0] + ext / 2, c[1] - ext / 2, c[1] + ext / 2, zmin - pad, zmax + pad)
        m = proj @ view_from_rel(basis, np.zeros(3))
        return LightViews("sun", [m], [f], [(0, 0, size)], (size, size), ext / size, np.zeros(3), f, zmin)
    pos_rel = light.position - cam.cam_pos
    if light.type == "AREA":
        depth_min = max(0.0, float(((corners - pos_rel) @ light.direction).min()))
    else:
        depth_min = float(np.linalg.norm(np.clip(light.position, *bounds) - light.position))
    far = float(np.linalg.norm(corners - pos_rel, axis=1).max()) * 1.01 + 1e-3
    near = max(far * 1e-5, 1e-6)
    if light.type == "SPOT" and light.spot_size <= WIDE_SPOT:
        f = light.direction
        tan_half = math.tan(light.spot_size / 2) * (1 + 2 * margin / size)
        basis = look_basis(f, light.matrix[:3, 1])
        m = perspective(tan_half, near, far) @ view_from_rel(basis, pos_rel)
        return LightViews("spot", [m], [f], [(0, 0, size)], (size, size), 2 * tan_half / size, pos_rel, f,
                          depth_min)
    size = int(min(size, max_texture // 3))
    tan_half = 1.0 + 2 * margin / size
    mats, fwds, tiles = [], [], []
    for k, axis in enumerate(CUBE_AXES):
        f = np.array(axis, np.float64)
        basis = look_basis(f, (0, 1, 0) if abs(f[2]) > 0.5 else (0, 0, 1))
        mats.append(perspective(tan_half, near, far) @ view_from_rel(basis, pos_rel))
        fwds.append(f)
        tiles.append(((k % 3) * size, (k // 3) * size, size))
    return LightViews("cube", mats, fwds, tiles, (3 * size, 2 * size), 2 * tan_half / size, pos_rel, light.direction,
                      depth_min)


class ShadowMapPass(ShadowPass):
    """Masks ``{light index: texture}`` at G-buffer resolution (1 lit, 0 shadowed)."""

    light_label = "Shadow map"

    def __init__(self, gpu):
        super().__init__(gpu)
        self.casters = CasterDraws(self.ctx, gpu.models)
        self._atlas: Target | None = None
        self._masks = TargetCache(self.ctx, what="mask")
        self.views: dict = {}  # light index -> LightViews of the last render (for debugging/tests)
        self.last_defines: set = set()  # "NAME=value" of the mask programs of the last render

    def _atlas_target(self, w, h) -> Target:
        """The depth atlas, grown (never shrunk) to hold ``w`` x ``h``."""
        a = self._atlas
        if a is None or a.texture.width < w or a.texture.height < h:
            aw, ah = (w, h) if a is None else (max(w, a.texture.width), max(h, a.texture.height))
            if a is not None:
                a.release()
            tex = create_texture(self.ctx, aw, ah)
            self._atlas = Target(tex, self.ctx.framebuffer(color_attachments=[tex]))
        return self._atlas

    def render(self, job) -> dict:
        ctx = self.ctx
        scene, gbuffer, settings = job.scene, job.gbuffer, job.settings
        cam = gbuffer.camera
        max_tex = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
        depth_prog = self.programs.get("shadowmap_depth")
        casters = np.nonzero(scene.instances.casts_shadow)[0] if len(scene.instances) else np.zeros(0, np.int64)
        alpha_prog = self.programs.get("shadowmap_depth", {"ALPHA": 1}) if alpha_caster_rows(scene, casters).any() \
            else None
        progs = [depth_prog] if alpha_prog is None else [depth_prog, alpha_prog]
        if alpha_prog is not None:
            self.gpu.bind_materials(alpha_prog, scene)
        draws = self._draws(scene, casters, cam.cam_pos, depth_prog, alpha_prog)
        linking = self.gpu.linking
        linking.update(scene)
        linked_draws = {}  # blocker set -> the draws of its casters (shadow linking)
        out = {}
        self.views = {}
        self.last_defines = set()
        for li in job.lights:
            job.light_started(li)
            light = scene.lights[li]
            mask = self._masks.get(li, *gbuffer.size)
            out[li] = mask.texture
            views = light_views(scene, light, cam, settings, max_tex)
            self.views[li] = views
            light_draws = draws
            if light.blocker_set >= 0:
                if light.blocker_set not in linked_draws:
                    linked_draws[light.blocker_set] = self._draws(
                        scene, np.nonzero(blockers(scene, light))[0], cam.cam_pos, depth_prog, alpha_prog,
                        ("link", light.blocker_set))
                light_draws = linked_draws[light.blocker_set]
            if views is None or (not light_draws and not linking.active):
                mask.texture.write(np.ones((gbuffer.height, gbuffer.width), np.float32).tobytes())
                continue
            # 1. depth maps
            atlas = self._atlas_target(*views.atlas_size)
            fbo = atlas.fbo
            fbo.use()
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            ctx.enable(moderngl.BLEND)
            ctx.blend_equation = moderngl.MIN
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            for m, f, (x0, y0, s) in zip(views.matrices, views.forwards, views.tiles):
                fbo.clear(1e30, 1e30, 1e30, 1e30, viewport=(x0, y0, s, s))
                ctx.viewport = (x0, y0, s, s)
                for prog in progs:
                    prog["u_light_clip_from_rel"].write(m.T.astype("f4").tobytes())
                    prog["u_light_origin_rel"].value = tuple(views.light_pos_rel)
                    prog["u_light_fwd"].value = tuple(f)
                for _, dvao, nverts, ninst in light_draws:
                    dvao.render(moderngl.TRIANGLES, vertices=nverts, instances=ninst)
            ctx.disable(moderngl.BLEND)
            ctx.blend_equation = moderngl.FUNC_ADD
            # 2. mask
            soft = soft_shape(light, settings.hard)
            defines = {} if soft is None else {"HS_PCSS": 1, "HS_SOFT_SHAPE": int(soft["shape"])}
            defines.update(linking.defines)
            self.last_defines.update(f"{k}={v}" for k, v in defines.items())
            mask_prog, vao = self.programs.fullscreen("shadowmap_mask", defines)
            mask.use(ctx)
            unit = gbuffer.bind(mask_prog)
            unit = linking.bind(mask_prog, unit)
            set_uniforms(mask_prog, linking.light_uniforms(light))
            atlas.texture.use(unit)
            mask_prog["u_shadowmap"].value = unit
            mats = np.zeros((6, 4, 4), np.float32)
            fwds = np.zeros((6, 3), np.float32)
            tiles = np.zeros((6, 4), np.float32)
            for k, (m, f, t) in enumerate(zip(views.matrices, views.forwards, views.tiles)):
                mats[k], fwds[k], tiles[k, :3] = m.T, f, t
            set_uniforms(mask_prog, {
                "u_view_clip_from_rel": mats.tobytes(), "u_view_fwd": fwds.tobytes(),
                "u_view_tile": tiles.tobytes(),
                "u_cube": int(views.kind == "cube"), "u_ortho_light": int(views.kind == "sun"),
                "u_light_pos_rel": tuple(float(v) for v in views.light_pos_rel),
                "u_light_dir": tuple(float(v) for v in views.light_dir),
                "u_texel_world": float(views.texel_world), "u_bias": float(settings.shadow_bias),
                "u_slope_bias": float(settings.slope_bias), "u_normal_offset": float(settings.normal_offset),
                "u_pcf": int(settings.pcf), "u_max_distance": float(settings.max_distance)})
            if soft is not None:
                set_uniforms(mask_prog, {
                    **{k: v for k, v in soft.items() if k != "shape"},
                    "u_filter_taps": int(settings.pcss_samples),
                    "u_search_taps": max(4, int(settings.pcss_samples) // 2),
                    "u_max_kernel": float(PCSS_MAX_KERNEL * views.tiles[0][2]),
                    "u_depth_min": float(views.depth_min),
                    "u_seed": zlib.crc32(light.name.encode("utf-8")) & 0x7FFFFFFF})
            self.gpu.budget.draw(vao, gbuffer.size)
        return out

    def _draws(self, scene, rows, origin, depth_prog, alpha_prog, tag=()) -> list:
        """``[(prog, vao, vertex count, instance count)]`` of the casters ``rows``: the
        alpha-cut ones with ``alpha_prog``, the others with ``depth_prog``."""
        cut = alpha_caster_rows(scene, rows)
        draws = [(depth_prog, *d) for d in self.casters.build(scene, rows[~cut], origin, depth_prog, tag)]
        if cut.any():
            draws += [(alpha_prog, *d) for d in self.casters.build_alpha(scene, rows[cut], origin, alpha_prog, tag)]
        return draws

    def stats(self, job, counts: bool = True) -> dict:
        return {**super().stats(job, counts), "defines": sorted(self.last_defines)}

    def release(self) -> None:
        self.casters.release()
        self._masks.release()
        if self._atlas is not None:
            self._atlas.release()
            self._atlas = None
