"""The scene camera and the render size."""
from __future__ import annotations

from ...core.errors import SceneError
from ...core.scene import Camera
from .common import to_matrix


def render_resolution(scene) -> tuple[int, int]:
    """The render size in pixels, as Blender computes it (integer percentage scaling)."""
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100,
            r.resolution_y * r.resolution_percentage // 100)


def export_camera(depsgraph) -> Camera | None:
    """The scene camera (evaluated at the depsgraph's frame), or None when the scene has none."""
    ob = depsgraph.scene.camera
    if ob is None:
        return None
    ob = ob.evaluated_get(depsgraph)
    if ob.type != "CAMERA":
        raise SceneError(f"the scene camera '{ob.name}' is a {ob.type.lower()} object, not a camera")
    d = ob.data
    return Camera(name=ob.name, matrix=to_matrix(ob.matrix_world), type=d.type, lens=d.lens,
                  sensor_width=d.sensor_width, sensor_height=d.sensor_height,
                  sensor_fit=d.sensor_fit, ortho_scale=d.ortho_scale, shift_x=d.shift_x,
                  shift_y=d.shift_y, clip_start=d.clip_start, clip_end=d.clip_end)
