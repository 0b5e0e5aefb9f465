"""The messages between a caller and its renderer process (:mod:`.remote`, :mod:`.render_server`).

Each is a frozen dataclass with named fields, pickled across the channel (:mod:`.channel`). A
message that coalesces with unsent ones says so itself: :meth:`Message.supersedes` (which
unsent messages it replaces) and :meth:`Message.merged` (what is queued for them: itself, or for
moves one message of every moved instance). The server dispatches each on its class (``Server.handlers``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np


class Message:
    """Base of every message."""

    #: equal keys coalesce: an unsent message with this message's key is dropped when it is
    #: posted (None: never)
    merge_key = None

    def supersedes(self, other: Message) -> bool:
        """Whether ``other``, posted earlier and still unsent, is dropped when this one is posted."""
        return self.merge_key is not None and getattr(other, "merge_key", None) == self.merge_key

    def merged(self, dropped: list[Message]) -> Message:
        """What is queued in place of ``dropped`` (the unsent messages it superseded) and itself."""
        return self


# -- the caller's: the viewport's scene commands ---------------------------------------------------
@dataclass(frozen=True)
class Bake(Message):
    """A new bake of ``scene``; it stands for the unsent bakes, moves and model edits before it."""

    scene: Any
    structure: str | None = None

    def supersedes(self, other: Message) -> bool:
        return isinstance(other, (Bake, MoveInstances, UpdateModel))


@dataclass(frozen=True)
class MoveInstances(Message):
    """Instances ``indices`` of ``scene`` moved; unsent moves become one."""

    scene: Any
    indices: np.ndarray
    merge_key = "move"

    def merged(self, dropped: list[MoveInstances]) -> MoveInstances:
        """One move for ``dropped`` and this one: every moved instance, this (the newest) scene."""
        idx = np.unique(np.concatenate([m.indices for m in dropped] + [self.indices]))
        return replace(self, indices=idx)


@dataclass(frozen=True)
class UpdateModel(Message):
    """Model ``model_id`` of ``scene`` edited; an unsent edit of the same model is replaced."""

    scene: Any
    model_id: int

    @property
    def merge_key(self):
        return ("model", self.model_id)


@dataclass(frozen=True)
class ResetHistory(Message):
    """Every view's accumulated history is stale."""


@dataclass(frozen=True)
class ResetLight(Message):
    """Light ``index``'s reused shadow is stale."""

    index: int


#: messages that act on the scene a renderer holds (dropped, unsent, when it ends)
SCENE_COMMANDS = (Bake, MoveInstances, UpdateModel, ResetHistory, ResetLight)


# -- the caller's: the viewport's frames -----------------------------------------------------------
@dataclass(frozen=True)
class ViewScene(Message):
    """The scene (without a camera) of the render requests that carry ``token``."""

    token: int
    scene: Any
    merge_key = "scene"


@dataclass(frozen=True)
class RenderView(Message):
    """Render ``request`` (its scene: only the camera and resolution) over the scene ``token``;
    ``seq``: the caller's number of the request. An unsent request of the same view is replaced."""

    request: Any
    token: int
    seq: int

    @property
    def merge_key(self):
        return ("render", self.request.view)


@dataclass(frozen=True)
class DropView(Message):
    """A view is gone: its unsent requests too."""

    view: Any

    def supersedes(self, other: Message) -> bool:
        return isinstance(other, RenderView) and other.request.view == self.view


# -- the caller's: final frames and calls ------------------------------------------------------------
@dataclass(frozen=True)
class FinalFrame(Message):
    """Job ``job``: one final frame (``FinalRenderer.render``'s options)."""

    job: int
    scene: Any
    settings: Any
    width: int
    height: int
    options: dict


@dataclass(frozen=True)
class Call(Message):
    """Job ``job``: run the generator function ``function(**kwargs)`` of this package to its end
    (pickled by reference: the renderer imports the same module)."""

    job: int
    function: Callable
    kwargs: dict


@dataclass(frozen=True)
class Cancel(Message):
    """Stop job ``job`` between two of its steps; an unsent job is dropped instead."""

    job: int

    def supersedes(self, other: Message) -> bool:
        return isinstance(other, (FinalFrame, Call)) and other.job == self.job


@dataclass(frozen=True)
class Close(Message):
    """The channel ended: the renderer's loop returns (never crosses)."""


# -- the renderer's --------------------------------------------------------------------------------
@dataclass(frozen=True)
class ViewFrame(Message):
    """A view's finished frame (``result``: a ``ViewResult`` or None) and its errors (``error_info``s)."""

    view: Any
    result: Any
    errors: list


@dataclass(frozen=True)
class ServerState(Message):
    """After a round: the newest message applied (``acked``), which views still have work, and
    whether any work is left."""

    acked: int
    busy: dict
    busy_any: bool


@dataclass(frozen=True)
class Progress(Message):
    """Job ``job`` reached step ``done`` of ``total`` (0: unknown), named ``label``."""

    job: int
    done: int
    total: int
    label: str


@dataclass(frozen=True)
class JobDone(Message):
    """Job ``job`` ended: its ``value``, or ``error`` (an ``error_info``)."""

    job: int
    value: Any
    error: tuple | None


@dataclass(frozen=True)
class Alive(Message):
    """The renderer's heartbeat."""


@dataclass(frozen=True)
class SendError(Message):
    """Message ``message`` (number ``seq``) could not be pickled: ``error`` (an ``error_info``).
    Made on the caller's side; never crosses."""

    seq: int
    error: tuple
    message: Any
