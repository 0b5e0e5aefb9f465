"""What one frame's passes share: the camera uniforms, the G-buffer, the :class:`FrameJob` every
pass reads its inputs from, and reading masks back."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import moderngl
import numpy as np

from .targets import read_texture, set_uniforms

# name -> (components, dtype) of the G-buffer's colour attachments, in attachment order
GBUFFER_TARGETS = (
    ("position", 4, "f4"),
    ("normal", 4, "f4"),
    ("shading_normal", 4, "f4"),
    ("albedo", 4, "f2"),
    ("material", 4, "f4"),
    ("depth", 1, "f4"),
    ("terminator", 4, "f4"),
)
GB_SAMPLERS = {"position": "u_gb_position", "normal": "u_gb_normal", "shading_normal": "u_gb_shading",
               "albedo": "u_gb_albedo", "material": "u_gb_material", "depth": "u_gb_depth",
               "terminator": "u_gb_terminator"}


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
    def from_camera(cls, camera, width: int, height: int) -> CameraUniforms:
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
        set_uniforms(prog, vals)


@dataclass
class GBuffer:
    """The G-buffer textures (owned by the pass, overwritten by its next render).

    ``position`` RGBA32F world xyz, w = 1 on geometry and 0 on background; ``normal`` RGBA32F
    unit geometric (face) normal turned towards the camera; ``shading_normal`` RGBA32F (the
    smooth normal, turned over with the geometric one where the camera sees a triangle's back);
    ``albedo`` RGBA16F linear base colour; ``material`` RGBA32F (specular, roughness, instance
    index, 1; on a holdout's pixels, which are background to every other target: 0, 0, index,
    -1); ``depth`` R32F view depth in metres (0 on background); ``terminator`` RGBA32F
    (the smooth-surface lift of Cycles' shadow terminator in the world, the object's geometry
    offset; zero on flat models); ``depth_buffer`` the
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


@dataclass
class FrameJob:
    """The inputs and products of one frame, passed to every pass's ``render``.

    The pipeline fills ``lights`` (the shadowed light indices, in mask order) and stores each
    pass's product in the field the pass :attr:`~.passes.base.Pass.produces`: ``gbuffer``, then
    ``masks`` (``{light index: R32F texture}``, 1 lit, 0 shadowed; lights without an entry are
    unshadowed), then ``image`` (the RGBA32F lighting texture). ``on_light(index)`` is called
    by the shadow passes before each light (progress and cancel). ``dark``: lights a shadow pass
    found to light no pixel (their reach holds no visible surface, their mask is 0 on every
    one): the lighting leaves them out, as it would add nothing of theirs. ``alpha_sample``: the
    sample index of a see-through accumulation (the G-buffer's stochastic alpha cut), None: the
    cut at 0.5."""

    scene: object
    settings: object
    width: int
    height: int
    film_transparent: bool = False
    lights: list = field(default_factory=list)
    gbuffer: GBuffer | None = None
    masks: dict = field(default_factory=dict)
    image: moderngl.Texture | None = None
    on_light: Callable[[int], None] | None = None
    dark: set = field(default_factory=set)
    alpha_sample: int | None = None

    @property
    def size(self) -> tuple:
        return int(self.width), int(self.height)

    def light_started(self, index: int) -> None:
        if self.on_light is not None:
            self.on_light(index)


def mask_source_pixels(mask_size, full_size, scale: int):
    """Full-resolution (rows, cols) in numpy (top-down) order sampled by each mask texel,
    as two (h, w) int arrays for a mask of ``mask_size`` = (w, h)."""
    mw, mh = mask_size
    fw, fh = full_size
    xs = np.minimum(np.arange(mw) * scale + scale // 2, fw - 1)
    ys_gl = np.minimum(np.arange(mh) * scale + scale // 2, fh - 1)  # bottom-up
    rows_gl = np.broadcast_to(ys_gl[:, None], (mh, mw))
    cols = np.broadcast_to(xs[None, :], (mh, mw))
    rows = (fh - 1 - rows_gl)[::-1]  # numpy row 0 = top = GL row mh-1
    return np.ascontiguousarray(rows), np.ascontiguousarray(cols)


def read_mask(tex: moderngl.Texture, gbuffer: GBuffer | None = None, coverage: np.ndarray | None = None) -> np.ndarray:
    """float32 (H, W), row 0 = top; NaN where the G-buffer has no geometry (when given; pass its
    ``coverage()`` too when reading several masks, to read the G-buffer once).

    A reduced-resolution mask gets NaN where its source pixel has no geometry."""
    m = read_texture(tex)
    if gbuffer is not None:
        cov = gbuffer.coverage() if coverage is None else coverage
        if m.shape != cov.shape:
            scale = max(1, round(gbuffer.width / tex.width))
            rows, cols = mask_source_pixels((tex.width, tex.height), gbuffer.size, scale)
            cov = cov[rows, cols]
        m = np.where(cov, m, np.nan).astype(np.float32)
    return m
