"""The "Compare with Cycles" operator: :mod:`..tools.compare` on the current frame of the current
scene, against its Cycles reference (:class:`.cycles_reference.CyclesReferenceProvider`), with
progress, cancel (Esc / right click) and the report opened at the end.

Interactive: a modal operator; a window timer runs one step of
:func:`~..tools.compare.compare_steps` per tick (a Cycles render of one light, one frame of a
variant), so the UI shows progress between steps and Esc cancels between steps (the scene is
restored: each reference render restores it itself). In background mode (``bpy`` as a module,
``blender -b``) ``execute`` runs every step at once.

The variants render in the final-render process (:func:`.gl.final_renderer`): no GL context is
made on Blender's main thread, and a step waits at most about 20 ms for it without holding
Python's lock; a cancel ends what it was rendering.

Wiring (done by the add-on's registration): ``compare_operator.register()`` /
``unregister()``; in a panel ``compare_operator.draw_compare_button(layout)``;
:func:`menu_draw` is appended to ``TOPBAR_MT_render`` by :func:`register` itself.
"""
from __future__ import annotations

import os
import tempfile

import bpy

from ..core.errors import HybridShadowError
from .engine import ENGINE_ID

OPERATOR_ID = "render.hybrid_shadows_compare"


def exr_reader_missing() -> str | None:
    """Why Cycles' EXRs cannot be read here (one line), or None: they are read through the
    OpenImageIO module Blender ships (OpenEXR where installed); the plot needs no package."""
    from ..tools.exr import can_read_exr

    if can_read_exr():
        return None
    return "Compare with Cycles cannot read EXR files: this Blender has no OpenImageIO Python module"


def default_output_dir(scene) -> str:
    base = bpy.path.abspath("//") if bpy.data.filepath else tempfile.gettempdir()
    return os.path.join(base, f"hybrid_shadows_compare_{bpy.path.clean_name(scene.name)}_{scene.frame_current}")


class RENDER_OT_hybrid_shadows_compare(bpy.types.Operator):
    """Render a per-light Cycles visibility reference for the current frame and compare every
    shadow mode and quality against it: error against run time, in an HTML report"""

    bl_idname = OPERATOR_ID
    bl_label = "Compare with Cycles"
    bl_options = {"REGISTER"}

    output_dir: bpy.props.StringProperty(name="Output Folder", subtype="DIR_PATH", default="",
                                         description="Where the report goes (default: next to the .blend "
                                         "file, or the temporary folder)")
    modes: bpy.props.StringProperty(name="Modes", default="all",
                                    description="Variants, comma separated: raytrace-high, raytrace-medium, "
                                    "raytrace-low, raytrace-interlaced, shadowmap-N, none, raytrace, shadowmap, all")
    repeats: bpy.props.IntProperty(name="Repeats", default=3, min=1, max=50,
                                   description="Timed frames per variant (median)")
    resolution_percentage: bpy.props.IntProperty(name="Resolution %", default=50, min=1, max=100, subtype="PERCENTAGE",
                                                 description="Of the scene's render resolution")
    mesh_spheres: bpy.props.BoolProperty(name="Spheres as Meshes", default=False,
                                         description="Cycles renders objects marked Sphere Primitive as their "
                                         "meshes (default: as the sphere the add-on traces, so that the error "
                                         "measures the shadows)")
    open_report: bpy.props.BoolProperty(name="Open Report", default=True)

    _timer = None
    _steps = None
    _result = None

    @classmethod
    def poll(cls, context):
        return context.scene is not None and context.scene.camera is not None

    # -- the work --------------------------------------------------------------------------------
    def _start(self, context):
        missing = exr_reader_missing()
        if missing:
            raise HybridShadowError(missing)
        from ..tools.compare import compare_steps
        from ..tools.variants import resolve_variants
        from .cycles_reference import CyclesReferenceProvider
        from .frames import current_scene
        from .gl import final_renderer

        scene = context.scene
        r = scene.render
        pct = self.resolution_percentage / 100.0
        resolution = (max(1, round(r.resolution_x * pct)), max(1, round(r.resolution_y * pct)))
        self.output = bpy.path.abspath(self.output_dir) if self.output_dir else default_output_dir(scene)
        variants = resolve_variants([self.modes])
        core_scene = current_scene(resolution=resolution)
        self._result = {}
        self._steps = compare_steps(core_scene, self.output,
                                    reference=CyclesReferenceProvider(scene, mesh_spheres=self.mesh_spheres),
                                    resolution=resolution, variants=variants, repeats=self.repeats,
                                    remote=final_renderer(),
                                    scene_label=f"{scene.name} (frame {scene.frame_current})", result=self._result)

    def _finish(self, context):
        if self._steps is not None:
            self._steps.close()  # a cancelled generator runs its finally blocks (and cancels the render)
            self._steps = None
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.area:
            context.area.header_text_set(None)
        if context.workspace:
            context.workspace.status_text_set(None)

    def _done(self, context):
        report = os.path.join(self.output, "report.html")
        self.report({"INFO"}, f"Compare with Cycles: report in {report}")
        if self.open_report and not bpy.app.background:
            bpy.ops.wm.url_open(url="file://" + os.path.abspath(report))

    # -- background: all at once ------------------------------------------------------------------
    def execute(self, context):
        try:
            self._start(context)
            for _done, _total, _label in self._steps:
                pass
        except HybridShadowError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        finally:
            self._finish(context)
        self._done(context)
        return {"FINISHED"}

    # -- interactive: one step per timer tick ------------------------------------------------------
    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self._start(context)
        except HybridShadowError as e:
            self._finish(context)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"}:
            self._finish(context)
            self.report({"WARNING"}, "Compare with Cycles cancelled")
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"}
        try:
            done, total, label = next(self._steps)
        except StopIteration:
            self._finish(context)
            self._done(context)
            return {"FINISHED"}
        except HybridShadowError as e:
            self._finish(context)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:  # a bug: still clean up
            self._finish(context)
            self.report({"ERROR"}, f"Compare with Cycles failed: {type(e).__name__}: {e}")
            return {"CANCELLED"}
        context.window_manager.progress_update(int(100 * done / max(total, 1)))
        text = f"Compare with Cycles: {done}/{total} {label} (Esc to cancel)"
        if context.area:
            context.area.header_text_set(text)
        if context.workspace:
            context.workspace.status_text_set(text)
        return {"RUNNING_MODAL"}


# ------------------------------------------------------------------------------------------------
# UI hooks
# ------------------------------------------------------------------------------------------------
def draw_compare_button(layout) -> None:
    """The button, for a panel's ``draw`` (the lead puts it in the render panel)."""
    layout.operator(OPERATOR_ID, icon="IMAGE_REFERENCE")


def menu_draw(self, context) -> None:
    """Appended to the Render menu (``TOPBAR_MT_render``), shown while the engine is active."""
    if context.engine != ENGINE_ID:
        return
    self.layout.separator()
    draw_compare_button(self.layout)


classes = (RENDER_OT_hybrid_shadows_compare,)


def register() -> None:
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.TOPBAR_MT_render.append(menu_draw)


def unregister() -> None:
    try:
        bpy.types.TOPBAR_MT_render.remove(menu_draw)
    except (AttributeError, ValueError):
        pass
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
