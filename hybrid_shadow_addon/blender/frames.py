"""Core scenes of a loaded bpy scene as a final render evaluates them, frame by frame: the
current frame (:func:`current_scene`) and its animation (:class:`BlenderFrames`, the frame source of the
``bench`` tool and of ``render --frames``)."""
from __future__ import annotations

import bpy

from ..core.scene import Scene
from .render_eval import render_scene


def current_scene(*, resolution=None) -> Scene:
    """The validated core scene of the context's scene at its current frame, as a final render
    evaluates it (``resolution`` overrides the render settings')."""
    return render_scene(bpy.context.scene, resolution=resolution)


class BlenderFrames:
    """The frames ``frame_start..frame_end`` of ``bscene`` (the context's scene), exported one
    at a time; ``name`` labels the results (default: the scene's name); ``resolution``
    overrides the render settings'."""

    def __init__(self, bscene, name: str | None = None, resolution=None):
        self.bscene = bscene
        self.name = name or bscene.name
        self.resolution = resolution

    @property
    def version(self) -> str:
        return bpy.app.version_string

    @property
    def frame_range(self) -> tuple:
        return int(self.bscene.frame_start), int(self.bscene.frame_end)

    def scene_at(self, frame: int) -> Scene:
        """Set ``bscene`` to ``frame`` and export it."""
        self.bscene.frame_set(int(frame))
        return current_scene(resolution=self.resolution)
