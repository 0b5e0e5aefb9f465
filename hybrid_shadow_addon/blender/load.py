"""Load a scene into bpy from a scene script, a built-in test scene or a ``.blend`` file.

A scene argument is ``TARGET`` or ``TARGET:key=value,key=value``:

- ``TARGET`` ending in ``.py``: a scene script; ``.blend``: a Blender file; anything else: the
  name of a built-in scene, a script under ``test_scenes/`` (``forest``, ``stiff/grazing``).
- The parameters reach a script as the dict global ``PARAMS``; values that look like numbers
  become ``int`` or ``float``.

The script contract: it runs (``runpy.run_path``) right after
``bpy.ops.wm.read_factory_settings(use_empty=True)``, builds the scene with bpy and sets
``scene.camera`` and the render resolution.

Every failure is a :class:`SceneLoadError` (or :class:`SceneError` for a scene without a camera)
with a one-line message.
"""
from __future__ import annotations

import re
import runpy
from pathlib import Path

import bpy

from ..core.errors import SceneError, SceneLoadError
from ..core.scene import Scene
from .render_eval import render_scene

#: The built-in scene scripts (the repository's ``test_scenes/``, sibling of the package).
SCENES_DIR = Path(__file__).resolve().parents[2] / "test_scenes"

_PARAMS = re.compile(r"^\w+=[^,=]*(,\w+=[^,=]*)*$")
_INT = re.compile(r"^[+-]?\d+$")


def builtin_scenes() -> list[str]:
    """Names of the built-in scenes: ``test_scenes/**/*.py`` without the suffix, except files
    starting with ``_`` (shared helpers)."""
    if not SCENES_DIR.is_dir():
        return []
    return sorted(p.relative_to(SCENES_DIR).with_suffix("").as_posix()
                  for p in SCENES_DIR.rglob("*.py")
                  if not any(part.startswith("_") for part in p.relative_to(SCENES_DIR).parts))


def _value(text: str):
    if _INT.match(text):
        return int(text)
    try:
        return float(text)
    except ValueError:
        return text


def parse_scene_arg(arg: str) -> tuple[str, dict]:
    """Split ``TARGET:key=value,...`` into the target and the parameter dict."""
    target, sep, tail = arg.rpartition(":")
    if sep and _PARAMS.match(tail):
        params = dict(item.split("=", 1) for item in tail.split(","))
        return target, {k: _value(v) for k, v in params.items()}
    return arg, {}


def resolve_scene(target: str) -> Path:
    """The file a scene target names: a ``.py``/``.blend`` path or a built-in scene script."""
    if target.endswith((".py", ".blend")):
        path = Path(target).expanduser()
        if not path.is_file():
            raise SceneLoadError(f"scene file not found: {target}")
        return path
    names = builtin_scenes()
    if target in names:
        return SCENES_DIR / f"{target}.py"
    names = ", ".join(names) or "none"
    raise SceneLoadError(f"unknown scene '{target}': give a .py or .blend file or one of the "
                         f"built-in scenes ({names})")


def _one_line(text: str) -> str:
    lines = [line.strip() for line in str(text).strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


def open_scene(arg: str, frame: int | None = None):
    """Load a scene argument into bpy and return the ``bpy.types.Scene``, left loaded (at
    ``frame`` when given) for renderers that need bpy."""
    target, params = parse_scene_arg(arg)
    path = resolve_scene(target)
    if path.suffix == ".blend":
        if params:
            raise SceneLoadError(f"parameters ({', '.join(params)}) apply to scene scripts, not to {path.name}")
        try:
            bpy.ops.wm.open_mainfile(filepath=str(path.resolve()), load_ui=False)
        except RuntimeError as exc:
            reason = _one_line(exc).removeprefix("Error: ")
            raise SceneLoadError(f"cannot open {path}: {reason}") from None
    else:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        try:
            runpy.run_path(str(path), init_globals={"PARAMS": params})
        except (Exception, SystemExit) as exc:
            detail = _one_line(exc)
            message = f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__
            raise SceneLoadError(f"scene script {path.name} failed: {message}") from None
    scene = bpy.context.scene
    if scene.camera is None:
        raise SceneError(f"scene '{scene.name}' ({target}) has no camera: set scene.camera")
    if frame is not None:
        scene.frame_set(int(frame))
    return scene


def load_scene(arg: str, *, frame: int | None = None) -> Scene:
    """Load a scene argument and export it (evaluated at ``frame`` when given, as a final render
    evaluates it: :func:`.render_eval.render_scene`) to a validated core :class:`Scene`."""
    return render_scene(open_scene(arg, frame))
