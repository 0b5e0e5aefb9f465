"""Compare shadow variants with a per-light visibility reference: error against run time.

For one core scene:

1. The reference of each shadow-casting light, from a :class:`~.reference.ReferenceProvider`,
   cached on disk (:mod:`.reference`).
2. One shared :class:`Pipeline`: bake once, then per variant (:mod:`.variants`) ``warmup``
   untimed frames (shader compilation) and ``repeats`` timed ones; the medians of shadow ms and
   total ms. The masks of the last frame are compared with the reference (:mod:`.metrics`).
   ``raytrace-interlaced`` is timed in its steady state and its error measured on the first
   frame after a change (:meth:`Pipeline.reset_history`).
3. ``metrics.json``, ``images/*.png`` (reference, our mask and the false-colour difference per
   variant and light), ``error_vs_time.png`` and ``report.html`` (:mod:`.report`).

Two modes. *Hard* (the default): the reference's lights are made hard (a provider with
``hard=True``) and so are the variants' (:mod:`.variants`); the error that counts is the
mismatch (|Δ| > 0.5, lit against shadowed). *Soft* (``soft=True``, ``compare --soft``): the
reference keeps the lights' sizes (a provider with ``hard=False``; many samples at the pixel
centre, :data:`SOFT_REFERENCE_SAMPLES` by default), the variants render with ``hard=False`` and
``shadow_samples`` rays per pixel (default: :class:`Settings`'), and shadow maps with their
soft filter, which ``hard=False`` switches on (percentage-closer soft shadows,
``Settings.pcss_samples`` taps; :func:`soft_shadowmap_filter`); the errors
that count are the mean absolute error and the share of valid pixels off by more than 0.1
(``off_pct``). The soft reference is cached apart from the hard one.

:func:`compare_steps` is a generator of steps so the Blender operator can run it from a modal
timer and cancel between steps; :func:`run_compare` drives it with a progress callback.
"""
from __future__ import annotations

import contextlib
import re
from dataclasses import fields, replace
from pathlib import Path

import numpy as np

from ..core.errors import HybridShadowError
from ..core.image import write_png
from ..core.progress import call
from ..core.settings import Settings
from . import metrics
from .reference import default_cache_dir, load_cached, reference_key, save_cached
from .report import write_report
from .variants import Variant, as_variants

INTERLACE_EXTRA = 4  # extra untimed frames of an interlaced variant: its history fills up
HARD_REFERENCE_SAMPLES = 1  # Cycles samples per pixel of a hard reference (one ray to a point light)
SOFT_REFERENCE_SAMPLES = 256  # ... of a soft one (the light's area sampled at the pixel centre)


def safe_name(text: str) -> str:
    return re.sub(r"[^\w.-]+", "_", text).strip("_") or "light"


def soft_shadowmap_filter(variants) -> str | None:
    """What the shadow-map variants of a soft comparison filter with: ``"pcss"`` (with ``hard``
    False a light with a size gets percentage-closer soft shadows, ``Settings.pcss_samples``
    taps) where :class:`Settings` has that field, None without one (hard shadow maps) or without
    shadow-map variants."""
    if not any(v.settings.mode == "shadowmap" for v in variants):
        return None
    return "pcss" if "pcss_samples" in {f.name for f in fields(Settings)} else None


def soft_variants(variants, shadow_samples: int | None = None) -> list:
    """The variants for a soft comparison: lights with their sizes (``hard=False``: ray tracing
    samples them, shadow maps take their soft filter), ``shadow_samples`` rays per pixel (None:
    as the variant has them, i.e. Settings' default)."""
    out = []
    for v in as_variants(variants):
        changes = {"hard": False}
        if shadow_samples is not None:
            changes["samples"] = int(shadow_samples)
        try:
            out.append(Variant(v.name, v.label, v.settings.replace(**changes)))
        except ValueError as e:
            raise HybridShadowError(f"--shadow-samples: {e}") from None
    return out


def compare_steps(scene, output_dir, *, reference, resolution=None, variants=None, repeats: int = 5,
                  warmup: int = 2, samples: int | None = None, cache_dir=None, use_cache: bool = True,
                  pipeline=None, gl_scope=None, scene_label: str | None = None, result: dict | None = None,
                  soft: bool | None = None, shadow_samples: int | None = None, remote=None):
    """Generator doing the comparison of the core ``scene`` with ``reference`` (a
    :class:`~.reference.ReferenceProvider`) step by step; yields ``(done, total, label)`` after
    each step. ``resolution`` overrides the scene's; ``gl_scope()``: a context manager around
    every use of ``pipeline``; ``remote``: a :class:`~..core.runtime.remote.FinalRenderer` whose
    process renders the variants instead (the caller's threads then make no GL call, and a step
    waits at most about 20 ms). The final metrics dict is stored in ``result["metrics"]`` (pass a
    dict).

    ``soft`` (None: as the provider's ``hard`` says, hard without one): the soft comparison
    (see the module's docstring); ``samples``: the reference's samples per pixel (None:
    :data:`HARD_REFERENCE_SAMPLES` or :data:`SOFT_REFERENCE_SAMPLES`); ``shadow_samples``: the
    variants' rays per pixel in soft mode."""
    if repeats < 1 or warmup < 0:
        raise HybridShadowError("--repeats must be at least 1 and --warmup at least 0")
    provider_hard = getattr(reference, "hard", None)
    if soft is None:
        soft = provider_hard is False
    elif provider_hard is not None and bool(provider_hard) == bool(soft):
        raise HybridShadowError(f"a {'soft' if soft else 'hard'} comparison needs a reference with "
                                f"hard={not soft}, not hard={provider_hard}")
    if samples is None:
        samples = SOFT_REFERENCE_SAMPLES if soft else HARD_REFERENCE_SAMPLES
    if samples < 1:
        raise HybridShadowError("--samples must be at least 1")
    if shadow_samples is not None and not soft:
        raise HybridShadowError("--shadow-samples is for soft comparisons (--soft): hard lights take one ray")
    result = {} if result is None else result
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "images").mkdir(exist_ok=True)
    variants = soft_variants(variants, shadow_samples) if soft else as_variants(variants)
    error_key = "mae" if soft else "mismatch_pct"  # what the Pareto front weighs

    if resolution is not None:
        scene = replace(scene, resolution=(int(resolution[0]), int(resolution[1])))
    scene.validate()
    width, height = scene.resolution
    names = list(reference.light_names(scene))
    if not names:
        raise HybridShadowError(f"scene '{scene.name}' has no shadow-casting light to compare")
    per_variant = warmup + repeats + 1
    total = len(names) + sum(per_variant + (INTERLACE_EXTRA if v.settings.interlace else 0) for v in variants) + 2
    done = 0

    # -- 1. the reference, per light, cached --------------------------------------------------------
    key = reference_key(scene, (width, height), samples, names, reference, soft=soft)
    cache_path = Path(cache_dir or default_cache_dir(reference)) / f"{key}.npz"
    cached = load_cached(cache_path) if use_cache else None
    if cached is not None and set(cached[0]) == set(names):
        visibility, ref_ms = cached
        done += len(names)
        yield done, total, f"{reference.name} {'soft ' if soft else ''}reference (cached)"
        from_cache = True
    else:
        visibility, ref_ms = {}, {}
        for name in names:
            visibility[name], ref_ms[name] = reference.visibility(scene, name, (width, height), samples)
            done += 1
            yield done, total, f"{reference.name} {'soft ' if soft else ''}reference: {name}"
        if use_cache:
            save_cached(cache_path, visibility, ref_ms)
        from_cache = False

    # -- 2. every variant on one pipeline ----------------------------------------------------------
    light_index = {light.name: i for i, light in enumerate(scene.lights)}
    job = dict(scene=scene, variants=variants, names=names, light_index=light_index, size=(width, height),
               warmup=warmup, repeats=repeats)
    if remote is not None:  # in a renderer process: no GL on the caller's threads
        steps = remote.call_steps(measure_variants, job)
    else:
        steps = measure_variants(**job, pipeline=pipeline, gl_scope=gl_scope)
    while True:
        try:
            label = next(steps)
        except StopIteration as stop:
            measured = stop.value
            break
        if label is not None:
            done += 1
        yield min(done, total - 1), total, label or "rendering"
    rows = [_variant_row(v, shadow, tot, names, visibility, ours, out)
            for v, (shadow, tot, ours) in zip(variants, measured["runs"])]
    bake_ms, grids_ms = measured["bake_ms"], measured["grids_ms"]

    # -- 3. outputs ---------------------------------------------------------------------------------
    ref_images = {}
    for n in names:
        p = f"images/reference_{safe_name(n)}.png"
        _png(out / p, metrics.visibility_image(visibility[n]))
        ref_images[n] = p
    front = metrics.pareto_front([(r["total_ms"], r["overall"][error_key]) for r in rows])
    for i, r in enumerate(rows):
        r["pareto"] = i in front
    m = {
        "scene": scene_label or scene.name,
        "frame": int(scene.frame),
        "resolution": [int(width), int(height)],
        "bpy_version": reference.version,
        "lights": names,
        "warnings": list(getattr(scene, "report", [])),
        "soft": bool(soft),
        "error_metric": error_key,
        "threshold": metrics.MISMATCH_THRESHOLD,
        "off_threshold": metrics.OFF_THRESHOLD,
        # soft mode: the shadow maps' soft filter ("pcss"; None: hard shadow maps, or none run)
        "soft_shadowmap_filter": soft_shadowmap_filter(variants) if soft else None,
        "repeats": int(repeats),
        "warmup": int(warmup),
        "bake_ms": float(bake_ms),
        "light_grid_build_ms": float(grids_ms),  # (once: the hard lights' grids, in the warm-up)
        "triangles": int(scene.triangle_count),
        "instances": len(scene.instances),
        "reference": {
            "samples": int(samples), "hard": not soft, "cached": from_cache,
            "cache_file": str(cache_path) if use_cache else None,
            "render_ms": {n: float(t) for n, t in ref_ms.items()},
            "total_ms": float(sum(ref_ms.values())),
            "images": ref_images,
            "valid_pixels": {n: int(np.isfinite(visibility[n]).sum()) for n in names},
        },
        "variants": rows,
        "pareto": [rows[i]["name"] for i in front],
        "files": {"metrics": "metrics.json", "plot": "error_vs_time.png", "report": "report.html"},
    }
    write_report(m, out)
    done += 1
    result["metrics"] = m
    yield done, total, "report written"


def measure_variants(scene, variants, names, light_index, size, warmup, repeats, pipeline=None, gl_scope=None):
    """Generator: bake once, then each variant's warm-up and timed frames on one pipeline
    (``pipeline``, or its own), yielding a label after each step; returns ``{"runs": [(shadow
    ms list, total ms list, {light name: mask})] per variant, "bake_ms", "grids_ms"}``."""
    width, height = size
    gl = gl_scope or contextlib.nullcontext
    own_pipeline = pipeline is None
    if own_pipeline:
        from ..core.gpu.pipeline import Pipeline

        pipeline = Pipeline()
    runs = []
    # the hard lights' grids from the first frame on (a warm-up frame builds them): the timed
    # frames are the steady state a viewport or an animation reaches, the build is reported apart
    with gl():
        rt = pipeline.shadow_pass("raytrace")
    grids, kept = rt.light_grids, rt.options
    rt.options = replace(kept, eager_light_grids=True)
    built0 = grids.total_build_ms
    try:
        with gl():
            bake_ms = pipeline.set_scene(scene)
        yield f"bake {bake_ms:.0f} ms"
        for v in variants:
            s = v.settings
            shadow, tot = [], []
            with gl():
                pipeline.reset_history()
            n_warm = warmup + (INTERLACE_EXTRA if s.interlace else 0)
            for k in range(n_warm + repeats):
                with gl():
                    frame = pipeline.render(scene, s, width, height)
                if k >= n_warm:
                    shadow.append(frame.timings["shadow_ms"])
                    tot.append(frame.timings["total_ms"])
                yield f"{v.name}: frame {k + 1}/{n_warm + repeats}"
            with gl():
                if s.interlace:  # the error of the first frame after a change
                    pipeline.reset_history()
                    frame = pipeline.render(scene, s, width, height)
                ours = {n: _mask(frame, light_index[n]) for n in names}
            runs.append((shadow, tot, ours))
            yield f"{v.name}: error"
    finally:
        rt.options = kept
        grids_ms = grids.total_build_ms - built0
        if own_pipeline:
            with gl():
                pipeline.release()
    return {"runs": runs, "bake_ms": bake_ms, "grids_ms": grids_ms}


def run_compare(scene, output_dir, *, reference, progress=None, **kwargs) -> dict:
    """Run :func:`compare_steps` to the end; ``progress(done, total, label)`` after each step
    (it may raise to cancel). Returns the metrics dict (also in ``metrics.json``)."""
    result = {}
    for done, total, label in compare_steps(scene, output_dir, reference=reference, result=result, **kwargs):
        call(progress, done, total, label)
    return result["metrics"]


def _variant_row(v, shadow, tot, names, visibility, ours, out: Path) -> dict:
    """One variant's entry of ``metrics.json``; writes its mask and difference images."""
    per_light, images = {}, {}
    for n in names:
        per_light[n] = metrics.mask_error(visibility[n], ours[n])
        stem = f"{v.name}_{safe_name(n)}"
        _png(out / "images" / f"{stem}_mask.png", metrics.visibility_image(ours[n]))
        _png(out / "images" / f"{stem}_diff.png", metrics.diff_image(visibility[n], ours[n]))
        images[n] = {"mask": f"images/{stem}_mask.png", "diff": f"images/{stem}_diff.png"}
    overall = metrics.combine(per_light.values())
    return {
        "name": v.name, "label": v.label, "settings": v.settings.to_dict(),
        "shadow_ms": float(np.median(shadow)), "total_ms": float(np.median(tot)),
        "shadow_ms_samples": [float(x) for x in shadow], "total_ms_samples": [float(x) for x in tot],
        "overall": overall.to_dict(), "per_light": {n: e.to_dict() for n, e in per_light.items()},
        "images": images,
    }


def _mask(frame, index: int) -> np.ndarray:
    if index in frame.masks:
        return frame.mask_array(index)
    # an unshadowed light (not in the frame's masks): lit wherever another mask has geometry
    if not frame.masks:
        raise HybridShadowError("the frame has no mask to compare")
    m = frame.mask_array(next(iter(frame.masks)))
    return np.where(np.isfinite(m), 1.0, np.nan).astype(np.float32)


def _png(path: Path, rgb8: np.ndarray) -> None:
    write_png(str(path), rgb8)
