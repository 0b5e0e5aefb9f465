"""Pass 2 (shadow maps): one depth map per shadowed light, then a full-screen mask per light.

- sun: orthographic map fitted to the camera frustum (far end clipped to the scene bounds and
  ``Settings.max_distance``), intersected with the scene bounds, depth range covering all
  casters;
- spot: perspective map over the cone (spots wider than 120 degrees use a cube);
- point (and area, treated as a point for now): a cube of six perspective views in a 3x2 atlas.

Maps store linear light depth (MIN blending, no depth-buffer precision issues). The mask uses
slope-scaled bias and normal offset, both in texels at the receiver, and (2r+1)^2 PCF taps.
Output: ``dict[light_index, R32F texture]`` at G-buffer resolution (1 lit, 0 shadowed).
"""
from __future__ import annotations

import math

import moderngl
import numpy as np

from . import create_mask_texture, select_shadowed_lights
from .gbuffer import POSITION_FORMAT, InstanceBatch, ModelBufferCache, position_vertex_data, sphere_proxy_matrices

WIDE_SPOT = math.radians(120.0)
CUBE_AXES = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))
INSTANCE_FORMAT = "4f 4f 4f/i"
INSTANCE_ATTRS = ("in_m0", "in_m1", "in_m2")


def ortho(l, r, b, t, n, f) -> np.ndarray:
    p = np.zeros((4, 4))
    p[0, 0], p[1, 1], p[2, 2] = 2 / (r - l), 2 / (t - b), -2 / (f - n)
    p[0, 3], p[1, 3], p[2, 3], p[3, 3] = -(r + l) / (r - l), -(t + b) / (t - b), -(f + n) / (f - n), 1
    return p


def perspective(tan_half, n, f) -> np.ndarray:
    p = np.zeros((4, 4))
    p[0, 0] = p[1, 1] = 1.0 / tan_half
    p[2, 2], p[2, 3], p[3, 2] = -(f + n) / (f - n), -2 * f * n / (f - n), -1
    return p


def look_basis(forward, up_hint) -> np.ndarray:
    """3x3 with columns right, up, back (camera convention: looks down -Z) for ``forward``."""
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    up = np.asarray(up_hint, np.float64)
    up = up - f * (up @ f)
    if np.linalg.norm(up) < 1e-6:
        alt = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        up = alt - f * (alt @ f)
    up /= np.linalg.norm(up)
    back = -f
    right = np.cross(up, back)
    return np.stack([right, up, back], axis=1)


def view_from_rel(basis, origin_rel) -> np.ndarray:
    v = np.eye(4)
    v[:3, :3] = basis.T
    v[:3, 3] = -basis.T @ origin_rel
    return v


def _box_corners(bmin, bmax) -> np.ndarray:
    return np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1]) for z in (bmin[2], bmax[2])])


def frustum_corners_rel(cam, far: float) -> np.ndarray:
    """(8, 3) camera frustum corners (camera-relative world) from clip start to ``far``."""
    l, r, b, t = cam.viewplane
    n = cam.clip_start
    pts = []
    for z in (n, far):
        s = 1.0 if cam.ortho else z / n
        for x in (l, r):
            for y in (b, t):
                pts.append((x * s, y * s, -z))
    return np.array(pts) @ cam.cam_rot.T


class LightViews:
    """The views of one light's shadow map (float64, camera-relative)."""

    def __init__(self, kind, matrices, forwards, tiles, atlas_size, texel_world, light_pos_rel, light_dir):
        self.kind = kind  # 'sun' | 'spot' | 'cube'
        self.matrices = matrices  # list of (4, 4) clip_from_rel
        self.forwards = forwards  # list of (3,)
        self.tiles = tiles  # list of (x0, y0, size)
        self.atlas_size = atlas_size  # (w, h)
        self.texel_world = texel_world
        self.light_pos_rel = light_pos_rel
        self.light_dir = light_dir


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
        return LightViews("sun", [m], [f], [(0, 0, size)], (size, size), ext / size, np.zeros(3), f)
    pos_rel = light.position - cam.cam_pos
    far = float(np.linalg.norm(corners - pos_rel, axis=1).max()) * 1.01 + 1e-3
    near = max(far * 1e-5, 1e-6)
    if light.type == "SPOT" and light.spot_size <= WIDE_SPOT:
        f = light.direction
        tan_half = math.tan(light.spot_size / 2) * (1 + 2 * margin / size)
        basis = look_basis(f, light.matrix[:3, 1])
        m = perspective(tan_half, near, far) @ view_from_rel(basis, pos_rel)
        return LightViews("spot", [m], [f], [(0, 0, size)], (size, size), 2 * tan_half / size, pos_rel, f)
    size = int(min(size, max_texture // 3))
    tan_half = 1.0 + 2 * margin / size
    mats, fwds, tiles = [], [], []
    for k, axis in enumerate(CUBE_AXES):
        f = np.array(axis, np.float64)
        basis = look_basis(f, (0, 1, 0) if abs(f[2]) > 0.5 else (0, 0, 1))
        mats.append(perspective(tan_half, near, far) @ view_from_rel(basis, pos_rel))
        fwds.append(f)
        tiles.append(((k % 3) * size, (k // 3) * size, size))
    return LightViews("cube", mats, fwds, tiles, (3 * size, 2 * size), 2 * tan_half / size, pos_rel, light.direction)


def _icosphere(subdiv: int = 2) -> np.ndarray:
    """De-indexed (3T, 3) float32 unit-sphere triangles, scaled to circumscribe the sphere."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    tris = np.array([[v[a], v[b], v[c]] for a, b, c in faces])
    for _ in range(subdiv):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [(x + y) / np.linalg.norm(x + y, axis=1, keepdims=True) for x, y in ((a, b), (b, c), (c, a))]
        tris = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    # the flat faces lie inside the sphere: scale so the inscribed distance reaches radius 1
    centroid = np.linalg.norm(tris.mean(axis=1), axis=1).min()
    return (tris.reshape(-1, 3) / centroid).astype(np.float32)


class ShadowMapPass:
    """``render(scene, gbuffer, settings, lights=None) -> dict[int, Texture]``."""

    def __init__(self, ctx: moderngl.Context, programs, models: ModelBufferCache | None = None):
        self.ctx = ctx
        self.programs = programs
        self.models = models if models is not None else ModelBufferCache(ctx)
        self._batches: dict = {}
        self._atlas = None
        self._atlas_fbo = None
        self._masks: dict = {}
        self._sphere_vbo = None
        self.views: dict = {}  # light index -> LightViews of the last render (for debugging/tests)

    def _atlas_target(self, w, h):
        if self._atlas is None or self._atlas.width < w or self._atlas.height < h:
            if self._atlas is not None:
                self._atlas_fbo.release()
                self._atlas.release()
            aw = max(w, 0 if self._atlas is None else self._atlas.width)
            ah = max(h, 0 if self._atlas is None else self._atlas.height)
            self._atlas = self.ctx.texture((aw, ah), 1, dtype="f4")
            self._atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._atlas_fbo = self.ctx.framebuffer(color_attachments=[self._atlas])
        return self._atlas_fbo

    def _mask(self, index, w, h):
        tex = self._masks.get(index)
        if tex is None or tex.size != (w, h):
            if tex is not None:
                tex.release()
            tex = self._masks[index] = create_mask_texture(self.ctx, w, h)
        return tex

    def _draws(self, scene, cam_pos):
        """Upload caster instance data once: a list of (vao, vertex_count, instance_count)."""
        inst = scene.instances
        prog = self.programs.get("shadowmap_depth")
        draws = []
        if not len(inst):
            return prog, draws
        casters = inst.casts_shadow
        for mi, model in enumerate(scene.models):
            rows = np.nonzero(casters & ~inst.sphere & (inst.model_ids == mi))[0]
            if not len(rows) or not model.triangle_count:
                continue
            vbo, nverts = self.models.get(model)
            draws.append((self._upload(mi, inst.matrices[rows], cam_pos, prog, vbo), nverts, len(rows)))
        rows = np.nonzero(casters & inst.sphere)[0]
        if len(rows):
            if self._sphere_vbo is None:
                ico = _icosphere()
                self._sphere_vbo = (self.ctx.buffer(position_vertex_data(ico).tobytes()), len(ico))
            vbo, nverts = self._sphere_vbo
            draws.append((self._upload("spheres", sphere_proxy_matrices(scene, rows), cam_pos, prog, vbo), nverts, len(rows)))
        return prog, draws

    def _upload(self, key, matrices, cam_pos, prog, vbo):
        m = matrices.copy()
        m[:, :3, 3] -= cam_pos
        data = np.ascontiguousarray(m[:, :3, :].reshape(len(m), 12), dtype=np.float32)
        b = self._batches.get(key)
        if b is None:
            b = self._batches[key] = InstanceBatch(self.ctx)
        return b.upload(data, prog, vbo, POSITION_FORMAT, ("in_pos",), INSTANCE_FORMAT, INSTANCE_ATTRS)

    def render(self, scene, gbuffer, settings, lights=None, on_light=None) -> dict:
        """Masks ``{light_index: texture}``; ``on_light(index)`` is called before each light."""
        ctx = self.ctx
        cam = gbuffer.camera
        idx = select_shadowed_lights(scene, settings) if lights is None else list(lights)
        self.models.prune(scene.models)
        max_tex = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
        depth_prog, draws = self._draws(scene, cam.cam_pos)
        mask_prog, vao = self.programs.fullscreen("shadowmap_mask")
        out = {}
        self.views = {}
        for li in idx:
            if on_light is not None:
                on_light(li)
            light = scene.lights[li]
            mask = self._mask(li, gbuffer.width, gbuffer.height)
            out[li] = mask
            views = light_views(scene, light, cam, settings, max_tex)
            self.views[li] = views
            if views is None or not draws:
                mask.write(np.ones((gbuffer.height, gbuffer.width), np.float32).tobytes())
                continue
            # 1. depth maps
            fbo = self._atlas_target(*views.atlas_size)
            fbo.use()
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            ctx.enable(moderngl.BLEND)
            ctx.blend_equation = moderngl.MIN
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            for m, f, (x0, y0, s) in zip(views.matrices, views.forwards, views.tiles):
                fbo.clear(1e30, 1e30, 1e30, 1e30, viewport=(x0, y0, s, s))
                ctx.viewport = (x0, y0, s, s)
                depth_prog["u_light_clip_from_rel"].write(m.T.astype("f4").tobytes())
                depth_prog["u_light_origin_rel"].value = tuple(views.light_pos_rel)
                depth_prog["u_light_fwd"].value = tuple(f)
                for dvao, nverts, ninst in draws:
                    dvao.render(moderngl.TRIANGLES, vertices=nverts, instances=ninst)
            ctx.disable(moderngl.BLEND)
            ctx.blend_equation = moderngl.FUNC_ADD
            # 2. mask
            mfbo = ctx.framebuffer(color_attachments=[mask])
            mfbo.use()
            ctx.viewport = (0, 0, gbuffer.width, gbuffer.height)
            unit = gbuffer.bind(mask_prog)
            self._atlas.use(unit)
            mask_prog["u_shadowmap"].value = unit
            mats = np.zeros((6, 4, 4), np.float32)
            fwds = np.zeros((6, 3), np.float32)
            tiles = np.zeros((6, 4), np.float32)
            for k, (m, f, t) in enumerate(zip(views.matrices, views.forwards, views.tiles)):
                mats[k], fwds[k], tiles[k, :3] = m.T, f, t
            mask_prog["u_view_clip_from_rel"].write(mats.tobytes())
            mask_prog["u_view_fwd"].write(fwds.tobytes())
            mask_prog["u_view_tile"].write(tiles.tobytes())
            vals = {"u_cube": int(views.kind == "cube"), "u_ortho_light": int(views.kind == "sun"),
                    "u_light_pos_rel": tuple(float(v) for v in views.light_pos_rel),
                    "u_light_dir": tuple(float(v) for v in views.light_dir),
                    "u_texel_world": float(views.texel_world), "u_bias": float(settings.shadow_bias),
                    "u_slope_bias": float(settings.slope_bias), "u_normal_offset": float(settings.normal_offset),
                    "u_pcf": int(settings.pcf), "u_max_distance": float(settings.max_distance)}
            for k, v in vals.items():
                if k in mask_prog:
                    mask_prog[k].value = v
            vao.render(moderngl.TRIANGLES, vertices=3)
            mfbo.release()
        return out

    def release(self) -> None:
        for b in self._batches.values():
            b.release()
        self._batches.clear()
        for t in self._masks.values():
            t.release()
        self._masks.clear()
        if self._atlas is not None:
            self._atlas_fbo.release()
            self._atlas.release()
            self._atlas = None
        if self._sphere_vbo is not None:
            self._sphere_vbo[0].release()
            self._sphere_vbo = None
