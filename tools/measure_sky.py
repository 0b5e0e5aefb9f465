"""Measure the Sky Texture's mean colour over the sphere with Cycles: the table that the world's
ambient colour reads (``hybrid_shadow_addon/blender/export/sky_mean.json``, :mod:`..world`).

For each sky type of the running Blender and each sun elevation of its table, Cycles (CPU) renders
a small equirectangular panorama of a world that holds only the Sky Texture (the node's default
settings, the sun disc off, Background strength 1); the mean is the panorama's solid-angle-weighted
mean (:func:`~hybrid_shadow_addon.blender.export.world.equirect_mean`). The sky's radiance is a
smooth function of the direction and a camera ray sees it directly, so 16 samples per pixel spread
over the pixel filter make a 64 x 32 panorama's mean agree with a 128 x 64 one's to 0.3 %. A
render takes about a second: all the types' tables, 1.5 to 2.5 minutes on two cores.

Usage (with the bpy venv whose Blender the table is for)::

    .venv/bin/python -m tools.measure_sky [--check | --write] [--types NISHITA,...] [--elevations 0,15,...]
        [--size 64x32] [--samples 16] [--tolerance 0.02]

Without ``--check`` or ``--write`` it prints the measured means and where they differ from the
table. ``--check`` exits 1 with one line per entry off by more than the tolerance: a channel
further from the table's value than ``--tolerance`` times the entry's brightest channel (at least
0.001, the noise of a night sky). ``--elevations`` between the table's check its interpolation.
``--write`` replaces the running Blender major version's entries of the types measured (at all
the stored table's elevations, or ``--elevations``) and the node settings they hold for.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

from hybrid_shadow_addon.blender.export.world import (
    SKY_TABLE_PATH,
    equirect_mean,
    set_sun_elevation,
    sky_mean,
    sky_settings,
)
from hybrid_shadow_addon.tools.exr import read_exr

REPO = Path(__file__).resolve().parents[1]

#: sun elevations (degrees) of a new table: denser near the horizon, where the sky changes fastest
DEFAULT_ELEVATIONS = (-10.0, -7.5, -5.0, -3.5, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0, 30.0,
                      45.0, 60.0, 75.0, 85.0, 90.0)
#: an entry is off where a channel differs by more than this share of the entry's brightest channel
TOLERANCE = 0.02
#: ... or by more than this (a night sky's mean is ~0 and its relative noise large)
ABS_TOLERANCE = 1e-3
ABOUT = ("Mean linear RGB over the sphere of Blender's Sky Texture, the sun disc left out, by Blender major "
         "version and sky type; each table holds for its node settings (the node's defaults) and was measured "
         "by tools/measure_sky.py from equirectangular Cycles renders. Rows: sun elevation in degrees, R, G, B.")


def sky_types() -> list:
    """The sky types the running Blender offers."""
    return [item.identifier for item in bpy.types.ShaderNodeTexSky.bl_rna.properties["sky_type"].enum_items]


def panorama(sc, size=(64, 32), samples=16) -> None:
    """An equirectangular camera at the origin of ``sc`` (rows: latitudes) and Cycles (CPU,
    ``samples``, no denoising) writing a 32-bit multilayer EXR: what :func:`render_mean` reads."""
    cam = bpy.data.objects.new("panorama", bpy.data.cameras.new("panorama"))
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.data.type = "PANO"
    cam.data.panorama_type = "EQUIRECTANGULAR"
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)  # looking at the horizon: the image's rows are latitudes
    r = sc.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = int(size[0]), int(size[1]), 100
    r.use_compositing = r.use_sequencer = False
    r.film_transparent = False
    im = r.image_settings
    if hasattr(im, "media_type"):  # Blender 5.0
        im.media_type = "MULTI_LAYER_IMAGE"
    else:
        im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    c = sc.cycles
    c.device = "CPU"
    c.samples = int(samples)
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.seed = 0


def sky_scene(size=(64, 32), samples=16):
    """A factory-empty scene: :func:`panorama` and a world whose Background (strength 1) shows a
    new Sky Texture, sun disc off. Returns (scene, the node)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    panorama(sc, size, samples)
    world = bpy.data.worlds.new("sky")
    if world.node_tree is None:  # Blender 4.x (5.x: always a node tree, use_nodes deprecated)
        world.use_nodes = True
    sc.world = world
    nodes = world.node_tree.nodes
    bg = next(n for n in nodes if n.type == "BACKGROUND")
    bg.inputs["Strength"].default_value = 1.0
    sky = nodes.new("ShaderNodeTexSky")
    sky.sun_disc = False
    world.node_tree.links.new(sky.outputs["Color"], bg.inputs["Color"])
    return sc, sky


@contextlib.contextmanager
def _silent_stdout():
    """Blender's own lines ('Saved: ...', 'Time: ...') kept off the standard output."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def render_mean(sc) -> np.ndarray:
    """The solid-angle-weighted mean linear RGB of the scene's equirectangular render."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "sky.exr")
        sc.render.filepath = path
        with _silent_stdout():
            bpy.ops.render.render(write_still=True, scene=sc.name)
        channels = read_exr(path)
    px = next(v for k, v in channels.items() if "Combined" in k or k in ("Image", "RGBA"))
    return equirect_mean(px[::-1])  # (the mean does not depend on the rows' order)


def measure(sky_type: str, elevations, size, samples, log=None) -> tuple:
    """(the node settings the table holds for, [(elevation, (r, g, b)), ...]) of one sky type."""
    sc, node = sky_scene(size, samples)
    node.sky_type = sky_type
    node.sun_disc = False
    rows = []
    for e in elevations:
        t = time.perf_counter()
        set_sun_elevation(node, math.radians(e))
        rgb = render_mean(sc)
        rows.append((float(e), tuple(float(f"{c:.5g}") for c in rgb)))
        if log:
            log(f"{sky_type:>20} {e:6.1f}°  {_fmt(rgb)}  {time.perf_counter() - t:.1f} s")
    return sky_settings(node), rows


def _fmt(rgb) -> str:
    return " ".join(f"{float(c):9.5f}" for c in rgb)


def off_entries(stored_rows, measured_rows, tolerance=TOLERANCE) -> list:
    """The entries whose measured mean differs from the table's by more than the tolerance (at an
    elevation between the table's: from the table interpolated as the export does): a line each."""
    table = np.array(stored_rows, np.float64)
    lo, hi = table[0, 0], table[-1, 0]
    lines = []
    for e, rgb in measured_rows:
        m = np.array(rgb, np.float64)
        if not lo <= e <= hi:
            lines.append(f"{e:g}°: outside the table's {lo:g}°..{hi:g}° (measured {_fmt(m)})")
            continue
        s = sky_mean(e, {"mean": stored_rows}).astype(np.float64)
        allowed = max(tolerance * float(s.max()), ABS_TOLERANCE)
        worst = float(np.abs(m - s).max())
        if worst > allowed:
            what = "table" if e in table[:, 0] else "table interpolated"
            lines.append(f"{e:g}°: {what} {_fmt(s)}, measured {_fmt(m)}: off by {worst:.4g} > {allowed:.4g}")
    return lines


def dump(doc: dict) -> str:
    """The table as JSON with each list of numbers on one line."""
    text = json.dumps(doc, indent=2, ensure_ascii=False)
    return re.sub(r"\[\s+([-+0-9.eE,\s]+?)\s+\]",
                  lambda m: "[" + ", ".join(x.strip(",") for x in m.group(1).split()) + "]", text) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="exit 1 where the table is off (one line each)")
    mode.add_argument("--write", action="store_true", help="rewrite this Blender's entries of the table")
    ap.add_argument("--types", help="comma-separated sky types (default: all the running Blender has)")
    ap.add_argument("--elevations", help="comma-separated sun elevations in degrees (default: the table's)")
    ap.add_argument("--size", default="64x32", help="panorama size WxH (default 64x32)")
    ap.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default 16)")
    ap.add_argument("--tolerance", type=float, default=TOLERANCE,
                    help=f"--check: allowed difference, a share of the entry's brightest channel (default "
                         f"{TOLERANCE}; at least {ABS_TOLERANCE})")
    ap.add_argument("--table", default=str(SKY_TABLE_PATH), help="the table file (default: the add-on's)")
    ap.add_argument("--quiet", action="store_true", help="print only what is off (--check) or nothing")
    args = ap.parse_args(argv)

    size = tuple(int(x) for x in args.size.lower().split("x"))
    have = sky_types()
    types = args.types.split(",") if args.types else have
    missing = [t for t in types if t not in have]
    if missing:
        ap.error(f"Blender {bpy.app.version_string} has no sky type {', '.join(missing)} (it has {', '.join(have)})")
    table_path = Path(args.table)
    doc = json.loads(table_path.read_text()) if table_path.exists() else {"about": ABOUT, "tables": {}}
    major = str(bpy.app.version[0])
    stored = doc["tables"].get(major, {})
    log = None if args.quiet else (lambda s: print(s, flush=True))

    failures, measured = [], {}
    for sky_type in types:
        entry = stored.get(sky_type)
        if args.elevations:
            elevations = [float(e) for e in args.elevations.split(",")]
        else:
            elevations = [float(row[0]) for row in entry["mean"]] if entry else list(DEFAULT_ELEVATIONS)
        settings, rows = measure(sky_type, elevations, size, args.samples, log)
        measured[sky_type] = (settings, rows)
        if args.check:
            if entry is None:
                failures.append(f"Blender {major} {sky_type}: no table")
                continue
            if entry.get("settings") != settings:
                failures.append(f"Blender {major} {sky_type}: the table holds for {entry.get('settings')}, "
                                f"a new node has {settings}")
            failures += [f"Blender {major} {sky_type} {line}" for line in off_entries(entry["mean"], rows,
                                                                                       args.tolerance)]
        elif not args.write and entry is not None and log:
            for line in off_entries(entry["mean"], rows, args.tolerance):
                log(f"  differs from the table at {line}")

    if args.write:
        tables = doc.setdefault("tables", {}).setdefault(major, {})
        for sky_type, (settings, rows) in measured.items():
            tables[sky_type] = {"blender": bpy.app.version_string, "size": list(size), "samples": args.samples,
                                "settings": settings, "mean": [[e, *rgb] for e, rgb in rows]}
        doc["about"] = ABOUT
        doc["tables"] = {k: doc["tables"][k] for k in sorted(doc["tables"], key=int)}
        table_path.write_text(dump(doc))
        if log:
            log(f"wrote Blender {major}'s {', '.join(measured)} to {table_path}")
    if args.check:
        for line in failures:
            print(line)
        if not failures and log:
            log(f"the table holds for Blender {bpy.app.version_string} ({', '.join(types)}) within "
                f"{args.tolerance:g}")
        return 1 if failures else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
