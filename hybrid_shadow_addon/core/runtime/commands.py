"""The scene commands: what changes the scene a renderer holds, between frames.

A :class:`~..gpu.pipeline.Pipeline` applies them itself; a :class:`~.worker.RenderWorker` queues
them for its thread, a :class:`~.remote.RemoteWorker` for its renderer process (each as a message
of :mod:`.messages`). The scene sync (:mod:`..scene_sync`, the viewport's) calls them on any of the
three. A new command is declared here first; ``tests/test_scene_commands.py`` checks that all
three implement every one.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class SceneCommands(Protocol):
    def set_scene(self, scene, structure: str | None = None) -> object:
        """Bake ``scene`` afresh (``structure``: the acceleration structure; None: the settings')."""

    def move_instances(self, scene, indices) -> None:
        """Instances ``indices`` of ``scene`` moved (their matrices in ``scene``)."""

    def update_model(self, scene, model_id: int) -> None:
        """Model ``model_id`` of ``scene`` edited (its triangles in ``scene``)."""

    def reset_history(self) -> None:
        """Accumulated and reused shadows are stale (the lighting or the world changed)."""

    def reset_light(self, index: int) -> None:
        """Light ``index``'s reused shadow is stale (it moved or changed shape)."""
