"""The Blender side of Hybrid Shadows: everything here imports bpy.

- :mod:`.export`: an evaluated depsgraph → :class:`hybrid_shadow_addon.core.scene.Scene`.
- :mod:`.load`: a scene script, built-in test scene or ``.blend`` file → a loaded bpy scene or a
  core ``Scene``.
- :mod:`.engine` (the ``HYBRID_SHADOWS`` render engine) with :mod:`.final_render`,
  :mod:`.viewport_engine` (the viewport, rendered in a renderer process shared by the viewports
  of a scene: :class:`~hybrid_shadow_addon.core.runtime.remote.RemoteWorker`; in-process, a
  :class:`~hybrid_shadow_addon.core.runtime.worker.RenderWorker` thread), :mod:`.viewport` and
  :mod:`.gl` (its OpenGL contexts);
  :mod:`.properties`, :mod:`.ui`, :mod:`.compare_operator` ("Compare with Cycles"): the add-on.
"""

# -- add-on registration --------------------------------------------------------------------------
# Order matters: properties before the engine and the panels that draw them; unregistered in
# reverse. ``engine.unregister`` also releases the shared final-render OpenGL context.
_MODULES = ("properties", "engine", "compare_operator", "ui")
_registered: list = []


def register():
    import importlib

    try:
        for name in _MODULES:
            module = importlib.import_module(f".{name}", __name__)
            module.register()
            _registered.append(module)
    except Exception:
        unregister()
        raise


def unregister():
    while _registered:
        module = _registered.pop()
        try:
            module.unregister()
        except Exception:  # keep unregistering the rest: a left-over engine hangs Blender at exit
            import traceback

            traceback.print_exc()
