"""Shared test set-up: Blender's user files go to a temporary folder, never $HOME."""
import os
import sys
import tempfile
from pathlib import Path

_tmp = Path(tempfile.mkdtemp(prefix="hs-blender-user-"))
for var in ("BLENDER_USER_RESOURCES", "XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
    os.environ.setdefault(var, str(_tmp / var.lower()))

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def gl_ctx():
    """One standalone OpenGL context for the whole session (skips only if none can exist)."""
    from hybrid_shadow_addon.core.gpu.context import create_context

    return create_context()
