"""A 4-frame animation for tests: a cube slides and turns across a plane past a static sphere
and a static box, under a sun and a point light; the camera is still. PARAMS: frames (default
4), width, height (default 160x120)."""
import os
import runpy

import bpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})
FRAMES = int(PARAMS.get("frames", 4))

scene = lib["setup_scene"]("animated", (int(PARAMS.get("width", 160)), int(PARAMS.get("height", 120))),
                           (1, FRAMES))
lib["set_world"](scene, (0.05, 0.06, 0.08))
grey = lib["material"]("Ground", (0.6, 0.6, 0.6))
lib["add_object"]("Plane", lib["plane"]("Plane", 12.0, materials=[grey]))
lib["add_object"]("Pillar", lib["box"]("Pillar", (0.6, 0.6, 2.5), base_at_origin=True, materials=[grey]),
                  location=(2.5, 2.0, 0))
lib["add_object"]("Ball", lib["uv_sphere"]("Ball", radius=0.7, segments=16, rings=8,
                                           materials=[lib["material"]("Blue", (0.1, 0.2, 0.8), 0.3)]),
                  location=(-2.0, 2.0, 0.7))
cube = lib["add_object"]("Cube", lib["box"]("Cube", (1.2, 1.2, 1.2),
                                           materials=[lib["material"]("Red", (0.8, 0.1, 0.1))]),
                         location=(-3.0, -1.0, 0.6))
edit = bpy.context.preferences.edit
interpolation, edit.keyframe_new_interpolation_type = edit.keyframe_new_interpolation_type, "LINEAR"
cube.keyframe_insert("location", frame=1)
cube.keyframe_insert("rotation_euler", frame=1)
cube.location, cube.rotation_euler = (3.0, -0.5, 0.6), (0, 0, 1.2)
cube.keyframe_insert("location", frame=FRAMES)
cube.keyframe_insert("rotation_euler", frame=FRAMES)
edit.keyframe_new_interpolation_type = interpolation  # (linear keys: every frame moves evenly)
lib["add_sun"]("Sun", elevation=40, azimuth=30, energy=3.0)
lib["add_light"]("Lamp", "POINT", (0.0, -3.0, 3.0), energy=600.0, shadow_soft_size=0.1)
lib["add_camera"](scene, (0, -9, 6), (0, 0, 0.5), lens=30)
scene.frame_set(1)
