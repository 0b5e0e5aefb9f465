"""One frame to files: the image, one mask per shadowed light, the stats — all or nothing.

Every file is written next to its destination under a temporary name and renamed into place
only once the whole frame succeeded, so a failure never leaves half-written outputs behind.
"""
from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..core.errors import HybridShadowError, SceneError
from ..core.gpu.context import check_light_count
from ..core.image import to_srgb8, write_png

IMAGE_SUFFIXES = (".png", ".exr", ".npy")


def mask_filename(light_name: str) -> str:
    """``mask_<light object name>.npy``; path separators become ``_``."""
    return "mask_" + re.sub(r"[/\\\x00]", "_", light_name) + ".npy"


def write_exr(path: str, rgba: np.ndarray) -> None:
    """Linear float RGBA EXR (row 0 = top)."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"RGBA": np.ascontiguousarray(rgba, dtype=np.float32)}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


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
    }
    stats.update(frame.stats)
    return stats


def check_renderable(scene) -> None:
    """SceneError for a scene with nothing to render (no object with triangles or a sphere)."""
    inst = scene.instances
    if len(inst):
        tris = np.array([m.triangle_count for m in scene.models], np.int64)[inst.model_ids]
        if ((tris > 0) | inst.sphere).any():
            return
    raise SceneError(f"scene '{scene.name}' is empty: no visible mesh objects to render")


def render_to_files(scene, settings, *, resolution=None, output: str, masks_dir: str | None = None,
                    stats_path: str | None = None, pipeline=None) -> dict:
    """Render ``scene`` once and write the outputs; returns the stats dict."""
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
    pipe = pipeline or Pipeline()
    check_light_count(pipe.ctx, len(scene.lights))
    if not scene.lights:
        print(f"warning: scene '{scene.name}' has no lights: rendering the world colour (ambient) only",
              file=sys.stderr, flush=True)
    bake_ms = pipe.set_scene(scene) if settings.mode == "raytrace" else 0.0
    frame = pipe.render(scene, settings, width, height)
    stats = frame_stats(scene, frame, bake_ms)

    staged = []  # (tmp, dest)
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
        if stats_path:
            t = _staged(Path(stats_path))
            staged.append((t, Path(stats_path)))
            Path(t).write_text(json.dumps(stats, indent=2) + "\n")
        for t, dest in staged:
            os.replace(t, dest)
        staged.clear()
    finally:
        for t, _ in staged:
            try:
                os.unlink(t)
            except OSError:
                pass
    return stats
