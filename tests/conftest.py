"""Shared test set-up: Blender's user files go to a temporary folder, never $HOME."""
import os
import sys
import tempfile
from pathlib import Path

import pytest

from tests.helpers.blender_env import TEST_SCENES

_tmp = Path(tempfile.mkdtemp(prefix="hs-blender-user-"))
for var in ("BLENDER_USER_RESOURCES", "XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
    os.environ.setdefault(var, str(_tmp / var.lower()))

_EXIT = pytest.StashKey[int]()  # pytest's exit status, kept for pytest_unconfigure


@pytest.fixture(scope="session")
def gl_ctx():
    """One standalone OpenGL context for the whole session."""
    from hybrid_shadow_addon.core.gpu.context import create_context

    return create_context()


@pytest.fixture(scope="module")
def pipeline(gl_ctx):
    """A Pipeline on the session's context, for one test module."""
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    p = Pipeline(gl_ctx)
    yield p
    p.release()


@pytest.fixture(scope="module")
def pass_rig(gl_ctx):
    """A :class:`~tests.helpers.rig.PassRig` (the passes one by one) on the session's context,
    for one test module."""
    from tests.helpers.rig import PassRig

    r = PassRig(gl_ctx)
    yield r
    r.release()


@pytest.fixture(scope="module")
def loaded():
    """``loaded(name)``: the core Scene of a TEST_SCENES entry (or any SCENE argument), loaded
    once per test module."""
    from hybrid_shadow_addon.blender.load import load_scene

    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = load_scene(TEST_SCENES.get(name, name))
        return cache[name]

    return get


def pytest_sessionfinish(session, exitstatus):
    session.config.stash[_EXIT] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """The parallel run's controller (``make test`` runs ``pytest -n``) reads the workers'
    warnings, whose add-on classes import bpy; bpy 4.5 then crashes while the interpreter
    finalises a process that never ran Blender. That process ends here, with pytest's status
    (everything is written by now)."""
    if "bpy" in sys.modules and config.pluginmanager.hasplugin("dsession") and _EXIT in config.stash:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(config.stash[_EXIT])
