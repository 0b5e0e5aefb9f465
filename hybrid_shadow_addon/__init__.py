"""Hybrid Shadows: ray-traced shadow masks over a rasterised G-buffer, for Blender.

``hybrid_shadow_addon.core`` is bpy-free (numpy + moderngl) and usable on its own;
``hybrid_shadow_addon.blender`` feeds it from Blender. ``register``/``unregister`` are the
add-on entry points and import bpy only when called.
"""

__version__ = "0.1.0"


def register():
    from .blender import register as _register

    _register()


def unregister():
    from .blender import unregister as _unregister

    _unregister()
