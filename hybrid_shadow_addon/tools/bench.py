"""Frame-rate benchmark along a camera path, the thesis' way (chapters 4.5-4.6, 5).

``N`` frames evenly spaced over the path's frame range come from a :class:`FrameSource`, one core
scene per frame (their export is timed apart). Every mode, and the no-shadow control (``none``),
is rendered along the path ``repeats`` times, in the order repetition -> mode -> frame. All modes
share one :class:`Pipeline`.

The scene is baked once. Between path frames only what changed is updated, outside the timing:
moved instances through :meth:`Pipeline.move_instances` (incremental), a full re-bake only when
the scene's structure (models, instance list) changes; camera and lights are per-frame inputs
anyway. Bake and update times are reported separately.

Per mode: the frame time of every frame and repetition (``Frame.timings["total_ms"]``); min /
average / max fps, average frame time, extra time over the control, standard deviation relative
to the mean, erraticness (:func:`.metrics.frame_stats`). Outputs: ``bench.json``, ``summary.md``
and the figures ``fig5_1_fps.png`` ... ``fig5_6_std_dev.png``.
"""
from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np

from ..core.errors import HybridShadowError
from ..core.progress import call
from ..core.scene import Scene
from . import metrics
from .reference import scene_hash
from .variants import VARIANTS, as_variants

DEFAULT_MODES = ("raytrace-high", "shadowmap-2048")
CONTROL = "none"


class FrameSource(Protocol):
    """The scenes of a camera path.

    - ``name``: the scene's label in ``bench.json`` and the summary.
    - ``version``: the version of what exports the scenes (``bench.json``'s ``bpy_version``).
    - ``frame_range``: ``(first, last)`` frame of the path, inclusive.
    """

    name: str
    version: str
    frame_range: tuple

    def scene_at(self, frame: int) -> Scene:
        """The validated core scene at ``frame``."""
        ...


def path_frames(frame_start: int, frame_end: int, n: int) -> list:
    """``n`` frames evenly spaced over ``frame_start..frame_end`` (inclusive, unique, rounded)."""
    if n < 1:
        raise HybridShadowError("--frames must be at least 1")
    if n == 1 or frame_end <= frame_start:
        return [int(frame_start)]
    return sorted({int(round(f)) for f in np.linspace(frame_start, frame_end, n)})


def _structure(scene) -> str:
    inst = scene.instances
    return scene_hash([scene.models, list(inst.names), inst.model_ids, inst.sphere, inst.casts_shadow])


def bench_variants(modes=None) -> list:
    """The control (``none``) first, then the variants of ``modes`` (names or :class:`Variant`
    objects; default :data:`DEFAULT_MODES`)."""
    picked = as_variants(list(modes) if modes else list(DEFAULT_MODES))
    return [VARIANTS[CONTROL]] + [v for v in picked if v.name != CONTROL]


def run_bench(source: FrameSource, output_dir, *, frames: int = 10, modes=None, repeats: int = 5,
              resolution=None, warmup: int = 1, progress=None, pipeline=None) -> dict:
    """Benchmark ``frames`` frames of ``source``'s path; ``resolution`` overrides the scenes';
    ``progress(done, total, label)`` after each step. Returns the ``bench.json`` dict."""
    if repeats < 1:
        raise HybridShadowError("--repeats must be at least 1")
    variants = bench_variants(modes)
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)

    fs = path_frames(*source.frame_range, frames)
    scenes, export_ms = [], []
    total = len(fs) + 1 + len(variants) * (warmup + repeats * len(fs)) + 1
    done = 0

    def step(label):
        nonlocal done
        done += 1
        call(progress, done, total, label)

    for f in fs:
        t0 = time.perf_counter()
        s = source.scene_at(f)
        if resolution is not None:
            s = replace(s, resolution=(int(resolution[0]), int(resolution[1])))
        scenes.append(s)
        export_ms.append((time.perf_counter() - t0) * 1e3)
        step(f"export frame {f}")
    width, height = scenes[0].resolution
    structures = [_structure(s) for s in scenes]

    own = pipeline is None
    if own:
        from ..core.gpu.pipeline import Pipeline

        pipeline = Pipeline()
    live = {"scene": None, "structure": None}
    bake_ms, update_ms = [], []

    def show(i):
        """Bring the pipeline to path frame ``i``; returns the scene to render."""
        s = scenes[i]
        cur = live["scene"]
        if cur is None or structures[i] != live["structure"]:
            live["scene"] = _copy_scene(s)
            live["structure"] = structures[i]
            bake_ms.append(pipeline.set_scene(live["scene"]))
            return live["scene"]
        cur.camera, cur.lights, cur.frame = s.camera, s.lights, s.frame
        moved = np.flatnonzero(np.any(cur.instances.matrices != s.instances.matrices, axis=(1, 2)))
        if len(moved):
            t0 = time.perf_counter()
            cur.instances.set_matrices(moved, s.instances.matrices[moved])
            pipeline.move_instances(cur, moved)
            update_ms.append((time.perf_counter() - t0) * 1e3)
        pipeline.reset_history()  # the camera moved: interlacing must not reuse older rays
        return cur

    times = {v.name: np.zeros((repeats, len(fs))) for v in variants}
    shadow = {v.name: np.zeros((repeats, len(fs))) for v in variants}
    try:
        scene0 = show(0)
        step(f"bake {bake_ms[0]:.0f} ms")
        for v in variants:  # shader compilation and first-use costs, untimed
            for _ in range(warmup):
                pipeline.render(scene0, v.settings, width, height)
                step(f"{v.name}: warm-up")
        for r in range(repeats):
            for v in variants:
                for i in range(len(fs)):
                    s = show(i)
                    frame = pipeline.render(s, v.settings, width, height)
                    times[v.name][r, i] = frame.timings["total_ms"]
                    shadow[v.name][r, i] = frame.timings["shadow_ms"]
                    step(f"pass {r + 1}/{repeats} {v.name} frame {fs[i]}")
    finally:
        if own:
            pipeline.release()

    control = times[CONTROL]
    result = {
        "scene": source.name,
        "frames": fs,
        "resolution": [int(width), int(height)],
        "repeats": int(repeats),
        "warmup": int(warmup),
        "bpy_version": source.version,
        "triangles": int(scenes[0].triangle_count),
        "instances": len(scenes[0].instances),
        "shadowed_lights": sum(1 for light in scenes[0].lights if light.use_shadow),
        "export_ms": [float(x) for x in export_ms],
        "bake_ms": [float(x) for x in bake_ms],
        "update_ms": {"count": len(update_ms), "mean": float(np.mean(update_ms)) if update_ms else 0.0,
                      "max": float(np.max(update_ms)) if update_ms else 0.0},
        "control": CONTROL,
        "modes": {},
    }
    for v in variants:
        st = metrics.frame_stats(times[v.name], None if v.name == CONTROL else control)
        if v.name == CONTROL:
            st["extra_ms"] = 0.0
            st["extra_ms_per_frame"] = [0.0] * len(fs)
        st["erraticness_per_frame"] = [float(x) for x in metrics.erraticness(times[v.name])]
        st["avg_shadow_ms"] = float(shadow[v.name].mean())
        result["modes"][v.name] = {
            "label": v.label, "settings": v.settings.to_dict(), "stats": st,
            "frame_ms": times[v.name].tolist(), "shadow_ms": shadow[v.name].tolist(),
        }
    figures = plot_bench(result, out)
    result["figures"] = figures
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "summary.md").write_text(summary_md(result))
    step("written")
    return result


def _copy_scene(s):
    """A scene whose instance matrices we may change (``set_matrices``) without touching ``s``."""
    inst = replace(s.instances, matrices=s.instances.matrices.copy(), inverse=s.instances.inverse.copy())
    return replace(s, instances=inst)


# ------------------------------------------------------------------------------------------------
# Figures (thesis 5.1-5.6) and the summary
# ------------------------------------------------------------------------------------------------
FIGURES = {
    "fig5_1_fps.png": "Average frame rate along the path",
    "fig5_2_fps_min_avg_max.png": "Minimum, average and maximum frame rate",
    "fig5_3_extra_frame_time.png": "Extra frame time over the no-shadow control along the path",
    "fig5_4_avg_extra_time.png": "Average extra frame time over the control",
    "fig5_5_erraticness.png": "Erraticness along the path",
    "fig5_6_std_dev.png": "Standard deviation of the frame rate, relative to the mean",
}


def plot_bench(b: dict, out: Path) -> dict:
    from matplotlib.figure import Figure  # no pyplot: no global backend

    names = list(b["modes"])
    labels = [b["modes"][n]["label"] if n != CONTROL else "none (control)" for n in names]
    colours = {n: c for n, c in zip(names, ["tab:blue", "tab:red", "tab:green", "tab:orange", "tab:purple",
                                               "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray"])}
    fs = b["frames"]
    title = f"{b['scene']} {b['resolution'][0]}x{b['resolution'][1]}, {b['repeats']} passes"

    def fig_line(fname, ylabel, series, skip_control=False):
        fig = Figure(figsize=(8, 4.2), dpi=100)
        ax = fig.subplots()
        for n, lab in zip(names, labels):
            if skip_control and n == CONTROL:
                continue
            ax.plot(fs, series(n), marker="o", ms=3, color=colours[n], label=lab)
        ax.set_xlabel("frame")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{FIGURES[fname]}: {title}", fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / fname)

    def fig_bars(fname, ylabel, values, skip_control=False):
        fig = Figure(figsize=(7, 4.2), dpi=100)
        ax = fig.subplots()
        keep = [(n, lab) for n, lab in zip(names, labels) if not (skip_control and n == CONTROL)]
        vals = [values(n) for n, _ in keep]
        if vals and isinstance(vals[0], tuple):
            x = np.arange(len(keep))
            for j, (part, c) in enumerate(zip(("min", "avg", "max"), ("tab:red", "tab:blue", "tab:green"))):
                bars = ax.bar(x + (j - 1) * 0.27, [v[j] for v in vals], 0.27, label=part, color=c)
                ax.bar_label(bars, fmt="%.1f", fontsize=7)
            ax.set_xticks(x, [lab for _, lab in keep])
            ax.legend(fontsize=8)
        else:
            bars = ax.bar([lab for _, lab in keep], vals, color=[colours[n] for n, _ in keep])
            ax.bar_label(bars, fmt="%.3g", fontsize=8)
        ax.set_ylabel(ylabel)
        ax.set_title(f"{FIGURES[fname]}: {title}", fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / fname)

    mode = b["modes"]
    fig_line("fig5_1_fps.png", "fps (average of the passes)",
             lambda n: metrics.fps_of(mode[n]["frame_ms"]).mean(axis=0))
    fig_bars("fig5_2_fps_min_avg_max.png", "fps",
             lambda n: (mode[n]["stats"]["min_fps"], mode[n]["stats"]["avg_fps"], mode[n]["stats"]["max_fps"]))
    fig_line("fig5_3_extra_frame_time.png", "ms over the control", lambda n: mode[n]["stats"]["extra_ms_per_frame"],
             skip_control=True)
    fig_bars("fig5_4_avg_extra_time.png", "average ms over the control", lambda n: mode[n]["stats"]["extra_ms"],
             skip_control=True)
    fig_line("fig5_5_erraticness.png", "erraticness (sum |fps - mean| / mean fps)",
             lambda n: mode[n]["stats"]["erraticness_per_frame"])
    fig_bars("fig5_6_std_dev.png", "std-dev of fps / mean fps", lambda n: mode[n]["stats"]["std_rel"])
    return dict(FIGURES)


def summary_rows(b: dict) -> list:
    rows = []
    for n, m in b["modes"].items():
        s = m["stats"]
        rows.append((m["label"] + (" (control)" if n == CONTROL else ""), s["min_fps"], s["avg_fps"], s["max_fps"],
                     s["avg_frame_ms"], s["extra_ms"], s["avg_shadow_ms"], 100 * s["std_rel"], s["erraticness"]))
    return rows


def summary_md(b: dict) -> str:
    lines = [f"# Benchmark: {b['scene']}", "",
             f"{len(b['frames'])} frames ({b['frames'][0]}..{b['frames'][-1]}) at {b['resolution'][0]}x"
             f"{b['resolution'][1]}, {b['repeats']} passes per mode, bpy {b['bpy_version']}; "
             f"{b['triangles']} triangles, {b['instances']} instances, {b['shadowed_lights']} shadowed lights.", "",
             f"Bake {', '.join(f'{x:.0f}' for x in b['bake_ms'])} ms (not timed in the frames); incremental updates: "
             f"{b['update_ms']['count']}, mean {b['update_ms']['mean']:.1f} ms; export "
             f"{np.mean(b['export_ms']):.0f} ms per frame.", "",
             "| mode | min fps | avg fps | max fps | avg frame ms | extra ms over control | avg shadow ms | "
             "std-dev % of mean | erraticness |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in summary_rows(b):
        lines.append("| {} | {:.1f} | {:.1f} | {:.1f} | {:.2f} | {:.2f} | {:.2f} | {:.1f} | {:.3f} |".format(*row))
    lines += ["", "Frame time: G-buffer + shadows + upsample + lighting + readback, until `glFinish`. "
              "Erraticness (thesis 4.6): per frame, the absolute differences of each pass' fps from the passes' "
              "average, summed, over the average fps; the table shows its mean along the path. Std-dev: sample "
              "standard deviation of every fps sample over their mean.", ""]
    for fname, caption in b["figures"].items():
        lines += [f"## {caption}", "", f"![{caption}]({fname})", ""]
    return "\n".join(lines)


def text_summary(b: dict) -> str:
    head = (f"{'mode':<26}{'min fps':>9}{'avg fps':>9}{'max fps':>9}{'avg ms':>9}{'extra ms':>10}"
            f"{'shadow ms':>10}{'std %':>7}{'errat.':>8}")
    lines = [head]
    for row in summary_rows(b):
        lines.append("{:<26}{:>9.1f}{:>9.1f}{:>9.1f}{:>9.2f}{:>10.2f}{:>10.2f}{:>7.1f}{:>8.3f}".format(*row))
    return "\n".join(lines)
