"""The ``HYBRID_SHADOWS`` render engine: the ``RenderEngine`` class, forwarding to
:mod:`.final_render` (final renders and their passes) and :mod:`.viewport_engine` (the rendered
viewport, rendered in a renderer process shared by the viewports of a scene: a
:class:`~..core.runtime.remote.RemoteWorker`). OpenGL contexts: :mod:`.gl`.
"""
from __future__ import annotations

import bpy

from . import final_render, viewport_engine
from .gl import release_shared

ENGINE_ID = "HYBRID_SHADOWS"


class HybridShadowsEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "Hybrid Shadows"
    bl_use_preview = False  # material/light previews: Blender's own
    bl_use_eevee_viewport = True  # Material Preview shading uses EEVEE, as with Cycles
    bl_use_shading_nodes_custom = False  # standard shader nodes in the node editor

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        viewport_engine.init(self)

    def __del__(self):
        viewport_engine.free(self)

    # -- final render -----------------------------------------------------------------------------
    def update_render_passes(self, scene=None, renderlayer=None):
        final_render.register_passes(self, scene, renderlayer)

    def render(self, depsgraph):
        final_render.render(self, depsgraph)

    # -- viewport ---------------------------------------------------------------------------------
    def view_update(self, context, depsgraph):
        viewport_engine.view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        viewport_engine.view_draw(self, context, depsgraph)

    def _view_render(self, scene, rv3d, width, height) -> None:
        viewport_engine.view_render(self, scene, rv3d, width, height)


CLASSES = (HybridShadowsEngine,)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    viewport_engine.register()


def unregister() -> None:
    viewport_engine.unregister()  # stops the viewport workers and their contexts
    release_shared()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
