"""The one interface of all passes.

A pass is built on the context's :class:`~..resources.GpuResources`, keeps its own render
targets from frame to frame, and turns a :class:`~..frame.FrameJob` into one product:
``render(job)`` reads what earlier passes left in the job and returns what the pass
:attr:`~Pass.produces` (the pipeline stores it in that field of the job).
"""
from __future__ import annotations


class Pass:
    #: the ``FrameJob`` field this pass's product goes to
    produces: str = ""
    #: the timing key (``<name>_ms``)
    name: str = ""
    #: the progress label of this pass's step; None when the pass reports per light instead
    label: str | None = None

    def __init__(self, gpu):
        self.gpu = gpu
        self.ctx = gpu.ctx
        self.programs = gpu.programs

    def render(self, job):
        raise NotImplementedError

    def reset_history(self) -> None:
        """Forget anything carried over from earlier frames (camera, scene or setting change)."""

    def camera_moved(self) -> None:
        """The camera moved (nothing else): what the pass cannot carry over is forgotten."""
        self.reset_history()

    def invalidate(self, boxes) -> None:
        """Objects whose old and new bounds are ``boxes`` ((n, 2, 3), bake space) changed."""
        self.reset_history()

    def reset_light(self, index: int) -> None:
        """Light ``index`` changed."""
        self.reset_history()

    def release(self) -> None:
        """Release the pass's own GL objects (not the shared resources)."""


class ShadowPass(Pass):
    """A shadow mode: one mask per shadowed light (``job.lights``), ``{light index: texture}``,
    at G-buffer resolution or at a reduced one that the upsample pass brings to full size."""

    produces = "masks"
    name = "shadow"
    #: shown as ``"<light_label>: <light name>"`` before each light; None: no per-light steps
    light_label: str | None = None
    #: whether the pass traces the baked scene (the pipeline bakes before the first frame)
    needs_bake: bool = False

    def configure_reuse(self, enabled: bool, auto: bool, exact: bool) -> bool:
        """How the next frame may reuse visibility from earlier frames: ``enabled`` (else it
        forgets), ``auto`` (light by light where that is timed cheaper; else always) and ``exact``
        (this frame traces its hard masks whole and keeps them). Whether this mode reuses (one
        that does not ignores it)."""
        return False

    def stats(self, job, counts: bool = True) -> dict:
        """``mask_resolution``, ``rays`` (the rays a full trace of the mask would take),
        ``rays_traced`` (the rays actually traced), ``pixels`` (pixels with geometry x shadowed
        lights; 0 where a mode does not count them) and shader ``defines`` of the last render.
        ``counts`` False: what only the GPU counted is not read back (None)."""
        return {"mask_resolution": list(job.size), "rays": 0, "rays_traced": 0, "pixels": 0, "defines": []}


class LightVisibility(Pass):
    """One side of a shadow pass's per-light work (the ray-traced pass's hard or soft
    visibility): between :meth:`begin_frame` and :meth:`end_frame` of a job,
    :meth:`light` returns one light's mask texture."""

    def begin_frame(self, job) -> None:
        """Once per frame, before its lights."""

    def light(self, job, ray):
        raise NotImplementedError

    def end_frame(self, job) -> None:
        """Once per frame, after its lights."""
