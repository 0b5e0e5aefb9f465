"""Command line: ``python -m hybrid_shadow_addon <command> ...``.

Commands are thin wrappers over the core and the Blender loader. Errors meant for the user
(:class:`~hybrid_shadow_addon.core.errors.HybridShadowError`) print one line on stderr and exit
with code 2; nothing prints a traceback unless ``HYBRID_SHADOWS_DEBUG=1``.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

from .core.errors import HybridShadowError

EXIT_USER_ERROR = 2


@contextlib.contextmanager
def blender_output_to_stderr():
    """Send whatever Blender prints on stdout (C level too) to stderr meanwhile, so our own
    stdout stays clean (``--json`` output must parse)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def load(scene_arg: str, frame: int | None = None):
    """Load SCENE (script path, built-in name, or .blend) into the bpy-free scene model."""
    from .blender.load import load_scene

    with blender_output_to_stderr():
        return load_scene(scene_arg, frame=frame)


# ---------------------------------------------------------------------------------------------
def cmd_info(args) -> int:
    scene = load(args.scene, args.frame)
    s = scene.summary()
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    lights = ", ".join(f"{n} {t.lower()}" for t, n in s["lights"].items() if n) or "none"
    print(f"scene       {s['scene']} (frame {s['frame']}, {s['resolution'][0]}x{s['resolution'][1]})")
    print(f"instances   {s['instances']} ({s['shadow_casters']} cast shadows, {s['sphere_primitives']} sphere primitives)")
    print(f"models      {s['models']}")
    print(f"triangles   {s['triangles']} placed, {s['unique_triangles']} unique")
    print(f"lights      {lights} ({s['shadowed_lights']} cast shadows)")
    cam = s["camera"]
    print(f"camera      {'none' if cam is None else cam['name'] + ' (' + cam['type'].lower() + ')'}")
    b = s["world_bounds"]
    if b is None:
        print("bounds      empty")
    else:
        fmt = lambda v: "(" + ", ".join(f"{x:.3f}" for x in v) + ")"  # noqa: E731
        print(f"bounds      {fmt(b['min'])} .. {fmt(b['max'])}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m hybrid_shadow_addon",
        description="Hybrid ray-traced shadows: inspect, render, compare with Cycles, benchmark.",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    scene_help = ("a scene script (.py), a built-in scene name (e.g. forest, or "
                  "'scaling:triangles=100000,instances=1000'), or a .blend file")

    pi = sub.add_parser("info", help="print what a scene holds", description="Print instances, models, "
                        "triangles, lights by type and world bounds of a scene.")
    pi.add_argument("scene", metavar="SCENE", help=scene_help)
    pi.add_argument("--json", action="store_true", help="machine-readable output")
    pi.add_argument("--frame", type=int, default=None, help="frame to evaluate (default: the scene's current)")
    pi.set_defaults(func=cmd_info)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except HybridShadowError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a bug: still one line, unless debugging
        if os.environ.get("HYBRID_SHADOWS_DEBUG"):
            raise
        print(f"internal error: {type(e).__name__}: {e} (set HYBRID_SHADOWS_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # bpy can take seconds tearing down at exit; our work is done and flushed.
    os._exit(code)
