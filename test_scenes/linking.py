"""Light and shadow linking (Blender 4.0+): a lamp whose receiver collection excludes the statue
(it lights everything else) and whose blocker collection includes only the pillar (the crate is
listed as excluded; the statue and the crate cast none of its shadows), beside a sun without
linking; 320x240."""
import os
import runpy

import bpy

lib = runpy.run_path(os.path.join(os.path.dirname(__file__), "_lib.py"))
PARAMS = globals().get("PARAMS", {})

scene = lib["setup_scene"]("linking", (int(PARAMS.get("width", 320)), int(PARAMS.get("height", 240))))
lib["set_world"](scene, (0.05, 0.05, 0.06))
grey = lib["material"]("Grey", (0.6, 0.6, 0.6))
lib["add_object"]("Ground", lib["plane"]("Ground", 12.0, materials=[grey]))
statue = lib["add_object"]("Statue", lib["uv_sphere"]("Statue", 0.8, segments=32, rings=16,
                                                      materials=[lib["material"]("Stone", (0.7, 0.6, 0.5))]),
                           location=(0.0, 0.0, 0.8))
pillar = lib["add_object"]("Pillar", lib["box"]("Pillar", (0.5, 0.5, 3.0), base_at_origin=True, materials=[grey]),
                           location=(-2.0, 1.5, 0.0))
crate = lib["add_object"]("Crate", lib["box"]("Crate", (1.0, 1.0, 1.0), base_at_origin=True, materials=[grey]),
                          location=(2.0, -1.2, 0.0), rotation=(0.0, 0.0, 0.5))
lamp = lib["add_light"]("Lamp", "POINT", location=(0.8, -0.6, 4.5), energy=1500.0)
lib["add_sun"]("Sun", elevation=50, azimuth=200, energy=2.0)
lib["add_camera"](scene, (7.5, -8.0, 6.0), (0.0, 0.3, 0.5), lens=32)


def linking_collection(name, states):
    """A collection outside the scene listing ``states`` ({object: "INCLUDE" | "EXCLUDE"})."""
    coll = bpy.data.collections.new(name)
    for ob in states:
        coll.objects.link(ob)
    for ob, entry in zip(coll.objects, coll.collection_objects):
        entry.light_linking.link_state = states[ob]
    return coll


lamp.light_linking.receiver_collection = linking_collection("Lamp Receivers", {statue: "EXCLUDE"})
lamp.light_linking.blocker_collection = linking_collection("Lamp Blockers", {pillar: "INCLUDE", crate: "EXCLUDE"})
