"""Children that run another tree's code: a peer tree (an earlier commit checked out in a folder)
or this one, each in a subprocess of its own.

A child starts in the tree, with the tree first on ``PYTHONPATH``, so that it imports that tree's
``hybrid_shadow_addon`` (its ``shaders/`` and ``test_scenes/`` beside it) ahead of the installed
package."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def tree_env(tree, env: dict | None = None) -> dict:
    """``env`` (this process's environment by default) with ``tree`` first on ``PYTHONPATH`` (and
    there once)."""
    tree = Path(tree).resolve()
    env = dict(os.environ if env is None else env)
    rest = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != tree]
    env["PYTHONPATH"] = os.pathsep.join([str(tree), *rest])
    return env


def run_in_tree(tree, args: list, **kw) -> subprocess.CompletedProcess:
    """``python ARGS`` in ``tree`` (its folder the working directory, first on ``PYTHONPATH``),
    the output captured as text."""
    tree = Path(tree).resolve()
    return subprocess.run([sys.executable, *map(str, args)], cwd=tree, env=tree_env(tree), capture_output=True,
                          text=True, **kw)
