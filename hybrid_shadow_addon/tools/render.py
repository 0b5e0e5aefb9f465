"""One frame to files: the image, one mask per shadowed light, the stats — all or nothing.

Every file is written next to its destination under a temporary name and renamed into place
only once the whole frame succeeded, so a failure never leaves half-written outputs behind.
"""
from __future__ import annotations

import glob
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.errors import HybridShadowError, SceneError
from ..core.image import to_srgb8, write_png
from .exr import write_exr

IMAGE_SUFFIXES = (".png", ".exr", ".npy")


def mask_filename(light_name: str) -> str:
    """``mask_<light object name>.npy``; path separators become ``_``."""
    return "mask_" + re.sub(r"[/\\\x00]", "_", light_name) + ".npy"


def write_image(path: str, rgba: np.ndarray) -> None:
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        write_png(path, to_srgb8(rgba))
    elif suffix == ".exr":
        write_exr(path, rgba)
    else:
        np.save(path, np.ascontiguousarray(rgba, np.float32), allow_pickle=False)


def _staged(dest: Path) -> str:
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=dest.suffix, dir=dest.parent)
    os.close(fd)
    return tmp


def frame_stats(scene, frame, bake_ms: float) -> dict:
    t = frame.timings
    stats = {
        "bake_ms": bake_ms,
        "gbuffer_ms": t["gbuffer_ms"],
        "shadow_ms": t["shadow_ms"],
        "upsample_ms": t["upsample_ms"],
        "lighting_ms": t["lighting_ms"],
        "readback_ms": t["readback_ms"],
        "total_ms": bake_ms + t["total_ms"],
        "triangles": scene.triangle_count,
        "instances": len(scene.instances),
        "lights": len(scene.lights),
        "shadowed_light_names": [scene.lights[i].name for i in frame.lights],
        "warnings": list(getattr(scene, "report", [])),
    }
    stats.update(frame.stats)
    return stats


def print_report(lines, seen: set | None = None, stream=None) -> None:
    """Print the export report's lines (those not in ``seen``, which then holds them) to
    ``stream`` (stderr): what the scene uses that is not rendered as Cycles does."""
    seen = set() if seen is None else seen
    new = [w for w in lines if w not in seen]
    seen.update(new)
    if not new:
        return
    out = stream or sys.stderr
    print(f"export report: {len(new)} approximation{'s' if len(new) != 1 else ''} or omission"
          f"{'s' if len(new) != 1 else ''}:", file=out)
    for w in new:
        print(f"  - {w}", file=out)
    out.flush()


def check_renderable(scene) -> None:
    """SceneError for a scene with nothing to render (no object with triangles or a sphere)."""
    inst = scene.instances
    if len(inst):
        tris = np.array([m.triangle_count for m in scene.models], np.int64)[inst.model_ids]
        if ((tris > 0) | inst.sphere).any():
            return
    raise SceneError(f"scene '{scene.name}' is empty: no visible mesh objects to render")


def write_outputs(out: Path, scene, frame, *, masks_dir=None, files=()) -> None:
    """Write ``frame``'s image to ``out``, its masks under ``masks_dir`` and ``files`` (``(path,
    text)`` pairs): staged next to each destination, renamed into place once all are written, the
    image last. The image is the frame's commit: a run killed before it leaves the frame to be
    rendered again, whatever of its other files were already in place."""
    staged = []  # (tmp, dest), the image first
    try:
        t = _staged(out)
        staged.append((t, out))
        write_image(t, frame.image)
        if masks_dir:
            Path(masks_dir).mkdir(parents=True, exist_ok=True)  # only once the frame exists
            for li in frame.lights:
                dest = Path(masks_dir) / mask_filename(scene.lights[li].name)
                t = _staged(dest)
                staged.append((t, dest))
                with open(t, "wb") as fh:
                    np.save(fh, frame.mask_array(li).astype(np.float32), allow_pickle=False)
        for dest, text in files:
            t = _staged(Path(dest))
            staged.append((t, Path(dest)))
            Path(t).write_text(text)
        for t, dest in staged[1:] + staged[:1]:  # the image last: the frame's commit
            os.replace(t, dest)
        staged.clear()
    finally:
        for t, _ in staged:
            try:
                os.unlink(t)
            except OSError:
                pass


def remove_stale_staged(dest: Path) -> None:
    """Remove files that a killed run left staged for ``dest`` (:func:`_staged`'s names)."""
    dest = Path(dest)
    if dest.parent.is_dir():
        for t in dest.parent.glob(f".{glob.escape(dest.name)}.*{glob.escape(dest.suffix)}"):
            try:
                t.unlink()
            except OSError:
                pass


def render_to_files(scene, settings, *, resolution=None, output: str, masks_dir: str | None = None,
                    stats_path: str | None = None, pipeline=None, progress=None, remote=None) -> dict:
    """Render ``scene`` once and write the outputs; returns the stats dict. ``progress(done,
    total, label)`` is called before each pass and shadowed light. ``remote``: a
    :class:`~..core.runtime.remote.FinalRenderer` renders it in its process (the command line's
    way: a renderer that dies or hangs is restarted and the frame rendered once more), else
    ``pipeline`` (or a new one) here."""
    from ..core.gpu.pipeline import Pipeline

    out = Path(output)
    if out.suffix.lower() not in IMAGE_SUFFIXES:
        raise HybridShadowError(f"output '{output}' must end in {', '.join(IMAGE_SUFFIXES)}")
    dests = [out] + ([Path(stats_path)] if stats_path else [])
    if masks_dir and not Path(masks_dir).resolve().parent.is_dir():
        raise HybridShadowError(f"folder '{Path(masks_dir).resolve().parent}' does not exist")
    for d in dests:
        if not d.parent.is_dir():
            raise HybridShadowError(f"folder '{d.parent}' does not exist")
    scene.validate()
    check_renderable(scene)
    width, height = resolution or scene.resolution
    if not scene.lights:
        print(f"warning: scene '{scene.name}' has no lights: rendering the world colour (ambient) only",
              file=sys.stderr, flush=True)
    if remote is not None:
        frame = remote.render(scene, settings, width, height, want=(), masks=bool(masks_dir), on_progress=progress)
        bake_ms = frame.stats.pop("bake_ms", 0.0)
    else:
        pipe = pipeline or Pipeline()
        bake_ms = pipe.set_scene(scene, settings.structure) if settings.mode == "raytrace" else 0.0
        frame = pipe.render(scene, settings, width, height, progress=progress)
    stats = frame_stats(scene, frame, bake_ms)
    if progress is not None:
        progress(1, 1, "written")

    write_outputs(out, scene, frame, masks_dir=masks_dir,
                  files=[(Path(stats_path), json.dumps(stats, indent=2) + "\n")] if stats_path else [])
    return stats


# ------------------------------------------------------------------------------------------------
# Frame ranges
# ------------------------------------------------------------------------------------------------
class FrameRangeError(HybridShadowError):
    """A ``--frames`` value that does not parse, or an empty or backwards range."""


_RANGE = re.compile(r"^\s*(-?\d+)\s*(?:(?:-|\.\.)\s*(-?\d+)\s*)?(?::\s*(\d+)\s*)?$")
#: more frames than this in one run is a typo, not an animation
MAX_FRAMES = 1_000_000


def parse_frames(text: str) -> list:
    """Frames of ``A-B[:STEP]`` (inclusive, ``A..B`` too), a single ``N``, or a comma-separated
    list of those, in the order given, each frame once."""
    text = str(text).strip()
    if not text:
        raise FrameRangeError("frame range is empty: give N, A-B or A-B:STEP (e.g. 1-24 or 1-100:5)")
    frames: list = []
    seen = set()
    for part in text.split(","):
        m = _RANGE.match(part)
        if not m:
            raise FrameRangeError(f"bad frame range '{part.strip()}' in '{text}': give N, A-B or A-B:STEP "
                                  "(e.g. 1-24 or 1-100:5)")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        step = int(m.group(3)) if m.group(3) is not None else 1
        if step < 1:
            raise FrameRangeError(f"frame range '{part.strip()}': the step must be at least 1")
        if b < a:
            raise FrameRangeError(f"frame range '{part.strip()}' ends before it starts ({b} < {a})")
        if (b - a) // step + 1 + len(frames) > MAX_FRAMES:
            raise FrameRangeError(f"frame range '{text}' has more than {MAX_FRAMES} frames")
        for f in range(a, b + 1, step):
            if f not in seen:
                seen.add(f)
                frames.append(f)
    return frames


def frame_path(pattern: str, frame: int) -> str:
    """Blender's rule: the last run of ``#`` in the file name becomes the zero-padded frame
    number (``name_####.png`` -> ``name_0007.png``); without ``#`` four digits go before the
    extension (``name.png`` -> ``name0007.png``)."""
    head, name = os.path.split(str(pattern))
    runs = list(re.finditer(r"#+", name))
    sign = "-" if frame < 0 else ""
    if runs:
        r = runs[-1]
        digits = f"{sign}{abs(frame):0{r.end() - r.start()}d}"
        return os.path.join(head, name[:r.start()] + digits + name[r.end():])
    stem, suffix = os.path.splitext(name)
    if suffix.lower() not in IMAGE_SUFFIXES:
        stem, suffix = name, ""
    return os.path.join(head, f"{stem}{sign}{abs(frame):04d}{suffix}")


def frame_masks_dir(masks_dir: str, frame: int) -> str:
    """``--masks-dir`` of one frame: its ``#`` replaced as in :func:`frame_path`, else a
    ``NNNN`` folder per frame under it."""
    if "#" in os.path.basename(os.path.normpath(masks_dir)):
        return frame_path(os.path.normpath(masks_dir), frame)
    return os.path.join(masks_dir, f"{'-' if frame < 0 else ''}{abs(frame):04d}")


def _read_stats(path: Path) -> dict:
    """Entries of an earlier run's ``--stats`` list by frame (for frames skipped now)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, list):
        return {}
    return {e["frame"]: e for e in data if isinstance(e, dict) and isinstance(e.get("frame"), int)}


def render_frames(source, frames, settings, *, output: str, resolution=None, masks_dir: str | None = None,
                  stats_path: str | None = None, overwrite: bool = False, progress=None, pipeline=None,
                  reuse: bool = False, remote=None) -> dict:
    """Render ``frames`` of ``source`` (``source.scene_at(frame) -> Scene``) to ``output`` (a
    ``#`` pattern, see :func:`frame_path`), baking once and updating the bake between frames
    (:func:`~..core.scene_sync.sync_scene`). Each frame's files appear all at once, its image last;
    frames whose image exists are skipped unless ``overwrite`` (a killed run leaves none half-made:
    what it staged is removed, a frame without its image is rendered again). ``stats_path``: a JSON list, one entry per
    frame (``frame``, ``bake``, the per-pass ms, ``rays_traced``, ``pixels_reused``, ``reuse``),
    rewritten after every frame. ``reuse``: hard lights' masks carry over between frames where
    the surface and the shadow rays stay the same (``core/gpu/passes/reproject.py``); soft
    lights take their own samples in every frame. ``remote``: a
    :class:`~..core.runtime.remote.FinalRenderer` renders the frames in its process, its bake kept
    and updated between them (as :func:`render_to_files`). Returns
    ``{"frames": [entries], "rendered": n, "skipped": n, "total_ms": ms}``."""
    from ..core.gpu.pipeline import Pipeline
    from ..core.scene_sync import sync_scene

    frames = list(frames)
    if not frames:
        raise FrameRangeError("no frames to render")
    if Path(output).suffix.lower() not in IMAGE_SUFFIXES:
        raise HybridShadowError(f"output '{output}' must end in {', '.join(IMAGE_SUFFIXES)}")
    stats_file = Path(stats_path) if stats_path else None
    if stats_file is not None and not stats_file.parent.is_dir():
        raise HybridShadowError(f"folder '{stats_file.parent}' does not exist")
    paths = {f: Path(frame_path(output, f)) for f in frames}
    for p in {p.parent for p in paths.values()}:
        p.mkdir(parents=True, exist_ok=True)  # as Blender does for its render output
    # a frame is done when its image is there: write_outputs puts it in place last
    todo = [f for f in frames if overwrite or not paths[f].exists()]
    for f in todo:
        remove_stale_staged(paths[f])
        if masks_dir and Path(frame_masks_dir(masks_dir, f)).is_dir():
            for t in Path(frame_masks_dir(masks_dir, f)).glob(".*.npy"):
                t.unlink(missing_ok=True)
    if stats_file is not None:
        remove_stale_staged(stats_file)
    earlier = _read_stats(stats_file) if stats_file is not None and stats_file.exists() else {}
    entries = {f: earlier.get(f, {"frame": f, "bake": "none", "output": str(paths[f])}) | {"skipped": True}
               for f in frames if f not in todo}
    own = remote is None and pipeline is None
    base = None if remote is not None else (pipeline or Pipeline())
    key = ("frames", id(source), time.time_ns())  # (the renderer's bake of this run, updated frame to frame)
    # the frames render through a view of the caller's pipeline (its bake, their own history and
    # reuse), which is left as it was
    pipe = None if base is None else base.view()
    if pipe is not None:
        pipe.reuse = bool(reuse)
        pipe.reuse_choice = "always"  # (every light, whatever it costs here: the same frames on any machine)
    raytrace = settings.mode == "raytrace"
    prev = None
    warned = False
    reported: set = set()
    t_start = time.perf_counter()
    skipped = len(frames) - len(todo)
    note = f", {skipped} already written" if skipped else ""
    try:
        for k, f in enumerate(todo):
            if progress is not None:
                progress(k, len(todo), f"frame {f}{note}")
            t0 = time.perf_counter()
            scene = source.scene_at(f)
            export_ms = (time.perf_counter() - t0) * 1e3
            print_report(scene.report, reported)
            scene.validate()
            check_renderable(scene)
            if not scene.lights and not warned:
                warned = True
                print(f"warning: scene '{scene.name}' has no lights: rendering the world colour (ambient) only",
                      file=sys.stderr, flush=True)
            width, height = resolution or scene.resolution
            if remote is not None:
                frame = remote.render(scene, settings, width, height, persistent_key=key, reuse=bool(reuse), want=(),
                                      masks=bool(masks_dir))
                kind, bake_ms = frame.stats.pop("bake"), frame.stats.pop("bake_ms", 0.0)
                updates = frame.stats.pop("bake_updates", {})
            else:
                sync = sync_scene(pipe, prev, scene, bake=raytrace, structure=settings.structure)
                prev = scene
                frame = pipe.render(scene, settings, width, height)
                kind, bake_ms = sync.kind, sync.ms
                updates = {"instances": len(sync.moved), "models": len(sync.models), "reason": sync.reason}
            entry = {"frame": f, "bake": kind, "output": str(paths[f]), "export_ms": export_ms}
            entry.update(frame_stats(scene, frame, bake_ms))
            entry["bake_updates"] = updates
            entry["reuse"] = {"hard": bool(reuse) and k > 0, "soft": "own samples"}
            entries[f] = entry
            listing = [entries[g] for g in frames if g in entries]
            files = [(stats_file, json.dumps(listing, indent=2) + "\n")] if stats_file is not None else []
            write_outputs(paths[f], scene, frame, masks_dir=frame_masks_dir(masks_dir, f) if masks_dir else None,
                          files=files)
    finally:
        if pipe is not None:
            pipe.release()
        if own:
            base.release()
    if progress is not None:
        progress(len(todo), max(len(todo), 1), f"{len(todo)} frames rendered{note}")
    if stats_file is not None and not todo:
        write_outputs_text(stats_file, json.dumps([entries[g] for g in frames], indent=2) + "\n")
    return {"frames": [entries[g] for g in frames], "rendered": len(todo), "skipped": skipped,
            "total_ms": (time.perf_counter() - t_start) * 1e3}


def write_outputs_text(dest: Path, text: str) -> None:
    """Write one text file all at once (staged, renamed into place)."""
    t = _staged(dest)
    try:
        Path(t).write_text(text)
        os.replace(t, dest)
    except BaseException:
        try:
            os.unlink(t)
        except OSError:
            pass
        raise
