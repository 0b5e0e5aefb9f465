"""Render the demo scene through the installed Blender extension with ``bpy.ops.render.render``.

Builds ``dist/hybrid_shadows-<version>-linux-x64.zip`` (or the platform given), installs it
into a temporary Blender user folder (BLENDER_USER_RESOURCES, XDG_CONFIG_HOME, XDG_CACHE_HOME:
nothing touches $HOME), loads the forest scene, renders it with the Hybrid Shadows engine and
saves a PNG. The bpy work runs in a child process so those variables are set before bpy starts.

Usage: ``.venv/bin/python -m tools.demo_blender [--scene forest:...] [--mode raytrace] [--output out/demo_blender.png]
[--log FILE]`` (``--log``: the extension build's and Blender's own output go to FILE, appended).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PLATFORM = {"linux": "linux-x64", "win32": "windows-x64"}.get(sys.platform, "macos-arm64")
EXT_MODULE = "bl_ext.user_default.hybrid_shadows"


def child(zip_path: str, scene_arg: str, mode: str, output: str) -> None:
    import bpy

    from hybrid_shadow_addon.blender.load import open_scene

    scene = open_scene(scene_arg)  # factory settings first: they reset the preferences
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    try:
        scene.render.engine = "HYBRID_SHADOWS"
        scene.hybrid_shadows.mode = mode.upper()
        scene.render.filepath = output
        scene.render.image_settings.file_format = "PNG"
        bpy.ops.render.render(write_still=True)
    finally:
        bpy.ops.preferences.addon_disable(module=EXT_MODULE)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="forest:trees=120,spheres=30,width=640,height=360")
    ap.add_argument("--mode", choices=("raytrace", "shadowmap", "none"), default="raytrace")
    ap.add_argument("--output", default=str(REPO / "out" / "demo_blender.png"))
    ap.add_argument("--platform", default=PLATFORM)
    ap.add_argument("--log", default=None, metavar="FILE", help="append the build's and Blender's output here")
    args = ap.parse_args(argv)
    out = Path(args.output).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    log = open(args.log, "a") if args.log else None
    sink = {"stdout": log, "stderr": subprocess.STDOUT} if log else {}
    print(f"demo_blender: building the extension and rendering {args.scene} through it"
          + (f" (Blender's output: {args.log})" if log else ""), flush=True)
    subprocess.run([sys.executable, "-m", "tools.build_extension", "--platform", args.platform],
                   check=True, cwd=REPO, **sink)
    version = next(line.split('"')[1] for line in (REPO / "blender_manifest.toml").read_text().splitlines()
                   if line.startswith("version"))
    zip_path = REPO / "dist" / f"hybrid_shadows-{version}-{args.platform.replace('-', '_')}.zip"
    with tempfile.TemporaryDirectory(prefix="hs-demo-blender-") as tmp:
        env = dict(os.environ)
        for var in ("BLENDER_USER_RESOURCES", "XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
            env[var] = str(Path(tmp) / var.lower())
        proc = subprocess.run([sys.executable, "-m", "tools.demo_blender", "--child", str(zip_path), args.scene,
                               args.mode, str(out)], env=env, cwd=REPO, **sink)
    if log:
        log.close()
    if proc.returncode != 0 or not out.is_file():
        print(f"demo_blender: the render failed (see {args.log or 'above'})", file=sys.stderr)
        return 1
    print(f"rendered {args.scene} with the installed Hybrid Shadows engine ({args.mode}) -> {out}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(*sys.argv[2:6])
        sys.exit(0)
    sys.exit(main())
