"""The G-buffer pass, rasterised with Blender's camera.

One instanced, indexed draw call per model: the model's distinct corners (position, smooth
shading normal, UV, and on each triangle's provoking corner its face normal) with an index
buffer (:meth:`~..geometry.ModelBufferCache.indexed`: a software rasteriser shades a vertex once
per index of a de-indexed buffer, three times per triangle), the face normal a flat attribute
rather than a texture read by ``gl_PrimitiveID``, and a per-model instance buffer
(camera-relative world matrix rows, normal matrix, colour, specular/roughness/index)
re-uploaded each render. Instances whose bounding sphere misses the view are not drawn. On a
software rasteriser, which shades vertices and sets up triangles on one thread, in view or not,
neither are the chunks of a big model (:func:`~..geometry.chunk_order`: its triangles in runs
of spatially close ones, each with a bounding sphere) that miss it: a terrain seen from within
draws only the part in view. A GPU draws such a model whole, in one call.
Instances the camera does not see (``Instances.visible_camera``) are not drawn; holdouts
(``Instances.holdout``) are drawn as background that hides what lies behind them, with the
material's w -1 so that the lighting leaves a hole (alpha 0, no colour) there.
Sphere primitives (``Instances.sphere``) are drawn as their model's bounding sphere
(ray/ellipsoid per fragment). Models with UVs shown with a textured material draw with the
``TEXTURED`` variant: the UVs of the indexed buffer, the material per instance, the colour image's texel (mip
mapped) times the instance colour, and the fragments that the material's alpha cuts discarded
(``FrameJob.alpha_sample``: a see-through accumulation's sample, :mod:`..see_through`).

World positions are the pixel-centre camera ray intersected with the triangle's plane (see
``shaders/gbuffer.glsl``), so they match an exact ray cast of ``Camera.pixel_rays``. The depth
test runs on a logarithmic depth of that position (:func:`log_depth_scale`).
"""
from __future__ import annotations

import moderngl
import numpy as np

from ...errors import SceneError
from ...limits import check_instance_count
from ...scene import max_scale
from ..context import check_frame_memory, check_render_size, software_context
from ..frame import GBUFFER_TARGETS, CameraUniforms, GBuffer
from ..geometry import (
    INDEXED_ATTRS,
    INDEXED_ATTRS_NO_UV,
    INDEXED_FORMAT,
    INDEXED_FORMAT_NO_UV,
    PROXY_ATTRS,
    PROXY_FORMAT,
    InstanceBatch,
    ProxyMesh,
    unit_cube,
)
from ..targets import create_texture
from .base import Pass

INSTANCE_FORMAT = "4f 4f 4f 3f 3f 3f 4f 4f/i"
#: The specular an emitting instance's G-buffer material holds: the lighting pass then shows its
#: albedo (the emission) as it is, lit by nothing
EMITTER_SPECULAR = -1.0
INSTANCE_ATTRS = ("in_m0", "in_m1", "in_m2", "in_n0", "in_n1", "in_n2", "in_color", "in_material")
SPHERE_FORMAT = INSTANCE_FORMAT.replace("/i", "") + " 4f 4f 4f 4f/i"
TEXTURED_FORMAT = INSTANCE_FORMAT.replace("/i", "") + " 1f/i"  # + the material (-1: none)
TEXTURED_ATTRS = INSTANCE_ATTRS + ("in_matid",)
SPHERE_ATTRS = INSTANCE_ATTRS + ("in_i0", "in_i1", "in_i2", "in_sphere")


def frustum_planes(clip_from_rel: np.ndarray) -> np.ndarray:
    """(6, 4) unit planes (normal, offset) of the view frustum of ``clip_from_rel``
    (camera-relative; Gribb & Hartmann): a point p is inside where ``planes[:, :3] @ p +
    planes[:, 3] >= 0`` for all six."""
    m = np.asarray(clip_from_rel, np.float64)
    planes = np.stack([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]])
    norm = np.linalg.norm(planes[:, :3], axis=1)
    return planes / np.where(norm > 0, norm, 1.0)[:, None]


def spheres_visible(planes: np.ndarray, rel: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(...) bool: the spheres of camera-relative centres ``rel`` (..., 3) and radii ``r`` (...)
    may reach the frustum of ``planes`` (:func:`frustum_planes`). Conservative: widened by 1e-4
    of the radius and 1e-6 of the distance for the float rounding of the rasteriser's clip test."""
    dist = rel @ planes[:, :3].T + planes[:, 3]
    slack = r * (1.0 + 1e-4) + 1e-6 * np.linalg.norm(rel, axis=-1)
    return ~np.isfinite(dist).all(axis=-1) | (dist >= -slack[..., None]).all(axis=-1)


def frustum_visible(scene, clip_from_rel: np.ndarray, cam_pos: np.ndarray) -> np.ndarray:
    """(N,) bool per instance: its world bounding sphere may reach the view frustum
    (:func:`spheres_visible`). Conservative: the sphere bounds every triangle and a sphere
    primitive's proxy box is drawn only where the sphere is, so an instance left out draws no
    fragment."""
    inst = scene.instances
    if not len(inst):
        return np.zeros(0, bool)
    c, r = scene.instance_spheres()
    return spheres_visible(frustum_planes(clip_from_rel), c - cam_pos, r)


def chunks_visible(scene, rows: np.ndarray, chunks, planes: np.ndarray, cam_pos: np.ndarray) -> np.ndarray:
    """(len(rows), K) bool: chunk k of instance ``rows[i]`` (:meth:`~..geometry.ModelBufferCache.chunks`,
    model-space spheres moved by the instance's matrix, the radius by its largest scale) may
    reach the frustum of ``planes`` (:func:`frustum_planes`)."""
    _, _, centres, radii = chunks
    m = scene.instances.matrices[rows]
    wc = np.einsum("nij,kj->nki", m[:, :3, :3], centres) + m[:, None, :3, 3]
    r = radii[None, :] * max_scale(m)[:, None]
    return spheres_visible(planes, wc - cam_pos, r)


def chunk_runs(vis: np.ndarray, chunks) -> list:
    """``[(row mask, [(first triangle, triangle count), ...]), ...]``: the chunks of ``vis``
    (:func:`chunks_visible`) grouped by the instances that see them, each group's chunks as runs
    of consecutive ones (one draw each)."""
    starts, counts = chunks[0], chunks[1]
    seen = vis.any(axis=0)
    if not seen.any():
        return []
    cols = np.ascontiguousarray(vis.T[seen])
    keys = np.packbits(cols, axis=1)
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    idx = np.nonzero(seen)[0]
    out = []
    for g in np.argsort(first):
        ks = idx[inv.ravel() == g]
        runs = np.split(ks, np.nonzero(np.diff(ks) != 1)[0] + 1)
        out.append((cols[first[g]], [(int(starts[a[0]]), int(counts[a].sum())) for a in runs]))
    return out


def camera_visible(scene) -> np.ndarray:
    """(N,) bool per instance: the camera sees it (``Instances.visible_camera``); the others
    are not drawn, and cast shadows all the same (the bake keeps them)."""
    return np.asarray(scene.instances.visible_camera, bool)


def holdout_index(inst, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) float64: the instance index of each row as the G-buffer's vertex stage reads
    it, ``-(index + 1)`` for a holdout (``Instances.holdout``: ``shaders/gbuffer.glsl`` writes its
    pixels as background that hides what lies behind, marked for the lighting to leave a hole)."""
    rows = np.asarray(rows)
    index = rows.astype(np.float64)
    return np.where(inst.holdout[rows], -1.0 - index, index)


def log_depth_scale(camera) -> float:
    """``1 / log2(clip_end / clip_start)``: the G-buffer's depth test runs on
    ``log2(view depth / clip_start) * scale`` (``shaders/gbuffer.glsl``), which keeps a relative
    depth resolution of ~1e-6 for any clip range (1e-4 .. 1e6 included)."""
    return float(1.0 / np.log2(float(camera.clip_end) / float(camera.clip_start)))


class GBufferPass(Pass):
    """``render(job) -> GBuffer`` at ``job.size`` (owned by the pass, overwritten next frame)."""

    produces = "gbuffer"
    name = "gbuffer"
    label = "G-buffer"

    def __init__(self, gpu):
        super().__init__(gpu)
        self.models = gpu.models
        self._batches: dict = {}  # model index -> InstanceBatch
        self._gbuffer: GBuffer | None = None
        self._cube = ProxyMesh(self.ctx, unit_cube)
        self.draw_calls = 0
        self.culled = 0  # instances of the last render outside the view frustum (not drawn)
        # big models drawn by chunks, those outside the view left out, on a software rasteriser
        # (it shades vertices and sets up triangles on one thread, culled or not); a GPU draws
        # them whole in one call (tests compare the two)
        self.chunked = software_context(self.ctx)
        self.triangles = 0  # triangles drawn by the last render (instances x triangles of each draw)
        self._frame_programs: dict = {}  # smooth -> (program, textured program): this render's
        self._alpha_sample = None  # this render's see-through sample index (None: the 0.5 cut)

    # -- targets -------------------------------------------------------------------------------
    def _targets(self, width, height) -> GBuffer:
        gb = self._gbuffer
        if gb is not None and gb.size == (width, height):
            return gb
        if gb is not None:
            gb.release()
        check_render_size(self.ctx, width, height, "G-buffer")
        tex = {name: create_texture(self.ctx, width, height, comps, dt) for name, comps, dt in GBUFFER_TARGETS}
        depth = self.ctx.depth_texture((width, height))
        fbo = self.ctx.framebuffer(color_attachments=[tex[n] for n, _, _ in GBUFFER_TARGETS], depth_attachment=depth)
        self._gbuffer = GBuffer(width, height, tex, depth, fbo)
        return self._gbuffer

    def _batch(self, key) -> InstanceBatch:
        b = self._batches.get(key)
        if b is None:
            b = self._batches[key] = InstanceBatch(self.ctx)
        return b

    @staticmethod
    def instance_data(scene, rows: np.ndarray, cam_pos: np.ndarray, spheres: bool = False) -> np.ndarray:
        """Per-instance float32 records (camera-relative matrices computed in float64)."""
        inst = scene.instances
        m = inst.matrices[rows].copy()
        m[:, :3, 3] -= cam_pos
        nmat = np.transpose(inst.inverse[rows, :3, :3], (0, 2, 1))
        color = inst.base_color[rows].astype(np.float64)
        specular = inst.specular[rows].astype(np.float64)
        emits = (inst.emission[rows] > 0.0).any(axis=1)
        if emits.any():  # an emitter: its emission as the colour, specular -1 marks it (lighting.glsl)
            color[emits, :3] = inst.emission[rows][emits]
            specular[emits] = EMITTER_SPECULAR
        cols = [m[:, 0, :], m[:, 1, :], m[:, 2, :], nmat[:, 0, :], nmat[:, 1, :], nmat[:, 2, :], color,
                np.stack([specular, inst.roughness[rows], holdout_index(inst, rows), inst.terminator[rows]], axis=1)]
        if spheres:
            inv = inst.inverse[rows].copy()
            # inverse of (T(-cam) @ M) = M^-1 @ T(cam): translation += M^-1[:3,:3] @ cam
            inv[:, :3, 3] += inv[:, :3, :3] @ cam_pos
            mids = inst.model_ids[rows]
            sph = np.array([[*scene.models[i].sphere_center, scene.models[i].sphere_radius] for i in mids], np.float64)
            cols += [inv[:, 0, :], inv[:, 1, :], inv[:, 2, :], sph.reshape(-1, 4)]
        return np.ascontiguousarray(np.concatenate(cols, axis=1), dtype=np.float32)

    def _model_vao(self, key, scene, model, rows, cam_pos, prog, tprog, vbo, ibo):
        """The vao drawing instances ``rows`` of ``model`` (textured where shown so; a mesh
        without UVs too when its materials read no image: a constant alpha cuts it, its UVs
        read as zeros)."""
        inst = scene.instances
        data = self.instance_data(scene, rows, cam_pos)
        mids = np.unique(inst.material_ids[rows])
        mids = mids[mids >= 0]
        if tprog is not None and len(mids) and (model.uvs is not None
                                                 or not any(scene.materials[k].textured for k in mids)):
            data = np.ascontiguousarray(np.concatenate(
                [data, inst.material_ids[rows].astype(np.float32)[:, None]], axis=1))
            return self._batch(key).upload(data, tprog, vbo, INDEXED_FORMAT, INDEXED_ATTRS, TEXTURED_FORMAT,
                                           TEXTURED_ATTRS, index_buffer=ibo)
        return self._batch(key).upload(data, prog, vbo, INDEXED_FORMAT_NO_UV, INDEXED_ATTRS_NO_UV,
                                       INSTANCE_FORMAT, INSTANCE_ATTRS, index_buffer=ibo)

    def _programs(self, scene, cam, smooth: bool):
        """``(plain program, textured program or None)`` for a model, with ``TERMINATOR`` where
        it has smooth corner normals (the shadow terminator's lift: a geometry stage), set up for
        this frame."""
        got = self._frame_programs.get(smooth)
        if got is not None:
            return got
        base = {"TERMINATOR": 1} if smooth else {}
        progs = [self.programs.get("gbuffer", base)]
        if scene.materials:
            progs.append(self.programs.get("gbuffer", {**base, "TEXTURED": 1}))
        for prog in progs:
            cam.apply(prog)
            prog["u_log_depth_scale"].value = log_depth_scale(scene.camera)
        if len(progs) > 1:
            self.gpu.bind_materials(progs[1], scene)
            sample = self._alpha_sample
            progs[1]["u_alpha_sample"].value = -1 if sample is None else int(sample)
        got = self._frame_programs[smooth] = (progs[0], progs[1] if len(progs) > 1 else None)
        return got

    # -- render ----------------------------------------------------------------------------------
    def render(self, job) -> GBuffer:
        scene = job.scene
        if scene.camera is None:
            raise SceneError(f"scene '{scene.name}' has no camera")
        check_instance_count(len(scene.instances))  # (the instance index is a float channel below)
        width, height = job.size
        check_frame_memory(self.ctx, width, height, len(job.lights or ()))
        gb = self._targets(width, height)
        cam = CameraUniforms.from_camera(scene.camera, width, height)
        gb.camera = cam
        gb.world_color = np.asarray(scene.world_color, np.float32)
        ctx = self.ctx
        gb.fbo.use()
        ctx.viewport = (0, 0, width, height)
        gb.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable_only(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        self.draw_calls = 0
        self.triangles = 0
        self._frame_programs = {}
        self._alpha_sample = job.alpha_sample
        self.models.prune(scene.models)
        inst = scene.instances
        planes = frustum_planes(cam.clip_from_rel)
        visible = frustum_visible(scene, cam.clip_from_rel, cam.cam_pos)
        self.culled = int(len(visible) - np.count_nonzero(visible))
        visible &= camera_visible(scene)
        if visible.any():
            order = np.argsort(inst.model_ids, kind="stable")
            tri_rows = order[~inst.sphere[order] & visible[order]]
            bounds = np.searchsorted(inst.model_ids[tri_rows], np.arange(len(scene.models) + 1))
            for mi, model in enumerate(scene.models):
                rows = tri_rows[bounds[mi]:bounds[mi + 1]]
                if not len(rows) or not model.triangle_count:
                    continue
                prog, tprog = self._programs(scene, cam, model.normals is not None)
                vbo, ibo, nidx = self.models.indexed(model)
                chunks = self.models.chunks(model) if self.chunked else None
                if chunks is None:
                    groups = [(np.ones(len(rows), bool), [(0, nidx // 3)])]
                else:
                    groups = chunk_runs(chunks_visible(scene, rows, chunks, planes, cam.cam_pos), chunks)
                for g, (sel, runs) in enumerate(groups):
                    vao = self._model_vao((mi, g), scene, model, rows[sel], cam.cam_pos, prog, tprog, vbo, ibo)
                    for start, n in runs:
                        vao.render(moderngl.TRIANGLES, vertices=3 * n, first=3 * start, instances=int(sel.sum()))
                        self.draw_calls += 1
                        self.triangles += n * int(sel.sum())
            sph_rows = np.nonzero(inst.sphere & visible)[0]
            if len(sph_rows):
                prog = self.programs.get("gbuffer", {"SPHERE": 1})
                cam.apply(prog)
                prog["u_log_depth_scale"].value = log_depth_scale(scene.camera)
                cube, nverts = self._cube.get()
                data = self.instance_data(scene, sph_rows, cam.cam_pos, spheres=True)
                vao = self._batch("spheres").upload(data, prog, cube, PROXY_FORMAT, PROXY_ATTRS,
                                                    SPHERE_FORMAT, SPHERE_ATTRS)
                vao.render(moderngl.TRIANGLES, vertices=nverts, instances=len(sph_rows))
                self.draw_calls += 1
        ctx.disable(moderngl.DEPTH_TEST)
        return gb

    def release(self) -> None:
        for b in self._batches.values():
            b.release()
        self._batches.clear()
        self._cube.release()
        if self._gbuffer is not None:
            self._gbuffer.release()
            self._gbuffer = None
