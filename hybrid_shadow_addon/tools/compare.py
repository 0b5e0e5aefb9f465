"""Compare every shadow mode and quality with a per-light Cycles visibility reference: error
against run time.

For the bpy scene as loaded (its current frame):

1. The Cycles reference (:func:`~.cycles_reference.render_reference`, one light at a time, both
   ``use_shadow`` on and off, the ratio), cached on disk under a hash of the exported scene, the
   resolution, the sample count, the recipe and the bpy version.
2. One shared :class:`Pipeline`: bake once, then per variant (``raytrace-high`` ...
   ``shadowmap-4096``, ``none``) ``warmup`` untimed frames (shader compilation) and ``repeats``
   timed ones; the medians of shadow ms and total ms. The masks of the last frame are compared
   with the reference (:mod:`..core.metrics`). ``raytrace-interlaced`` is timed in its steady state
   (a quarter of the rays per frame) and its error measured on the first frame after a change
   (:meth:`Pipeline.reset_history`): the worst case of interlacing.
3. ``metrics.json``, ``images/*.png`` (reference, our mask and the false-colour difference per
   variant and light), ``error_vs_time.png`` and ``report.html``.

The work is a generator of steps (:func:`compare_steps`) so the Blender operator can run it from
a modal timer and cancel between steps; :func:`run_compare` drives it with a progress callback.
"""
from __future__ import annotations

import contextlib
import hashlib
import html
import json
import os
import re
import time
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np

from ..core import metrics
from ..core.errors import HybridShadowError
from ..core.settings import Settings

RECIPE_VERSION = 2  # bump when the reference recipe changes: invalidates the cache


# ------------------------------------------------------------------------------------------------
# Variants
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Variant:
    name: str
    label: str
    settings: Settings


def _variants() -> dict:
    out = {}
    for q in ("high", "medium", "low"):
        out[f"raytrace-{q}"] = Variant(f"raytrace-{q}", f"raytrace {q}", Settings(mode="raytrace", quality=q))
    out["raytrace-interlaced"] = Variant("raytrace-interlaced", "raytrace high interlaced",
                                         Settings(mode="raytrace", quality="high", interlace=True))
    for s in (512, 1024, 2048, 4096):
        out[f"shadowmap-{s}"] = Variant(f"shadowmap-{s}", f"shadowmap {s}", Settings(mode="shadowmap", shadowmap_size=s))
    out["none"] = Variant("none", "none", Settings(mode="none"))
    return out


VARIANTS = _variants()
GROUPS = {"raytrace": [k for k in VARIANTS if k.startswith("raytrace")],
          "shadowmap": [k for k in VARIANTS if k.startswith("shadowmap")],
          "all": list(VARIANTS)}


def resolve_variants(names=None) -> list:
    """Variant names (or groups ``raytrace``, ``shadowmap``, ``all``; ``shadowmap-N`` for any
    size N) to :class:`Variant` objects, in the canonical order, without duplicates."""
    if not names:
        names = ["all"]
    picked = []
    for n in names:
        for part in str(n).split(","):
            part = part.strip().lower()
            if not part:
                continue
            if part in GROUPS:
                picked.extend(VARIANTS[k] for k in GROUPS[part])
            elif part in VARIANTS:
                picked.append(VARIANTS[part])
            elif re.fullmatch(r"shadowmap-\d+", part):
                size = int(part.split("-")[1])
                try:
                    picked.append(Variant(part, f"shadowmap {size}", Settings(mode="shadowmap", shadowmap_size=size)))
                except ValueError as e:
                    raise HybridShadowError(f"--modes {part}: {e}") from None
            else:
                raise HybridShadowError(f"unknown mode '{part}': use {', '.join(list(VARIANTS) + list(GROUPS))} "
                                        f"or shadowmap-N")
    seen, out = set(), []
    order = list(VARIANTS)
    for v in sorted(picked, key=lambda v: (order.index(v.name) if v.name in order else len(order), v.name)):
        if v.name not in seen:
            seen.add(v.name)
            out.append(v)
    return out


# ------------------------------------------------------------------------------------------------
# Reference cache
# ------------------------------------------------------------------------------------------------
def _feed(h, obj) -> None:
    if is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in fields(obj):
            h.update(f.name.encode())
            _feed(h, getattr(obj, f.name))
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            h.update(repr(k).encode())
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"seq{len(obj)}".encode())
        for v in obj:
            _feed(h, v)
    else:
        h.update(repr(obj).encode())


def scene_hash(scene) -> str:
    """SHA-256 of everything in the exported core scene (geometry, instances, lights, camera)."""
    h = hashlib.sha256()
    _feed(h, scene)
    return h.hexdigest()


def reference_key(scene, resolution, samples: int, light_names) -> str:
    import bpy

    h = hashlib.sha256()
    _feed(h, [scene_hash(scene), list(resolution), int(samples), list(light_names), RECIPE_VERSION,
              bpy.app.version_string])
    return h.hexdigest()[:24]


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "hybrid_shadows" / "cycles"


def load_cached(path: Path):
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            vis = {n: z[f"vis{i}"].astype(np.float32) for i, n in enumerate(meta["lights"])}
        return vis, meta["render_ms"]
    except (OSError, KeyError, ValueError):
        return None


def save_cached(path: Path, visibility: dict, render_ms: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(visibility)
    arrays = {f"vis{i}": visibility[n] for i, n in enumerate(names)}
    meta = json.dumps({"lights": names, "render_ms": render_ms})
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, meta=np.array(meta), **arrays)
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------------------
# The steps
# ------------------------------------------------------------------------------------------------
def safe_name(text: str) -> str:
    return re.sub(r"[^\w.-]+", "_", text).strip("_") or "light"


def reference_lights(bscene, scene) -> list:
    """Names of the exported shadow-casting lights that are light objects of ``bscene`` (Cycles
    renders one at a time by hiding the others)."""
    objs = bscene.objects
    return [l.name for l in scene.lights
            if l.use_shadow and l.name in objs and objs[l.name].type == "LIGHT" and not objs[l.name].hide_render]


def compare_steps(bscene, output_dir, *, resolution=None, variants=None, repeats: int = 5, warmup: int = 2,
                  samples: int = 1, cache_dir=None, use_cache: bool = True, pipeline=None,
                  gl_scope=None, scene_label: str | None = None, result: dict | None = None):
    """Generator doing the comparison step by step; yields ``(done, total, label)`` after each
    step. The final metrics dict is stored in ``result["metrics"]`` (pass a dict)."""
    import bpy

    from ..blender.export import export_depsgraph
    from .cycles_reference import render_reference

    if repeats < 1 or warmup < 0:
        raise HybridShadowError("--repeats must be at least 1 and --warmup at least 0")
    result = {} if result is None else result
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "images").mkdir(exist_ok=True)
    gl = gl_scope or contextlib.nullcontext
    variants = resolve_variants(variants) if not variants or isinstance(variants[0], str) else list(variants)

    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = export_depsgraph(depsgraph, resolution=resolution).validate()
    width, height = scene.resolution if resolution is None else resolution
    names = reference_lights(bscene, scene)
    if not names:
        raise HybridShadowError(f"scene '{bscene.name}' has no shadow-casting light to compare")
    interlace_extra = 4
    per_variant = warmup + repeats + 1
    total = len(names) + sum(per_variant + (interlace_extra if v.settings.interlace else 0) for v in variants) + 2
    done = 0

    # -- 1. the Cycles reference, per light, cached -----------------------------------------------
    key = reference_key(scene, (width, height), samples, names)
    cache_path = Path(cache_dir or default_cache_dir()) / f"{key}.npz"
    cached = load_cached(cache_path) if use_cache else None
    if cached is not None and set(cached[0]) == set(names):
        reference, cycles_ms = cached
        done += len(names)
        yield done, total, "Cycles reference (cached)"
        from_cache = True
    else:
        reference, cycles_ms = {}, {}
        for name in names:
            ref = render_reference(bscene, [name], resolution=(width, height), samples=samples)
            reference[name] = ref.visibility[name]
            cycles_ms[name] = ref.render_ms[name]
            done += 1
            yield done, total, f"Cycles reference: {name}"
        if use_cache:
            save_cached(cache_path, reference, cycles_ms)
        from_cache = False

    # -- 2. every variant on one pipeline ----------------------------------------------------------
    own_pipeline = pipeline is None
    if own_pipeline:
        from ..core.gpu.pipeline import Pipeline

        pipeline = Pipeline()
    light_index = {l.name: i for i, l in enumerate(scene.lights)}
    rows = []
    try:
        with gl():
            bake_ms = pipeline.set_scene(scene)
        done += 1
        yield done, total, f"bake {bake_ms:.0f} ms"
        for v in variants:
            s = v.settings
            shadow, tot = [], []
            with gl():
                pipeline.reset_history()
            n_warm = warmup + (interlace_extra if s.interlace else 0)
            for k in range(n_warm + repeats):
                with gl():
                    frame = pipeline.render(scene, s, width, height)
                if k >= n_warm:
                    shadow.append(frame.timings["shadow_ms"])
                    tot.append(frame.timings["total_ms"])
                done += 1
                yield done, total, f"{v.name}: frame {k + 1}/{n_warm + repeats}"
            with gl():
                if s.interlace:  # the error of the first frame after a change
                    pipeline.reset_history()
                    frame = pipeline.render(scene, s, width, height)
                ours = {n: _mask(frame, light_index[n]) for n in names}
            done += 1
            yield done, total, f"{v.name}: error"
            per_light = {}
            images = {}
            for n in names:
                e = metrics.mask_error(reference[n], ours[n])
                per_light[n] = e
                stem = f"{v.name}_{safe_name(n)}"
                _png(out / "images" / f"{stem}_mask.png", metrics.visibility_image(ours[n]))
                _png(out / "images" / f"{stem}_diff.png", metrics.diff_image(reference[n], ours[n]))
                images[n] = {"mask": f"images/{stem}_mask.png", "diff": f"images/{stem}_diff.png"}
            overall = metrics.combine(per_light.values())
            rows.append({
                "name": v.name, "label": v.label, "settings": v.settings.to_dict(),
                "shadow_ms": float(np.median(shadow)), "total_ms": float(np.median(tot)),
                "shadow_ms_samples": [float(x) for x in shadow], "total_ms_samples": [float(x) for x in tot],
                "overall": overall.to_dict(), "per_light": {n: e.to_dict() for n, e in per_light.items()},
                "images": images,
            })
    finally:
        if own_pipeline:
            with gl():
                pipeline.release()

    # -- 3. outputs ---------------------------------------------------------------------------------
    ref_images = {}
    for n in names:
        p = f"images/reference_{safe_name(n)}.png"
        _png(out / p, metrics.visibility_image(reference[n]))
        ref_images[n] = p
    front = metrics.pareto_front([(r["total_ms"], r["overall"]["mismatch_pct"]) for r in rows])
    for i, r in enumerate(rows):
        r["pareto"] = i in front
    m = {
        "scene": scene_label or bscene.name,
        "frame": int(bscene.frame_current),
        "resolution": [int(width), int(height)],
        "bpy_version": bpy.app.version_string,
        "lights": names,
        "threshold": metrics.MISMATCH_THRESHOLD,
        "repeats": int(repeats),
        "warmup": int(warmup),
        "bake_ms": float(bake_ms),
        "triangles": int(scene.triangle_count),
        "instances": len(scene.instances),
        "reference": {
            "samples": int(samples), "cached": from_cache, "cache_file": str(cache_path) if use_cache else None,
            "render_ms": {n: float(t) for n, t in cycles_ms.items()},
            "total_ms": float(sum(cycles_ms.values())),
            "images": ref_images,
            "valid_pixels": {n: int(np.isfinite(reference[n]).sum()) for n in names},
        },
        "variants": rows,
        "pareto": [rows[i]["name"] for i in front],
        "files": {"metrics": "metrics.json", "plot": "error_vs_time.png", "report": "report.html"},
    }
    plot_error_vs_time(m, out / "error_vs_time.png")
    (out / "metrics.json").write_text(json.dumps(m, indent=2) + "\n")
    (out / "report.html").write_text(report_html(m))
    done += 1
    result["metrics"] = m
    yield done, total, "report written"


def _mask(frame, index: int) -> np.ndarray:
    if index in frame.masks:
        return frame.mask_array(index)
    # an unshadowed light (not in the frame's masks): lit wherever another mask has geometry
    if not frame.masks:
        raise HybridShadowError("the frame has no mask to compare")
    m = frame.mask_array(next(iter(frame.masks)))
    return np.where(np.isfinite(m), 1.0, np.nan).astype(np.float32)


def _png(path: Path, rgb8: np.ndarray) -> None:
    from ..core.gpu.passes import write_png

    write_png(str(path), rgb8)


def run_compare(bscene, output_dir, *, progress=None, **kwargs) -> dict:
    """Run :func:`compare_steps` to the end; ``progress(done, total, label)`` after each step
    (it may raise to cancel). Returns the metrics dict (also in ``metrics.json``)."""
    result = {}
    for done, total, label in compare_steps(bscene, output_dir, result=result, **kwargs):
        if progress:
            progress(done, total, label)
    return result["metrics"]


# ------------------------------------------------------------------------------------------------
# Plot and report
# ------------------------------------------------------------------------------------------------
def plot_error_vs_time(m: dict, path) -> None:
    import matplotlib.ticker
    from matplotlib.figure import Figure  # no pyplot: no global backend (safe inside Blender)

    rows = m["variants"]
    fig = Figure(figsize=(8, 5), dpi=110)
    ax = fig.subplots()
    colours = {"raytrace": "tab:red", "shadowmap": "tab:blue", "none": "tab:gray"}
    for i, r in enumerate(sorted(rows, key=lambda r: r["total_ms"])):
        t, e = r["total_ms"], r["overall"]["mismatch_pct"]
        ax.scatter([t], [e], s=46, color=colours.get(r["settings"]["mode"], "k"), zorder=3,
                   edgecolors="k" if r.get("pareto") else "none", linewidths=1.2)
        ax.annotate(r["label"], (t, e), textcoords="offset points", xytext=(6, 4 if i % 2 == 0 else -11), fontsize=8)
    front = sorted((r for r in rows if r.get("pareto")), key=lambda r: r["total_ms"])
    if len(front) > 1:
        xs = [r["total_ms"] for r in front]
        ys = [r["overall"]["mismatch_pct"] for r in front]
        ax.step(xs, ys, where="post", color="k", lw=1, ls="--", zorder=2, label="Pareto front")
    cyc = m["reference"]["total_ms"]
    if cyc > 0:
        ax.axvline(cyc, color="tab:green", lw=1.5, label=f"Cycles reference ({cyc:.0f} ms, "
                   f"{len(m['lights'])} light{'s' if len(m['lights']) != 1 else ''} x 2 renders)")
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(
        lambda v, _: f"{v:g}" if f"{v:g}"[0] in "25" else ""))
    ax.set_xlabel("time per frame, ms (log; median of warm frames)")
    ax.set_ylabel(f"mismatch, % of valid pixels (|Δ| > {m['threshold']})")
    ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"{m['scene']} {m['resolution'][0]}x{m['resolution'][1]}: shadow error against run time")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def table_rows(m: dict) -> list:
    """(name, shadow ms, total ms, mismatch %, missed %, false %, MAE) per variant."""
    return [(r["label"], r["shadow_ms"], r["total_ms"], r["overall"]["mismatch_pct"], r["overall"]["missed_pct"],
             r["overall"]["false_pct"], r["overall"]["mae"]) for r in m["variants"]]


def markdown_table(m: dict) -> str:
    lines = ["| mode | shadow ms | total ms | mismatch % | missed % | false % | MAE |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, sm, tm, mm, mi, fa, mae in table_rows(m):
        lines.append(f"| {name} | {sm:.1f} | {tm:.1f} | {mm:.3f} | {mi:.3f} | {fa:.3f} | {mae:.4f} |")
    lines.append(f"| Cycles reference (per light: 2 renders) | – | {m['reference']['total_ms']:.0f} | 0 | 0 | 0 | 0 |")
    return "\n".join(lines)


def text_table(m: dict) -> str:
    head = f"{'mode':<26}{'shadow ms':>10}{'total ms':>10}{'mismatch %':>12}{'missed %':>10}{'false %':>9}{'MAE':>8}"
    lines = [head]
    for name, sm, tm, mm, mi, fa, mae in table_rows(m):
        lines.append(f"{name:<26}{sm:>10.1f}{tm:>10.1f}{mm:>12.3f}{mi:>10.3f}{fa:>9.3f}{mae:>8.4f}")
    ref = m["reference"]
    lines.append(f"{'Cycles reference':<26}{'':>10}{ref['total_ms']:>10.0f}"
                 f"{'':>12}{'':>10}{'':>9}{'':>8}  ({'cached' if ref['cached'] else 'rendered'})")
    return "\n".join(lines)


def report_html(m: dict) -> str:
    e = html.escape
    lights = m["lights"]
    head = ("<tr><th>mode</th><th>shadow ms</th><th>total ms</th><th>mismatch %</th><th>missed %</th>"
            "<th>false %</th><th>MAE</th>" + "".join(f"<th>{e(n)} mismatch %</th>" for n in lights) + "</tr>")
    body = []
    for r in m["variants"]:
        o = r["overall"]
        cls = ' class="pareto"' if r.get("pareto") else ""
        body.append(f"<tr{cls}><td>{e(r['label'])}</td><td>{r['shadow_ms']:.1f}</td><td>{r['total_ms']:.1f}</td>"
                    f"<td>{o['mismatch_pct']:.3f}</td><td>{o['missed_pct']:.3f}</td><td>{o['false_pct']:.3f}</td>"
                    f"<td>{o['mae']:.4f}</td>"
                    + "".join(f"<td>{r['per_light'][n]['mismatch_pct']:.3f}</td>" for n in lights) + "</tr>")
    ref = m["reference"]
    body.append(f"<tr><td>Cycles reference</td><td>–</td><td>{ref['total_ms']:.0f}</td><td colspan=\"{4 + len(lights)}\">"
                f"{ref['samples']} spp, {'cached' if ref['cached'] else 'rendered now'}; per light: "
                + ", ".join(f"{e(n)} {t:.0f} ms" for n, t in ref["render_ms"].items()) + "</td></tr>")
    grids = []
    for n in lights:
        cells = [f"<tr><td>Cycles reference</td><td><img src=\"{e(ref['images'][n])}\" alt=\"reference {e(n)}\"></td>"
                 f"<td class=\"legend\">valid pixels: {ref['valid_pixels'][n]}<br>"
                 "<span style=\"color:#eb2828\">■</span> missed shadow (we are lit)<br>"
                 "<span style=\"color:#1e8cff\">■</span> false shadow (we are shadowed)<br>"
                 "black: not valid</td></tr>"]
        for r in m["variants"]:
            im = r["images"][n]
            cells.append(f"<tr><td>{e(r['label'])}<br>{r['per_light'][n]['mismatch_pct']:.3f} %</td>"
                         f"<td><img src=\"{e(im['mask'])}\" alt=\"{e(r['name'])} mask\"></td>"
                         f"<td><img src=\"{e(im['diff'])}\" alt=\"{e(r['name'])} difference\"></td></tr>")
        grids.append(f"<h3>Light {e(n)}</h3><table class=\"grid\"><tr><th></th><th>visibility</th>"
                     f"<th>difference to Cycles</th></tr>{''.join(cells)}</table>")
    w, h = m["resolution"]
    scale = max(1, min(4, 480 // max(w, 1)))
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>Hybrid Shadows vs Cycles: {e(m['scene'])}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; margin-bottom: 1.5em; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; text-align: right; }}
td:first-child {{ text-align: left; }}
tr.pareto td:first-child {{ font-weight: bold; }}
.grid img {{ width: {w * scale}px; image-rendering: pixelated; }}
.legend {{ text-align: left; font-size: 90%; }}
</style></head><body>
<h1>Hybrid Shadows vs Cycles: {e(m['scene'])}</h1>
<p>Frame {m['frame']}, {w}x{h}, bpy {e(m['bpy_version'])}; {m['triangles']} triangles, {m['instances']} instances;
bake {m['bake_ms']:.0f} ms. Times: median of {m['repeats']} warm frames after {m['warmup']} warm-up frames.
Error: pixels valid in the Cycles reference and with geometry in ours; mismatch = |Δ| &gt; {m['threshold']}.
Interlaced ray tracing: error of the first frame after a change. Bold: on the Pareto front.</p>
<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>
<h2>Error against time</h2>
<p><img src="error_vs_time.png" alt="error against time"></p>
<h2>Masks and differences</h2>
{''.join(grids)}
<p><a href="metrics.json">metrics.json</a></p>
</body></html>
"""
