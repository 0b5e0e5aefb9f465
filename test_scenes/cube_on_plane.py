"""A 2 m cube standing on a 10 m plane, one sun at 45° elevation; 320x240. For unit tests."""
import os
import runpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("cube_on_plane", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
lib["add_object"]("Plane", lib["plane"]("Plane", 10.0, materials=[lib["material"]("Ground", (0.6, 0.6, 0.6))]))
lib["add_object"]("Cube", lib["box"]("Cube", (2, 2, 2), materials=[lib["material"]("Red", (0.8, 0.1, 0.1), 0.4)]),
                  location=(0, 0, 1))
lib["add_sun"]("Sun", elevation=45, azimuth=30, energy=3.0)
lib["add_camera"](scene, (7, -7, 5), (0, 0, 0.5), lens=35)
