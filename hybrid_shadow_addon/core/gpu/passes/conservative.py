"""Conservative light-space occupancy maps for the ray-traced shadow pass
(``shaders/conservative_map.glsl``; Hertel, Hormann & Westermann 2009), built only under
``Settings.conservative`` ``sun`` or ``all``: they pay where a map's draw costs less than the
traversal it saves (many receivers nearer the light than every caster, costly rays).

Per shadowed light, one R32F map holds for every texel a lower bound ``D`` of the light depth
of any shadow caster whose surface touches the texel's column. A shadow ray from a receiver
towards the light stays inside the receiver's column (sun: orthographic, the ray is parallel to
the projection axis; point/spot/area: the ray passes through the projection centre), so a caster
can only be hit where the ray's depth is at least ``D``: the ray is cut there (``tmax``), and a
receiver nearer the light than ``D`` is lit without traversal. Receivers outside the map (or
when the map is missing) are traced in full, so the result never changes, only the work.

- sun: one orthographic view along ``-u_light_vec`` (the very float32 vector the rays use),
  fitted to the G-buffer receivers' extent across the light; casters culled by their bounding
  spheres against that window and against the farthest receiver depth;
- point / spot / area: a cube of six perspective faces around the light position (the exact
  float32 ``u_light_vec``), each fitted to the receivers that fall on it (faces without
  receivers are skipped), in a 3 x 2 atlas.

Error budget (what makes it conservative rather than approximately right): the tracer and this
rasteriser see the same caster surfaces up to the float32 rounding of world positions,
``delta = 2^-18 * W * cond`` (``W`` the largest world coordinate of scene, camera and light;
``cond`` the worst instance matrix anisotropy); each triangle's footprint is grown by
``delta`` (sun; ``delta / depth`` on a face) plus 0.5 + 1/16 texel, the depth bounds carry the
slack documented in the shader, and the ray pass subtracts ``4 * delta`` from ``D``. Texels are
never smaller than ``2^-12`` of the coordinate magnitude, so the receiver's own column lookup
is far below 1/16 texel off.
"""
from __future__ import annotations

import time

import moderngl
import numpy as np

from ..geometry import CasterDraws
from ..lights import light_ray_uniforms
from ..projection import CUBE_AXES, look_basis
from ..targets import TargetCache, set_uniforms

EMPTY = 1e30


class MapViews:
    """Uniforms of one light's map for ``shaders/raytrace.glsl`` (``HS_CONSERVATIVE``)."""

    def __init__(self, persp, origin, bases, windows, tiles, margin):
        self.persp = persp  # False: sun (one view); True: six cube faces
        self.origin = origin  # (3,) float64 world (float32-exact)
        self.bases = bases  # list of (3, 3) columns right, up, forward
        self.windows = windows  # list of (lo_x, lo_y, scale_x, scale_y) or None (face skipped)
        self.tiles = tiles  # list of (x0, y0, size)
        self.margin = margin  # depth margin (metres) subtracted from D by the ray pass


def bind_map(prog, unit, tex, views, origin) -> int:
    """Bind a light's map ``tex`` and its ``views`` (:class:`MapViews`) to ``prog`` from
    ``unit`` on (``origin``: the bake's); returns the next free unit."""
    tex.use(unit)
    prog["u_cm"].value = unit
    n = len(views.bases)
    bases = np.zeros((6, 3, 3), np.float32)
    wins = np.zeros((6, 4), np.float32)
    tiles = np.zeros((6, 4), np.float32)
    for k in range(n):
        bases[k] = views.bases[k].T  # column-major upload: rows of .T = columns
        if views.windows[k] is not None:
            wins[k] = views.windows[k]
            tiles[k] = (*views.tiles[k], 1.0)
    prog["u_cm_origin"].value = tuple(float(v) for v in np.asarray(views.origin) - origin)  # bake space
    for name, arr in (("u_cm_basis", bases), ("u_cm_win", wins), ("u_cm_tile", tiles)):
        u = prog[name]  # (the sun's program keeps only element 0 of the arrays)
        u.write(arr[:max(1, u.array_length)].tobytes())
    prog["u_cm_margin"].value = float(views.margin)
    return unit + 1


class ConservativeMaps:
    """Builds one light's conservative map per call to :meth:`render` into a shared atlas;
    :meth:`start` and :meth:`for_light` pick the lights ``Settings.conservative`` maps and time
    the builds (``last_ms``)."""

    def __init__(self, gpu, sun_size: int = 2048, face_size: int = 512):
        self.ctx = gpu.ctx
        self.programs = gpu.programs
        self.casters = CasterDraws(self.ctx, gpu.models)
        self.sun_size = int(sun_size)
        self.face_size = int(face_size)
        self._targets = TargetCache(self.ctx, what="conservative map")
        self._frame = None
        self.stats: dict = {}
        self.last_ms = 0.0  # time spent building the maps in the last frame (incl. finish)
        self._locals = False  # whether this frame's point, spot and area lights get maps too

    # -- the frame's lights ----------------------------------------------------------------------
    def start(self, scene, gbuffer, settings, lights) -> None:
        """A frame of ``settings`` (``conservative`` ``sun`` or ``all``) shadowing ``lights``:
        read the receivers if some light will get a map."""
        self.last_ms = 0.0
        self._locals = settings.conservative == "all"
        if lights and (self._locals or any(not light_ray_uniforms(scene.lights[li])[0] for li in lights)):
            t0 = time.perf_counter()
            self.begin_frame(scene, gbuffer)
            self.last_ms += (time.perf_counter() - t0) * 1e3

    def for_light(self, scene, li: int, local: bool):
        """The map ``(texture, MapViews)`` of light ``li`` this frame, or None (a local light
        under ``sun``, or nothing to gain)."""
        if local and not self._locals:
            return None
        ctx = self.ctx
        ctx.finish()  # (so last_ms holds the maps alone, not the previous light's rays)
        t0 = time.perf_counter()
        cmap = self.render(scene, li, local, light_ray_uniforms(scene.lights[li])[1])
        ctx.finish()
        self.last_ms += (time.perf_counter() - t0) * 1e3
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        return cmap

    # -- per frame ---------------------------------------------------------------------------
    def begin_frame(self, scene, gbuffer) -> None:
        """Read the receivers (G-buffer positions) and the casters' spheres once per frame."""
        self.stats = {}
        pos = gbuffer.read("position")
        rec = pos[pos[..., 3] > 0.5][:, :3].astype(np.float64)
        inst = scene.instances
        casters = np.nonzero(inst.casts_shadow)[0] if len(inst) else np.zeros(0, np.int64)
        c, r = scene.instance_spheres()
        bounds = scene.world_bounds()
        w = 1.0
        if bounds is not None:
            w = max(w, float(np.abs(np.concatenate(bounds)).max()))
        if len(rec):
            w = max(w, float(np.abs(rec).max()))
        w = max(w, float(np.abs(gbuffer.camera.cam_pos).max()) if gbuffer.camera is not None else 0.0)
        cond = 1.0
        if len(casters):
            m = inst.matrices[casters, :3, :3]
            sv = np.linalg.svd(m, compute_uv=False)
            cond = float(np.max(sv[:, 0] / np.maximum(sv[:, 2], 1e-30)))
        self._frame = dict(rec=rec, casters=casters, centers=c, radii=r, W=w, cond=min(cond, 1e6),
                           cam_pos=None if gbuffer.camera is None else np.asarray(gbuffer.camera.cam_pos, np.float64))

    def _delta(self, extra_w: float = 0.0) -> float:
        f = self._frame
        return 2.0 ** -18 * max(f["W"], extra_w) * max(1.0, f["cond"])

    # -- one light -----------------------------------------------------------------------------
    def render(self, scene, key, local: bool, light_vec) -> tuple | None:
        """Build the map of one light (``light_vec`` as the ray pass's ``u_light_vec``, float32).
        Returns ``(texture, MapViews)`` or None (nothing to gain: no receivers)."""
        f = self._frame
        if f is None or not len(f["rec"]):
            return None
        vec = np.asarray(light_vec, np.float32).astype(np.float64)
        if local:
            return self._render_cube(scene, key, vec)
        return self._render_sun(scene, key, vec)

    def _render_sun(self, scene, key, to_sun):
        f = self._frame
        fwd = -to_sun  # exactly the rays' direction, reversed
        if not np.all(np.isfinite(fwd)) or np.linalg.norm(fwd) == 0:
            return None
        basis = look_basis(fwd / np.linalg.norm(fwd), (0.0, 0.0, 1.0) if abs(fwd[2]) < 0.9 else (0.0, 1.0, 0.0))
        basis[:, 2] = fwd  # depth along the unnormalised float32 direction (|fwd| ~ 1)
        origin = np.float32(f["cam_pos"] if f["cam_pos"] is not None else f["rec"].mean(0)).astype(np.float64)
        v = (f["rec"] - origin) @ basis
        S = self.sun_size
        delta = self._delta()
        lo = v[:, :2].min(0)
        hi = v[:, :2].max(0)
        coord = float(np.abs(np.concatenate([lo, hi])).max()) + 1.0
        ext = np.maximum(hi - lo, 2.0 ** -12 * coord * S)
        texel = ext / (S - 8)
        lo = lo - 4 * texel
        scale = 1.0 / texel
        fmax = float(v[:, 2].max())
        # casters: sphere vs window (2 texels + delta of slack), nearer than the farthest receiver
        c = (f["centers"][f["casters"]] - origin) @ basis
        r = f["radii"][f["casters"]] * max(1.0, float(np.linalg.norm(fwd))) + delta
        wlo, whi = lo - 2 * texel, lo + S * texel + 2 * texel
        keep = (c[:, 0] + r >= wlo[0]) & (c[:, 0] - r <= whi[0]) & (c[:, 1] + r >= wlo[1]) & \
               (c[:, 1] - r <= whi[1]) & (c[:, 2] - r <= fmax + 4 * delta + texel.max())
        rows = f["casters"][keep]
        target = self._targets.get(("sun", key), S, S)
        self._draw_views(scene, target.fbo, origin, [basis], [(lo, scale)], [(0, 0, S)], False, delta, 0.0, rows)
        self.stats[key] = {"casters": int(len(rows)), "views": 1}
        win = (float(lo[0]), float(lo[1]), float(scale[0]), float(scale[1]))
        return target.texture, MapViews(False, origin, [basis], [win], [(0, 0, S)], 4 * delta)

    def _render_cube(self, scene, key, light_pos):
        f = self._frame
        origin = light_pos  # float32-exact
        rec = f["rec"] - origin
        a = np.abs(rec)
        major = np.argmax(a, axis=1)  # ties: x before y before z (as the GLSL)
        comp = rec[np.arange(len(rec)), major]
        face = 2 * major + (comp < 0)
        S = self.face_size
        W = max(f["W"], float(np.abs(origin).max()))
        delta = self._delta(W)
        near = max(2.0 ** -20 * W, 1e-7)
        bases, wins, tiles, rows_per = [], [], [], []
        cen = f["centers"][f["casters"]] - origin
        rad = f["radii"][f["casters"]] + delta
        for k, axis in enumerate(CUBE_AXES):
            fw = np.array(axis, np.float64)
            basis = look_basis(fw, (0, 1, 0) if abs(fw[2]) > 0.5 else (0, 0, 1))
            basis[:, 2] = fw
            tiles.append(((k % 3) * S, (k // 3) * S, S))
            bases.append(basis)
            sel = face == k
            v = rec[sel] @ basis
            v = v[v[:, 2] > 0]
            if not len(v):
                wins.append(None)
                rows_per.append(None)
                continue
            s = v[:, :2] / v[:, 2:3]
            lo, hi = s.min(0), s.max(0)
            ext = np.maximum(hi - lo, 2.0 ** -12 * 2.0 * S)
            texel = ext / (S - 8)
            lo = lo - 4 * texel
            scale = 1.0 / texel
            fmax = float(v[:, 2].max())
            wlo, whi = lo - 2 * texel, lo + S * texel + 2 * texel
            c = cen @ basis
            keep = (c[:, 2] + rad > near) & (c[:, 2] - rad <= fmax * (1 + 1e-3) + 4 * delta)
            for ax in (0, 1):  # side planes x = w z through the light, sphere on the inner side
                for wv, sgn in ((whi[ax], 1.0), (wlo[ax], -1.0)):
                    dist = sgn * (c[:, ax] - wv * c[:, 2]) / np.sqrt(1.0 + wv * wv)
                    keep &= dist <= rad
            wins.append((lo, scale))
            rows_per.append(f["casters"][keep])
        target = self._targets.get(("cube", key), 3 * S, 2 * S)
        n = self._draw_views(scene, target.fbo, origin, bases, wins, tiles, True, delta, near, rows_per)
        self.stats[key] = {"casters": n, "views": sum(w is not None for w in wins)}
        wl = [None if w is None else (float(w[0][0]), float(w[0][1]), float(w[1][0]), float(w[1][1])) for w in wins]
        return target.texture, MapViews(True, origin, bases, wl, tiles, 4 * delta)

    def _draw_views(self, scene, fbo, origin, bases, wins, tiles, persp, delta, near, rows):
        ctx = self.ctx
        prog = self.programs.get("conservative_map")
        fbo.use()
        fbo.clear(EMPTY, EMPTY, EMPTY, EMPTY)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_equation = moderngl.MIN
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        total = 0
        try:
            for k, (basis, win, (x0, y0, size)) in enumerate(zip(bases, wins, tiles)):
                if win is None:
                    continue
                r = rows[k] if persp else rows
                draws = self.casters.build(scene, r, origin, prog)
                total += len(r)
                if not draws:
                    continue
                ctx.viewport = (x0, y0, size, size)
                ctx.scissor = (x0, y0, size, size)
                set_uniforms(prog, {
                    "u_basis": basis.T.astype("f4").tobytes(),  # column-major: columns of basis
                    "u_persp": int(persp), "u_near": float(near), "u_win_lo": tuple(map(float, win[0])),
                    "u_win_scale": tuple(map(float, win[1])), "u_tile_size": float(size),
                    "u_expand": float(delta), "u_tile_origin": (float(x0), float(y0))})
                for vao, nverts, ninst in draws:
                    vao.render(moderngl.TRIANGLES, vertices=nverts, instances=ninst)
        finally:
            ctx.scissor = None
            ctx.disable(moderngl.BLEND)
            ctx.blend_equation = moderngl.FUNC_ADD
        return total

    def release(self) -> None:
        self.casters.release()
        self._targets.release()
