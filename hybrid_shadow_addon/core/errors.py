"""Errors the user sees: every one carries a one-line, readable message.

The CLI prints ``str(error)`` on one line and exits with code 2; the Blender side reports it
with ``report({'ERROR'}, ...)``. Anything else escaping is a bug.
"""


class HybridShadowError(Exception):
    """Base class of all errors meant for the user."""


class SceneError(HybridShadowError):
    """The scene is unusable: invalid values, no camera, nothing to render, ..."""


class SceneLoadError(HybridShadowError):
    """A scene argument could not be loaded (missing file, failing script, unreadable .blend)."""


class GPUError(HybridShadowError):
    """No usable OpenGL context, or a request beyond the GPU's limits."""


class Cancelled(HybridShadowError):  # noqa: N818 - a user's choice, not an error; a public name
    """The user cancelled (Esc in Blender, a progress callback that raises it)."""
