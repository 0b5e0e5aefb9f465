"""Blender set-up shared by the tests: an environment whose Blender user files stay in a
temporary folder (``isolated_env``), and a ``blender`` command line run with the ``bpy`` module in
place of the binary (there is no ``blender`` here): ``python tests/helpers/blender_env.py
[blender arguments...]``.

Arguments are applied in order, as Blender does: the ``.blend`` file, ``-S/--scene``,
``-E/--engine``, ``--python-expr`` (``--python-exit-code``), ``-o/--render-output``,
``-F/--render-format``, ``-f/--render-frame A..B,C`` (each range an animation render, like
Blender's), ``-s``/``-e``/``-a``; ``-b``, ``-y`` and ``--factory-startup`` are accepted and
ignored. The add-on is registered from the source tree first (a worker has the extension
installed and enabled) and unregistered at the end; the last line on stdout is a JSON report of
the frames rendered and the engine's bakes by kind.

``python tests/helpers/blender_env.py --make-blend SCENE OUT.blend`` saves a scene argument (see
``blender/load.py``) as a ``.blend`` file.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
IGNORED = {"-b", "--background", "-y", "--enable-autoexec", "--factory-startup", "-noaudio"}

#: the built-in scenes at test sizes (pipeline tests run on every one)
TEST_SCENES = {
    "cube_on_plane": "cube_on_plane",
    "forest": "forest",
    "clusters": "clusters",
    "city": "city:blocks=4",
    "scaling": "scaling:triangles=20000,instances=200",
}


def checkout_env(env: dict | None = None) -> dict:
    """``env`` (this process's environment by default) with this checkout first on ``PYTHONPATH``:
    a subprocess imports the ``hybrid_shadow_addon`` under test, not another checkout's that the
    environment may have installed."""
    from benchmarks.trees import tree_env

    return tree_env(REPO, env)


def isolated_env(tmp: Path) -> dict:
    """This process's environment with Blender's user folders under ``tmp``, for a subprocess
    that runs ``bpy`` (this checkout first on its import path: :func:`checkout_env`)."""
    env = checkout_env()
    for var in ("BLENDER_USER_RESOURCES", "XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
        env[var] = str(tmp / var.lower())
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


class ArgvError(Exception):
    pass


def frame_ranges(text: str) -> list:
    out = []
    for part in text.split(","):
        a, _, b = part.strip().partition("..")
        out.append((int(a), int(b or a)))
    return out


def run(argv: list) -> dict:
    import bpy

    report = {"rendered": [], "python_errors": 0}
    exit_code_on_error = 0
    i = 0

    def value():
        nonlocal i
        if i + 1 >= len(argv):
            raise ArgvError(f"{argv[i]} needs a value")
        i += 1
        return argv[i]

    def animate(start, end):
        scene = bpy.context.scene
        saved = scene.frame_start, scene.frame_end
        scene.frame_start, scene.frame_end = start, end
        try:
            bpy.ops.render.render(animation=True)
        finally:
            scene.frame_start, scene.frame_end = saved
        report["rendered"] += list(range(start, end + 1, scene.frame_step))

    start = end = None
    while i < len(argv):
        a = argv[i]
        if a in IGNORED:
            pass
        elif a.endswith(".blend") and not a.startswith("-"):
            bpy.ops.wm.open_mainfile(filepath=str(Path(a).resolve()), load_ui=False)
        elif a in ("-S", "--scene"):
            name = value()
            if bpy.context.scene.name != name:
                win = bpy.context.window
                if win is None:
                    raise ArgvError(f"cannot switch to scene {name!r} without a window")
                win.scene = bpy.data.scenes[name]
        elif a in ("-E", "--engine"):
            bpy.context.scene.render.engine = value()
        elif a == "--python-exit-code":
            exit_code_on_error = int(value())
        elif a == "--python-expr":
            code = value()
            try:
                exec(compile(code, "<string>", "exec"), {"__name__": "__main__"})
            except Exception as exc:
                report["python_errors"] += 1
                print(f"Error: --python-expr: {type(exc).__name__}: {exc}", file=sys.stderr)
                if exit_code_on_error:
                    raise SystemExit(exit_code_on_error) from exc
        elif a in ("-o", "--render-output"):
            bpy.context.scene.render.filepath = value()
        elif a in ("-F", "--render-format"):
            bpy.context.scene.render.image_settings.file_format = value()
        elif a in ("-f", "--render-frame"):
            for s, e in frame_ranges(value()):
                animate(s, e)
        elif a in ("-s", "--frame-start"):
            start = int(value())
        elif a in ("-e", "--frame-end"):
            end = int(value())
        elif a in ("-a", "--render-anim"):
            scene = bpy.context.scene
            animate(scene.frame_start if start is None else start, scene.frame_end if end is None else end)
        else:
            raise ArgvError(f"unsupported blender argument {a!r}")
        i += 1
    return report


def bake_counts(frames: list) -> dict:
    """The final frames' bakes by kind, from their stats (``final_render.frame_handlers``)."""
    return {kind: sum(f.get("bake", "none") == kind for f in frames) for kind in ("full", "incremental", "none")}


def main(argv: list) -> int:
    import bpy  # noqa: F401

    if argv[:1] == ["--make-blend"]:
        from hybrid_shadow_addon.blender.load import open_scene

        open_scene(argv[1])
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(argv[2]).resolve()))
        return 0
    import hybrid_shadow_addon
    from hybrid_shadow_addon.blender import final_render

    hybrid_shadow_addon.register()
    frames = []
    final_render.frame_handlers.append(frames.append)
    try:
        report = run(argv)
        report["bakes"] = bake_counts(frames)
    finally:
        hybrid_shadow_addon.unregister()
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
