"""The scene as a final render evaluates it, for the command line, ``compare`` and ``--frames``.

Blender evaluates a scene either for the viewport (``bpy.context.evaluated_depsgraph_get()``) or
for a render (F12, ``blender -b -a``, Cycles' references). They differ wherever a setting has a
viewport and a render side: objects and collections hidden in the viewport but rendered,
modifiers enabled in one of the two, Subdivision Surface levels, curve, metaball and particle
resolutions and amounts, Geometry Nodes' "Is Viewport". Python is handed a render-mode
depsgraph only inside a render engine's ``render()``: :func:`render_scene` runs Blender's own
F12 path with a small engine (:class:`RenderEvaluation`) that exports the depsgraph it is given
and draws nothing (no compositing, the render result left empty). The viewport engine keeps the
viewport's evaluation.
"""
from __future__ import annotations

import bpy

from ..core.errors import SceneError
from ..core.scene import Scene
from .export import export_depsgraph


class RenderEvaluation(bpy.types.RenderEngine):
    """Exports the render depsgraph of one ``bpy.ops.render.render()`` into :attr:`request`."""

    bl_idname = "HS_RENDER_EVALUATION"
    bl_label = "Hybrid Shadows (render evaluation)"
    bl_use_postprocess = False  # (no compositing or sequencer over the empty result)

    #: {"resolution": ...} in; "scene" (a core Scene) or "error" (the exception) out (no
    #: annotation: Blender would read one as a property definition)
    request = None

    def render(self, depsgraph):
        req = RenderEvaluation.request
        if req is None:
            return
        try:
            req["scene"] = export_depsgraph(depsgraph, resolution=req.get("resolution"))
        except BaseException as exc:  # (re-raised by render_scene: Blender would print and drop it)
            req["error"] = exc


def render_scene(bscene=None, *, resolution=None) -> Scene:
    """The validated core scene of ``bscene`` (default: the context's) at its current frame, as
    a final render evaluates it (``resolution``: (width, height) overriding the render
    settings'). The scene's render engine is restored afterwards, and the engine class
    unregistered (bpy 4.5 waits forever at exit for a registered one)."""
    bscene = bscene or bpy.context.scene
    req = {"resolution": resolution}
    bpy.utils.register_class(RenderEvaluation)
    engine = bscene.render.engine
    try:
        bscene.render.engine = RenderEvaluation.bl_idname
        if bscene.render.engine != RenderEvaluation.bl_idname:  # (else the scene's own engine would render)
            raise SceneError(f"scene '{bscene.name}': its render engine cannot be switched for the export")
        RenderEvaluation.request = req
        bpy.ops.render.render(scene=bscene.name)
    finally:
        RenderEvaluation.request = None
        bscene.render.engine = engine
        bpy.utils.unregister_class(RenderEvaluation)
    if "error" in req:
        raise req["error"]
    if "scene" not in req:
        raise SceneError(f"scene '{bscene.name}': Blender rendered no frame (is the view layer's Render "
                         "Single Layer or the scene's camera off?)")
    return req["scene"].validate()
