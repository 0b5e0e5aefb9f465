"""Every renderer the scene sync drives takes every scene command
(``core/runtime/commands.py``): the pipeline itself, the in-process worker and the renderer
process's worker, with the protocol's parameters in its order."""
from __future__ import annotations

import inspect

import pytest

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.runtime.commands import SceneCommands
from hybrid_shadow_addon.core.runtime.remote import RemoteWorker
from hybrid_shadow_addon.core.runtime.worker import RenderWorker

COMMANDS = [name for name, member in vars(SceneCommands).items()
            if callable(member) and not name.startswith("_")]


def test_the_protocol_declares_the_five_commands():
    assert sorted(COMMANDS) == ["move_instances", "reset_history", "reset_light", "set_scene", "update_model"]


@pytest.mark.parametrize("cls", [Pipeline, RenderWorker, RemoteWorker], ids=lambda c: c.__name__)
@pytest.mark.parametrize("name", COMMANDS)
def test_each_renderer_implements_each_command(cls, name):
    method = getattr(cls, name, None)
    assert callable(method), f"{cls.__name__} has no {name}"
    want = list(inspect.signature(getattr(SceneCommands, name)).parameters.values())
    have = list(inspect.signature(method).parameters.values())
    assert [p.name for p in have[:len(want)]] == [p.name for p in want], (cls.__name__, name)
    for p, q in zip(want, have):  # (a protocol default stays a default)
        assert (p.default is inspect.Parameter.empty) or (q.default is not inspect.Parameter.empty), (cls, name, p)
    for extra in have[len(want):]:  # (what a renderer adds is optional)
        assert extra.default is not inspect.Parameter.empty or extra.kind is inspect.Parameter.VAR_KEYWORD


def test_a_class_missing_a_command_is_not_a_renderer():
    class Partial:
        def set_scene(self, scene, structure=None):
            pass

    assert not isinstance(Partial(), SceneCommands)
    assert isinstance(RenderWorker.__new__(RenderWorker), SceneCommands)
