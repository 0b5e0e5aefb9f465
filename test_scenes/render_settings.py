"""What a final render evaluates apart from the viewport, one difference per object, on a 12 m
plane under a sun (320x240): ``Render Only``, a column disabled in the viewports but rendered;
``Viewport Array``, a block whose Array modifier (three blocks) is enabled in the viewport only;
``Smooth``, a cube under a Subdivision Surface at level 0 in the viewport and 3 for render."""
import os
import runpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("render_settings", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.06, 0.08))
grey = lib["material"]("Grey", (0.6, 0.6, 0.6))
lib["add_object"]("Plane", lib["plane"]("Plane", 12.0, materials=[grey]))
column = lib["add_object"]("Render Only", lib["box"]("Column", (1.0, 1.0, 3.0), base_at_origin=True, materials=[grey]),
                           location=(-3.0, 1.0, 0.0))
column.hide_viewport = True
block = lib["add_object"]("Viewport Array", lib["box"]("Block", (1.0, 1.0, 1.0), base_at_origin=True, materials=[grey]),
                          location=(0.0, -1.5, 0.0))
array = block.modifiers.new("Array", "ARRAY")
array.count = 3
array.relative_offset_displace = (0.0, 1.5, 0.0)
array.show_render = False
smooth = lib["add_object"]("Smooth", lib["box"]("Rounded", (2.0, 2.0, 2.0), materials=[grey]), location=(3.0, 0.0, 1.2))
subsurf = smooth.modifiers.new("Subdivision", "SUBSURF")
subsurf.levels = 0
subsurf.render_levels = 3
lib["add_sun"]("Sun", elevation=35, azimuth=-60, energy=3.0)
lib["add_camera"](scene, (0.0, -12.0, 8.0), (0.0, 0.0, 0.5), lens=30)
