"""numpy mirrors of the rays ``shaders/raytrace.glsl`` traces (origins, offsets, directions), for
tests and the throughput benchmark."""
from __future__ import annotations

import numpy as np

from ..gpu.lights import light_cone, light_ray_uniforms

ORIGIN_ULPS = 2.0 ** -21  # offset_origin's push: this share of the largest coordinate (4-8 ULPs)
ORIGIN_MIN_STEP = 2.0 ** -16  # and at least this (metres, near the bake origin)


def offset_origins(p: np.ndarray, n: np.ndarray, slack: np.ndarray) -> np.ndarray:
    """numpy mirror of ``offset_origin`` in ``shaders/common/shadow_ray.glsl`` (float32
    throughout): ``p`` pushed along ``n`` by 2^-21 of its largest coordinate (at least 2^-16)
    plus ``slack``."""
    p = np.asarray(p, np.float32)
    n = np.asarray(n, np.float32)
    m = np.abs(p).max(axis=-1)
    step = np.maximum(m * np.float32(ORIGIN_ULPS), np.float32(ORIGIN_MIN_STEP)) + np.asarray(slack, np.float32)
    return (p + n * step.astype(np.float32)[..., None]).astype(np.float32)


def surface_points(camera, rows, cols, depth) -> np.ndarray:
    """numpy mirror of ``surface_point`` in ``shaders/raytrace.glsl`` without the camera's
    position: camera-relative points (N, 3) of pixels (rows, cols) (row 0 = top) at G-buffer
    view ``depth``, in float32 as the shader computes them. ``camera``: ``GBuffer.camera``."""
    f = np.float32
    W, H = camera.resolution
    fx = ((np.asarray(cols) + f(0.5)) / f(W)).astype(f)
    fy = ((f(H - 1) - np.asarray(rows) + f(0.5)) / f(H)).astype(f)
    xmin, xmax, ymin, ymax = (f(v) for v in camera.viewplane)
    cs = f(camera.clip_start)
    local = np.stack([xmin * (f(1) - fx) + xmax * fx, ymin * (f(1) - fy) + ymax * fy,
                      np.full(len(fx), -cs, f)], axis=1)
    R = camera.cam_rot.astype(f)
    depth = np.asarray(depth, f)
    if camera.ortho:
        return local @ R.T + (-R[:, 2])[None] * (depth - cs)[:, None]
    return (local @ R.T) * (depth / cs)[:, None]


def terminator_origins(p, n, ns, lift, to_light, slack) -> np.ndarray:
    """numpy mirror of ``shadow_ray_origin`` in ``shaders/common/shadow_ray.glsl`` (Cycles'
    ``shadow_ray_offset``, light/sample.h): points ``p`` (N, 3) bake space, geometric normals
    ``n`` towards the camera, shading normals ``ns``, the G-buffer's ``lift`` (N, 4: the smooth
    surface's lift, the geometry offset; 0 on flat models), ``to_light`` (N, 3). Where the lift
    applies, the origin rises by its share; it is then pushed off the plane (standing for Cycles'
    skip of its own triangle) unless the geometric normal faces away from the light."""
    f = np.float32
    p, n, ns = (np.asarray(a, f) for a in (p, n, ns))
    lift = np.asarray(lift, f)
    cutoff = lift[:, 3]
    unit = np.asarray(to_light, f)
    unit = unit / np.linalg.norm(unit, axis=1, keepdims=True).astype(f)
    nl = (ns * unit).sum(axis=1)
    ngl = (n * unit).sum(axis=1)
    safe = np.where(cutoff > 0, cutoff, f(1))
    amount = np.where(nl < cutoff, np.clip(f(2) - (ngl + nl) / safe, 0, 1), np.clip(f(1) - ngl / safe, 0, 1))
    amount = np.where(cutoff > 0, amount, f(0)).astype(f)
    lifted = (p + lift[:, :3] * amount[:, None]).astype(f)
    own = (amount > 0) & ~(ngl > 0)  # (the ray may hit its own surface: no push)
    return np.where(own[:, None], lifted, offset_origins(lifted, n, slack))


def shadow_rays(gbuffer, pixels, light, origin=(0.0, 0.0, 0.0)):
    """The rays ``shaders/raytrace.glsl`` traces for G-buffer pixels ``(rows, cols)``:
    ``(origins, dirs, tmax, facing)``. Origins are world space (float64: the shader's float32
    bake-space origins plus the bake's ``origin``); samples with ``facing`` False (the shading
    normal turned from the light, out of its reach) are not traced (mask 0)."""
    rows, cols = pixels
    origin = np.asarray(origin, np.float64)
    cam = gbuffer.camera
    depth = gbuffer.read("depth")[rows, cols]
    n = gbuffer.read("normal")[rows, cols, :3].astype(np.float32)
    ns = gbuffer.read("shading_normal")[rows, cols, :3].astype(np.float32)
    lift = gbuffer.read("terminator")[rows, cols].astype(np.float32)
    p = (cam.cam_pos - origin).astype(np.float32) + surface_points(cam, rows, cols, depth)
    local, vec = light_ray_uniforms(light, origin)
    vec = np.asarray(vec, np.float32)  # (as the shader's uniform)
    to_light = vec - p if local else np.broadcast_to(vec, p.shape)
    facing = (ns * to_light).sum(axis=1) > 0
    if local:
        axis, cone = light_cone(light)
        unit = to_light / np.linalg.norm(to_light, axis=1, keepdims=True)
        facing &= (-unit @ np.asarray(axis, np.float32)) > np.float32(cone)
    o = terminator_origins(p, n, ns, lift, to_light, depth * np.float32(3.0e-6))
    if local:
        d = vec - o
        tmax = np.ones(len(o), np.float32)
    else:
        d = np.broadcast_to(vec, o.shape).copy()
        tmax = np.full(len(o), np.inf, np.float32)
    return o.astype(np.float64) + origin, d, tmax, facing
