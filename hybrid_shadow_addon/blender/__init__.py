"""The Blender side of Hybrid Shadows: everything here imports bpy.

- :mod:`.export`: an evaluated depsgraph → :class:`hybrid_shadow_addon.core.scene.Scene`.
- :mod:`.load`: a scene script, built-in test scene or ``.blend`` file → a loaded bpy scene or a
  core ``Scene``.
"""
