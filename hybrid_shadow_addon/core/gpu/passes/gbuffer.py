"""Pass 1: the G-buffer, rasterised with Blender's camera.

One instanced draw call per model: a de-indexed vertex buffer (position + face normal, cached
per model) and a per-model instance buffer (camera-relative world matrix rows, normal matrix,
colour, specular/roughness/index) re-uploaded each render. Sphere primitives
(``Instances.sphere``) are drawn as their model's bounding sphere (ray/ellipsoid per fragment).

World positions are the pixel-centre camera ray intersected with the triangle's plane (see
``shaders/gbuffer.glsl``), so they match an exact ray cast of ``Camera.pixel_rays``.
The depth test runs on a logarithmic depth of that position (:func:`log_depth_scale`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import moderngl
import numpy as np

from ...errors import SceneError
from ..context import check_render_size

INSTANCE_FORMAT = "4f 4f 4f 3f 3f 3f 4f 3f/i"
INSTANCE_ATTRS = ("in_m0", "in_m1", "in_m2", "in_n0", "in_n1", "in_n2", "in_color", "in_material")
SPHERE_FORMAT = INSTANCE_FORMAT.replace("/i", "") + " 4f 4f 4f 4f/i"
SPHERE_ATTRS = INSTANCE_ATTRS + ("in_i0", "in_i1", "in_i2", "in_sphere")

# name -> (components, dtype) of the colour attachments, in attachment order
TARGETS = (
    ("position", 4, "f4"),
    ("normal", 4, "f4"),
    ("shading_normal", 4, "f2"),
    ("albedo", 4, "f2"),
    ("material", 4, "f4"),
    ("depth", 1, "f4"),
)
GB_SAMPLERS = {"position": "u_gb_position", "normal": "u_gb_normal", "shading_normal": "u_gb_shading",
               "albedo": "u_gb_albedo", "material": "u_gb_material", "depth": "u_gb_depth"}


@dataclass
class CameraUniforms:
    """Everything a pass needs to rebuild camera rays on the GPU (float64 on the CPU)."""

    clip_from_rel: np.ndarray  # (4, 4) projection @ view rotation
    cam_rot: np.ndarray  # (3, 3) camera axes in world (columns)
    cam_pos: np.ndarray  # (3,)
    viewplane: tuple
    resolution: tuple
    clip_start: float
    ortho: bool

    @classmethod
    def from_camera(cls, camera, width: int, height: int) -> "CameraUniforms":
        cw = camera.world_matrix_normalized()
        view = camera.view_matrix()
        rot_view = np.eye(4)
        rot_view[:3, :3] = view[:3, :3]
        return cls(camera.projection_matrix(width, height) @ rot_view, cw[:3, :3].copy(), cw[:3, 3].copy(),
                   tuple(float(v) for v in camera.viewplane(width, height)), (int(width), int(height)),
                   float(camera.clip_start), camera.type == "ORTHO")

    def apply(self, prog: moderngl.Program) -> None:
        """Set the uniforms of ``shaders/common/camera.glsl`` that ``prog`` uses."""
        vals = {
            "u_clip_from_rel": self.clip_from_rel.T.astype("f4").tobytes(),
            "u_cam_rot": self.cam_rot.T.astype("f4").tobytes(),
            "u_cam_pos": tuple(float(v) for v in self.cam_pos),
            "u_viewplane": self.viewplane,
            "u_resolution": tuple(float(v) for v in self.resolution),
            "u_clip_start": self.clip_start,
            "u_ortho": int(self.ortho),
        }
        for k, v in vals.items():
            if k in prog:
                if isinstance(v, bytes):
                    prog[k].write(v)
                else:
                    prog[k].value = v


@dataclass
class GBuffer:
    """The G-buffer textures (owned by the pass, overwritten by its next render).

    ``position`` RGBA32F world xyz, w = 1 on geometry and 0 on background; ``normal`` RGBA32F
    unit geometric (face) normal turned towards the camera; ``shading_normal`` RGBA16F;
    ``albedo`` RGBA16F linear base colour; ``material`` RGBA32F (specular, roughness, instance
    index, 1); ``depth`` R32F view depth in metres (0 on background); ``depth_buffer`` the
    depth attachment. Arrays from :meth:`read` have row 0 = top row of the image.
    """

    width: int
    height: int
    textures: dict
    depth_buffer: moderngl.Texture
    fbo: moderngl.Framebuffer
    camera: CameraUniforms | None = None
    world_color: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))

    def __getattr__(self, name):
        tex = self.__dict__.get("textures", {})
        if name in tex:
            return tex[name]
        raise AttributeError(name)

    @property
    def size(self) -> tuple:
        return self.width, self.height

    def read(self, name: str) -> np.ndarray:
        """float32 (H, W, C) (or (H, W) for one channel), row 0 = top."""
        return read_texture(self.textures[name])

    def bind(self, prog: moderngl.Program, first_unit: int = 0) -> int:
        """Bind the textures to the ``u_gb_*`` samplers of ``shaders/common/gbuffer.glsl`` that
        ``prog`` uses, from texture unit ``first_unit``; set the camera uniforms. Returns the
        next free unit."""
        unit = first_unit
        for name, uniform in GB_SAMPLERS.items():
            if uniform in prog:
                self.textures[name].use(unit)
                prog[uniform].value = unit
                unit += 1
        if self.camera is not None:
            self.camera.apply(prog)
        return unit

    def coverage(self) -> np.ndarray:
        """(H, W) bool: True where there is geometry (row 0 = top)."""
        return self.read("position")[..., 3] > 0.5

    def release(self) -> None:
        self.fbo.release()
        for t in self.textures.values():
            t.release()
        self.depth_buffer.release()


def read_texture(tex: moderngl.Texture) -> np.ndarray:
    """A 2D texture as float32 numpy, row 0 = TOP row (GL stores bottom-up)."""
    dt = {"f4": np.float32, "f2": np.float16, "f1": np.uint8, "u1": np.uint8, "i4": np.int32, "u4": np.uint32}[tex.dtype]
    a = np.frombuffer(tex.read(), dtype=dt).reshape(tex.height, tex.width, tex.components)
    a = a[::-1]
    a = a.astype(np.float32) / 255.0 if tex.dtype == "f1" else a.astype(np.float32)
    return a[..., 0].copy() if tex.components == 1 else np.ascontiguousarray(a)


def log_depth_scale(camera) -> float:
    """``1 / log2(clip_end / clip_start)``: the G-buffer's depth test runs on
    ``log2(view depth / clip_start) * scale`` (``shaders/gbuffer.glsl``), which keeps a relative
    depth resolution of ~1e-6 for any clip range (1e-4 .. 1e6 included)."""
    return float(1.0 / np.log2(float(camera.clip_end) / float(camera.clip_start)))


def _unit_cube() -> np.ndarray:
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(a, b, c_) for q in quads for (a, b, c_) in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return c[np.array(tris).ravel()]


# The vertex layout of every model buffer (de-indexed: 3 vertices per triangle, model space).
VERTEX_FORMAT = "3f 3f 3f"
VERTEX_ATTRS = ("in_pos", "in_face_normal", "in_shading_normal")
POSITION_FORMAT = "3f 24x"  # the same buffers read for positions only (depth-only passes)


def position_vertex_data(points: np.ndarray) -> np.ndarray:
    """(N, 9) float32 vertices of proxy geometry: positions only, normals zero."""
    out = np.zeros((len(points), 9), np.float32)
    out[:, :3] = points
    return out


def face_vertex_data(model) -> np.ndarray:
    """(3T, 9) float32 de-indexed positions, the triangle's unit face normal and the shading
    normal of each corner (the model's smooth normals, else the face normal)."""
    v = model.vertices.astype(np.float64)
    tri = v[model.triangles.astype(np.int64)]  # (T, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(ln > 0, n / np.where(ln > 0, ln, 1), 0.0)
    out = np.empty((len(tri), 3, 9), np.float32)
    out[:, :, :3] = model.vertices[model.triangles]
    out[:, :, 3:6] = n[:, None, :]
    out[:, :, 6:9] = n[:, None, :] if model.normals is None else model.normals
    return out.reshape(-1, 9)


class ModelBufferCache:
    """De-indexed vertex buffers (:data:`VERTEX_FORMAT`) per model, shared by the
    passes that rasterise the scene. Keyed by model identity; :meth:`prune` drops the buffers
    of models no longer in the scene."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._entries: dict = {}  # id(model) -> (model, vbo, vertex_count)

    def get(self, model):
        """``(vbo, vertex_count)``; vbo is None for a model without triangles."""
        e = self._entries.get(id(model))
        if e is None or e[0] is not model or e[2] != 3 * model.triangle_count:
            if e is not None and e[1] is not None:
                e[1].release()
            data = face_vertex_data(model)
            vbo = self.ctx.buffer(data.tobytes()) if len(data) else None
            e = (model, vbo, 3 * model.triangle_count)
            self._entries[id(model)] = e
        return e[1], e[2]

    def prune(self, models) -> None:
        keep = {id(m) for m in models}
        for k in [k for k in self._entries if k not in keep]:
            vbo = self._entries.pop(k)[1]
            if vbo is not None:
                vbo.release()

    def buffer_ids(self) -> dict:
        return {k: id(e[1]) for k, e in self._entries.items()}

    def release(self) -> None:
        self.prune(())


class InstanceBatch:
    """A growable dynamic instance buffer and the VAO drawing one vertex buffer with it."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.ibuf = None
        self.vao = None
        self.capacity = 0
        self._key = None

    def upload(self, data: np.ndarray, prog, vbo, vbo_format, vbo_attrs, inst_format, inst_attrs):
        nbytes = data.nbytes
        key = (id(prog), id(vbo))
        if self.ibuf is None or self.capacity < nbytes or key != self._key:
            if self.vao is not None:
                self.vao.release()
            if self.ibuf is None or self.capacity < nbytes:
                if self.ibuf is not None:
                    self.ibuf.release()
                self.capacity = max(nbytes, 2 * self.capacity, 256)
                self.ibuf = self.ctx.buffer(reserve=self.capacity, dynamic=True)
            self.vao = self.ctx.vertex_array(prog, [(vbo, vbo_format, *vbo_attrs),
                                                    (self.ibuf, inst_format, *inst_attrs)], skip_errors=True)
            self._key = key
        self.ibuf.write(data.tobytes())
        return self.vao

    def release(self):
        for o in (self.vao, self.ibuf):
            if o is not None:
                o.release()
        self.vao = self.ibuf = None
        self.capacity = 0


def sphere_proxy_matrices(scene, rows) -> np.ndarray:
    """World matrices mapping the unit sphere/cube onto each sphere primitive's bounding sphere."""
    inst = scene.instances
    mids = inst.model_ids[rows]
    c = np.array([scene.models[i].sphere_center for i in mids], np.float64).reshape(-1, 3)
    r = np.array([scene.models[i].sphere_radius for i in mids], np.float64)
    local = np.tile(np.eye(4), (len(rows), 1, 1))
    local[:, [0, 1, 2], [0, 1, 2]] = r[:, None]
    local[:, :3, 3] = c
    return inst.matrices[rows] @ local


class GBufferPass:
    """``render(scene, width, height) -> GBuffer``; caches vertex buffers per model.

    ``models`` (a :class:`ModelBufferCache`) can be shared with the shadow-map pass."""

    def __init__(self, ctx: moderngl.Context, programs, models: ModelBufferCache | None = None):
        self.ctx = ctx
        self.programs = programs
        self.models = models if models is not None else ModelBufferCache(ctx)
        self._batches: dict = {}  # model index -> InstanceBatch
        self._gbuffer: GBuffer | None = None
        self._sphere_vbo = None
        self.draw_calls = 0

    # -- targets -------------------------------------------------------------------------------
    def _targets(self, width, height) -> GBuffer:
        gb = self._gbuffer
        if gb is not None and gb.size == (width, height):
            return gb
        if gb is not None:
            gb.release()
        check_render_size(self.ctx, width, height, "G-buffer")
        tex = {}
        for name, comps, dt in TARGETS:
            t = self.ctx.texture((width, height), comps, dtype=dt)
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            t.repeat_x = t.repeat_y = False
            tex[name] = t
        depth = self.ctx.depth_texture((width, height))
        fbo = self.ctx.framebuffer(color_attachments=[tex[n] for n, _, _ in TARGETS], depth_attachment=depth)
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
        cols = [m[:, 0, :], m[:, 1, :], m[:, 2, :], nmat[:, 0, :], nmat[:, 1, :], nmat[:, 2, :],
                inst.base_color[rows].astype(np.float64),
                np.stack([inst.specular[rows], inst.roughness[rows], rows.astype(np.float64)], axis=1)]
        if spheres:
            inv = inst.inverse[rows].copy()
            # inverse of (T(-cam) @ M) = M^-1 @ T(cam): translation += M^-1[:3,:3] @ cam
            inv[:, :3, 3] += inv[:, :3, :3] @ cam_pos
            mids = inst.model_ids[rows]
            sph = np.array([[*scene.models[i].sphere_center, scene.models[i].sphere_radius] for i in mids], np.float64)
            cols += [inv[:, 0, :], inv[:, 1, :], inv[:, 2, :], sph.reshape(-1, 4)]
        return np.ascontiguousarray(np.concatenate(cols, axis=1), dtype=np.float32)

    # -- render ----------------------------------------------------------------------------------
    def render(self, scene, width: int, height: int) -> GBuffer:
        if scene.camera is None:
            raise SceneError(f"scene '{scene.name}' has no camera")
        width, height = int(width), int(height)
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
        self.models.prune(scene.models)
        inst = scene.instances
        if len(inst):
            prog = self.programs.get("gbuffer")
            cam.apply(prog)
            prog["u_log_depth_scale"].value = log_depth_scale(scene.camera)
            order = np.argsort(inst.model_ids, kind="stable")
            tri_rows = order[~inst.sphere[order]]
            bounds = np.searchsorted(inst.model_ids[tri_rows], np.arange(len(scene.models) + 1))
            for mi, model in enumerate(scene.models):
                rows = tri_rows[bounds[mi]:bounds[mi + 1]]
                if not len(rows) or not model.triangle_count:
                    continue
                vbo, nverts = self.models.get(model)
                data = self.instance_data(scene, rows, cam.cam_pos)
                vao = self._batch(mi).upload(data, prog, vbo, VERTEX_FORMAT, VERTEX_ATTRS,
                                             INSTANCE_FORMAT, INSTANCE_ATTRS)
                vao.render(moderngl.TRIANGLES, vertices=nverts, instances=len(rows))
                self.draw_calls += 1
            sph_rows = np.nonzero(inst.sphere)[0]
            if len(sph_rows):
                prog = self.programs.get("gbuffer", {"SPHERE": 1})
                cam.apply(prog)
                prog["u_log_depth_scale"].value = log_depth_scale(scene.camera)
                if self._sphere_vbo is None:
                    self._sphere_vbo = ctx.buffer(position_vertex_data(_unit_cube()).tobytes())
                data = self.instance_data(scene, sph_rows, cam.cam_pos, spheres=True)
                vao = self._batch("spheres").upload(data, prog, self._sphere_vbo, VERTEX_FORMAT, VERTEX_ATTRS,
                                                    SPHERE_FORMAT, SPHERE_ATTRS)
                vao.render(moderngl.TRIANGLES, vertices=36, instances=len(sph_rows))
                self.draw_calls += 1
        ctx.disable(moderngl.DEPTH_TEST)
        return gb

    def release(self) -> None:
        for b in self._batches.values():
            b.release()
        self._batches.clear()
        self.models.release()
        if self._gbuffer is not None:
            self._gbuffer.release()
            self._gbuffer = None
        if self._sphere_vbo is not None:
            self._sphere_vbo.release()
            self._sphere_vbo = None
