"""Build the Blender extension: ``dist/hybrid_shadows-<version>-<platform>.zip``, one per platform.

The zip holds ``blender_manifest.toml`` and a root ``__init__.py`` beside ``hybrid_shadow_addon/``
and ``shaders/`` (the repo's relative layout, so shaders are found the same way as in the repo),
plus the moderngl and glcontext wheels of each platform and Python version (cp311 for Blender
4.2-5.0, cp313 for 5.1 and later), fetched with pip (cached in
``build/wheels``). Tests, test scenes and the numpy oracles (``core/oracle``) stay out. Each zip is validated with the
``blender_ext.py`` that ships inside bpy.

Usage: ``.venv/bin/python -m tools.build_extension [--platform linux-x64 ...] [--offline]``
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "build"
DIST = REPO / "dist"

# Blender platform -> pip --platform tags. Versions come from requirements.txt; macos-x64 has no
# wheels of the newest releases, so it takes the last ones that were built for it.
PLATFORMS = {
    "linux-x64": (("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
                   "manylinux_2_5_x86_64", "manylinux1_x86_64"), {}),
    "windows-x64": (("win_amd64",), {}),
    "macos-arm64": (("macosx_11_0_arm64",), {}),
    "macos-x64": (("macosx_10_9_x86_64", "macosx_10_13_x86_64"), {"moderngl": "5.12.0", "glcontext": "3.0.0"}),
}
WHEEL_PACKAGES = ("moderngl", "glcontext")
#: Python versions of the Blender releases the extension supports: 4.2 LTS - 5.0 (3.11), 5.1+ (3.13)
PYTHON_VERSIONS = ("3.11", "3.13")
ROOT_INIT = '''"""Hybrid Shadows extension entry point."""
from .hybrid_shadow_addon import register, unregister  # noqa: F401
'''


def pinned_versions() -> dict:
    pins = {}
    for line in (REPO / "requirements.txt").read_text().splitlines():
        m = re.match(r"^\s*([A-Za-z0-9_.-]+)==([^\s#]+)", line)
        if m:
            pins[m.group(1).lower()] = m.group(2)
    return {p: pins[p] for p in WHEEL_PACKAGES}


def blender_ext_cli() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    found = sorted(p for base in (spec.submodule_search_locations if spec else [])
                   for p in Path(base).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        sys.exit("build_extension: blender_ext.py not found inside bpy")
    return found[-1]


def fetch_wheels(platform: str, offline: bool) -> list:
    """The moderngl and glcontext wheels of ``platform`` for every Python version Blender ships
    (:data:`PYTHON_VERSIONS`); Blender installs the ones that match its own Python."""
    tags, overrides = PLATFORMS[platform]
    versions = {**pinned_versions(), **overrides}
    dest = BUILD / "wheels" / platform
    dest.mkdir(parents=True, exist_ok=True)
    wheels = []
    for py in PYTHON_VERSIONS:
        cp = "cp" + py.replace(".", "")
        for pkg, ver in versions.items():
            have = sorted(dest.glob(f"{pkg}-{ver}-{cp}-*.whl"))
            if not have:
                if offline:
                    sys.exit(f"build_extension: {pkg}=={ver} ({cp}) for {platform} is not in {dest} "
                             "(run without --offline)")
                subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check",
                                "--no-deps", "--only-binary=:all:", "--python-version", py,
                                "--implementation", "cp", *[a for t in tags for a in ("--platform", t)],
                                "-d", str(dest), f"{pkg}=={ver}"],
                               check=True, stderr=subprocess.DEVNULL)
                have = sorted(dest.glob(f"{pkg}-{ver}-{cp}-*.whl"))
            wheels.append(have[0])
    return wheels


def manifest_with_wheels(names: list, platforms: list) -> str:
    text = (REPO / "blender_manifest.toml").read_text()
    text = re.sub(r"(?ms)^platforms\s*=\s*\[.*?\]\n", "", text)
    text = re.sub(r"(?ms)^wheels\s*=\s*\[.*?\]\n", "", text)
    listed = ",\n".join(f'  "./wheels/{n}"' for n in names)
    plats = ", ".join(f'"{p}"' for p in platforms)
    keys = f"platforms = [{plats}]\nwheels = [\n{listed},\n]\n\n"
    first_table = re.search(r"(?m)^\[", text)  # top-level keys go before the first [table]
    at = first_table.start() if first_table else len(text)
    return text[:at] + keys + text[at:]


def stage(platforms: list, offline: bool) -> Path:
    src = BUILD / "extension"
    shutil.rmtree(src, ignore_errors=True)
    src.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    oracle = REPO / "hybrid_shadow_addon" / "core" / "oracle"

    def ignore_package(folder, names):
        return set(ignore(folder, names)) | ({"oracle"} if Path(folder) == oracle.parent else set())

    shutil.copytree(REPO / "hybrid_shadow_addon", src / "hybrid_shadow_addon", ignore=ignore_package)
    shutil.copytree(REPO / "shaders", src / "shaders", ignore=ignore)
    shutil.copy2(REPO / "README.md", src / "README.md")
    (src / "__init__.py").write_text(ROOT_INIT)
    (src / "wheels").mkdir()
    names = []
    for p in platforms:
        for whl in fetch_wheels(p, offline):
            shutil.copy2(whl, src / "wheels" / whl.name)
            names.append(whl.name)
    (src / "blender_manifest.toml").write_text(manifest_with_wheels(sorted(set(names)), platforms))
    return src


def ext_id_version(src: Path) -> str:
    """``<id>-<version>`` from the staged manifest (the zip name's stem before the platform)."""
    text = (src / "blender_manifest.toml").read_text()
    ident = re.search(r'(?m)^id\s*=\s*"([^"]+)"', text).group(1)
    version = re.search(r'(?m)^version\s*=\s*"([^"]+)"', text).group(1)
    return f"{ident}-{version}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--platform", action="append", choices=sorted(PLATFORMS),
                    help="platform(s) to build (default: all four)")
    ap.add_argument("--offline", action="store_true", help="use only wheels already in build/wheels")
    args = ap.parse_args(argv)
    platforms = args.platform or list(PLATFORMS)
    cli = blender_ext_cli()
    src = stage(platforms, args.offline)
    DIST.mkdir(exist_ok=True)
    subprocess.run([sys.executable, str(cli), "validate", str(src)], check=True)
    # always split: one platform then still gets its "-<platform>" suffix (without the flag the
    # zip would be named hybrid_shadows-<version>.zip)
    cmd = [sys.executable, str(cli), "build", "--source-dir", str(src), "--output-dir", str(DIST),
           "--split-platforms"]
    subprocess.run(cmd, check=True)
    built = [DIST / f"{ext_id_version(src)}-{p.replace('-', '_')}.zip" for p in platforms]
    for z in built:
        subprocess.run([sys.executable, str(cli), "validate", str(z)], check=True, stdout=subprocess.DEVNULL)
        print(f"built {z.relative_to(REPO)} ({z.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
