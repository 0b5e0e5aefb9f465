"""The outputs of ``compare`` from its metrics dict: the error-against-time plot, the text
table the CLI prints and the HTML report.

A hard comparison's error is the mismatch (% of valid pixels with |Δ| > 0.5); a soft one's
(``m["soft"]``) the mean absolute error and the share of valid pixels off by more than 0.1
(``off_pct``), each with its own axis of the plot, its own columns."""
from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

#: the error axis of the plot is logarithmic: mismatches below this (% of pixels) sit on it
ERROR_FLOOR_PCT = 1e-3
#: ... and mean absolute errors below this
ERROR_FLOOR_MAE = 1e-5


def is_soft(m: dict) -> bool:
    return bool(m.get("soft"))


def plot_axes(m: dict) -> list:
    """``(metric key, axis label, floor)`` of each panel of the plot: the mismatch for a hard
    comparison; the MAE and the share off by more than 0.1 for a soft one."""
    if is_soft(m):
        return [("mae", "mean absolute error (log, floor {floor:g})", ERROR_FLOOR_MAE),
                ("off_pct", f"% of valid pixels off by > {m.get('off_threshold', 0.1)} (log, floor {{floor:g}})",
                 ERROR_FLOOR_PCT)]
    return [("mismatch_pct", f"mismatch, % of valid pixels (|Δ| > {m['threshold']}; log, floor {{floor:g}})",
             ERROR_FLOOR_PCT)]


def write_report(m: dict, out) -> None:
    """``error_vs_time.png``, ``metrics.json`` and ``report.html`` into the folder ``out``."""
    out = Path(out)
    plot_error_vs_time(m, out / "error_vs_time.png")
    (out / "metrics.json").write_text(json.dumps(m, indent=2) + "\n")
    (out / "report.html").write_text(report_html(m))


def plot_error_vs_time(m: dict, path) -> None:
    """The plot with matplotlib where it is installed, else drawn with numpy alone
    (:mod:`.raster_plot`: Blender's Python has no matplotlib)."""
    try:
        import matplotlib.ticker
        from matplotlib.figure import Figure  # no pyplot: no global backend (safe inside Blender)
    except ImportError:
        from .raster_plot import plot_error_vs_time_png

        plot_error_vs_time_png(m, path, plot_axes(m))
        return
    rows = m["variants"]
    panels = plot_axes(m)
    fig = Figure(figsize=(8 * len(panels), 5), dpi=110)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    colours = {"raytrace": "tab:red", "shadowmap": "tab:blue", "none": "tab:gray"}
    primary = m.get("error_metric", panels[0][0])  # the metric the Pareto front weighs
    for ax, (key, ylabel, floor) in zip(axes, panels):
        # (log axis: a variant without error is drawn on the floor)
        level, last = 0, None
        for r in sorted(rows, key=lambda r: r["total_ms"]):
            t, e = r["total_ms"], max(r["overall"][key], floor)
            ax.scatter([t], [e], s=46, color=colours.get(r["settings"]["mode"], "k"), zorder=3,
                       edgecolors="k" if r.get("pareto") else "none", linewidths=1.2)
            # (a point close to the one before it gets its label at the next of four heights, so
            # that points of equal error and close times, e.g. every exact ray-traced variant on
            # the floor, stay readable)
            close = last is not None and abs(np.log10(t / last[0])) < 0.35 and abs(np.log10(e / last[1])) < 0.3
            level = level + 1 if close else 0
            last = (t, e)
            ax.annotate(r["label"], (t, e), textcoords="offset points", xytext=(6, (4, -11, 16, 28)[level % 4]),
                        fontsize=8, arrowprops=dict(arrowstyle="-", lw=0.5, color="0.4") if level % 4 else None)
        front = sorted((r for r in rows if r.get("pareto")), key=lambda r: r["total_ms"])
        if len(front) > 1 and key == primary:
            xs = [r["total_ms"] for r in front]
            ys = [max(r["overall"][key], floor) for r in front]
            ax.step(xs, ys, where="post", color="k", lw=1, ls="--", zorder=2, label="Pareto front")
        cyc = m["reference"]["total_ms"]
        if cyc > 0:
            ax.axvline(cyc, color="tab:green", lw=1.5, label=f"Cycles {'soft ' if is_soft(m) else ''}reference "
                       f"({cyc:.0f} ms, {len(m['lights'])} light{'s' if len(m['lights']) != 1 else ''} x 2 renders)")
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.FuncFormatter(
            lambda v, _: f"{v:g}" if f"{v:g}"[0] in "25" else ""))
        ax.set_xlabel("time per frame, ms (log; median of warm frames)")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_ylabel(ylabel.format(floor=floor))
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title(f"{m['scene']} {m['resolution'][0]}x{m['resolution'][1]}: "
                     f"{'soft ' if is_soft(m) else ''}shadow error against run time")
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def table_rows(m: dict) -> list:
    """(name, shadow ms, total ms, mismatch %, missed %, false %, MAE) per variant."""
    return [(r["label"], r["shadow_ms"], r["total_ms"], r["overall"]["mismatch_pct"], r["overall"]["missed_pct"],
             r["overall"]["false_pct"], r["overall"]["mae"]) for r in m["variants"]]


def soft_table_rows(m: dict) -> list:
    """(name, shadow ms, total ms, MAE, off %, mismatch %) per variant (soft comparisons)."""
    return [(r["label"], r["shadow_ms"], r["total_ms"], r["overall"]["mae"], r["overall"]["off_pct"],
             r["overall"]["mismatch_pct"]) for r in m["variants"]]


def text_table(m: dict) -> str:
    if is_soft(m):
        return _soft_text_table(m)
    head = f"{'mode':<26}{'shadow ms':>10}{'total ms':>10}{'mismatch %':>12}{'missed %':>10}{'false %':>9}{'MAE':>8}"
    lines = [head]
    for name, sm, tm, mm, mi, fa, mae in table_rows(m):
        lines.append(f"{name:<26}{sm:>10.1f}{tm:>10.1f}{mm:>12.3f}{mi:>10.3f}{fa:>9.3f}{mae:>8.4f}")
    ref = m["reference"]
    lines.append(f"{'Cycles reference':<26}{'':>10}{ref['total_ms']:>10.0f}"
                 f"{'':>12}{'':>10}{'':>9}{'':>8}  ({'cached' if ref['cached'] else 'rendered'})")
    return "\n".join(lines)


def _soft_text_table(m: dict) -> str:
    off = f"> {m.get('off_threshold', 0.1)} %"
    lines = [f"{'mode':<26}{'shadow ms':>10}{'total ms':>10}{'MAE':>9}{off:>9}{'mismatch %':>12}"]
    for name, sm, tm, mae, op, mm in soft_table_rows(m):
        lines.append(f"{name:<26}{sm:>10.1f}{tm:>10.1f}{mae:>9.4f}{op:>9.3f}{mm:>12.3f}")
    ref = m["reference"]
    lines.append(f"{'Cycles soft reference':<26}{'':>10}{ref['total_ms']:>10.0f}{'':>9}{'':>9}{'':>12}"
                 f"  ({ref['samples']} spp, {'cached' if ref['cached'] else 'rendered'})")
    return "\n".join(lines)


def _light_error(m: dict, r: dict, n: str) -> str:
    """One variant's error for light ``n`` in the report: mismatch %, or soft: MAE and off %."""
    p = r["per_light"][n]
    return f"{p['mae']:.4f} / {p['off_pct']:.2f} %" if is_soft(m) else f"{p['mismatch_pct']:.3f} %"


def _mode_note(m: dict) -> str:
    if not is_soft(m):
        return "Every light hard (point-like) in the reference and in ours."
    sm = {"pcss": "percentage-closer soft shadows"}.get(m.get("soft_shadowmap_filter"))
    maps = f" Shadow maps: {sm or 'hard (no soft filter)'}." if any(
        r["settings"]["mode"] == "shadowmap" for r in m["variants"]) else ""
    return (f"Soft: the lights keep their sizes (sun angle, radius, area size and shape); the reference has "
            f"{m['reference']['samples']} samples at each pixel centre. Error: the mean absolute error (MAE) and "
            f"the share of valid pixels off by more than {m.get('off_threshold', 0.1)}; the Pareto front weighs "
            f"the MAE.{maps}")


def _warnings_html(m: dict) -> str:
    """The export report's lines (what the scene uses that is not rendered as Cycles does)."""
    lines = m.get("warnings") or []
    if not lines:
        return ""
    items = "".join(f"<li>{html.escape(str(w))}</li>" for w in lines)
    return f"<h2>Export report</h2>\n<p>Approximated or left out ({len(lines)}):</p><ul>{items}</ul>\n"


def report_html(m: dict) -> str:
    e = html.escape
    lights = m["lights"]
    soft = is_soft(m)
    off = f"&gt; {m.get('off_threshold', 0.1)} %"
    if soft:
        head = ("<tr><th>mode</th><th>shadow ms</th><th>total ms</th><th>MAE</th>"
                f"<th>{off}</th><th>mismatch %</th>"
                + "".join(f"<th>{e(n)} MAE</th><th>{e(n)} {off}</th>" for n in lights) + "</tr>")
    else:
        head = ("<tr><th>mode</th><th>shadow ms</th><th>total ms</th><th>mismatch %</th><th>missed %</th>"
                "<th>false %</th><th>MAE</th>" + "".join(f"<th>{e(n)} mismatch %</th>" for n in lights) + "</tr>")
    body = []
    for r in m["variants"]:
        o = r["overall"]
        cls = ' class="pareto"' if r.get("pareto") else ""
        if soft:
            body.append(f"<tr{cls}><td>{e(r['label'])}</td><td>{r['shadow_ms']:.1f}</td><td>{r['total_ms']:.1f}</td>"
                        f"<td>{o['mae']:.4f}</td><td>{o['off_pct']:.3f}</td><td>{o['mismatch_pct']:.3f}</td>"
                        + "".join(f"<td>{r['per_light'][n]['mae']:.4f}</td><td>{r['per_light'][n]['off_pct']:.3f}</td>"
                                  for n in lights) + "</tr>")
        else:
            body.append(f"<tr{cls}><td>{e(r['label'])}</td><td>{r['shadow_ms']:.1f}</td><td>{r['total_ms']:.1f}</td>"
                        f"<td>{o['mismatch_pct']:.3f}</td><td>{o['missed_pct']:.3f}</td><td>{o['false_pct']:.3f}</td>"
                        f"<td>{o['mae']:.4f}</td>"
                        + "".join(f"<td>{r['per_light'][n]['mismatch_pct']:.3f}</td>" for n in lights) + "</tr>")
    ref = m["reference"]
    span = 3 + 2 * len(lights) if soft else 4 + len(lights)
    body.append(f"<tr><td>Cycles {'soft ' if soft else ''}reference</td><td>–</td><td>{ref['total_ms']:.0f}</td>"
                f"<td colspan=\"{span}\">"
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
            cells.append(f"<tr><td>{e(r['label'])}<br>{_light_error(m, r, n)}</td>"
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
bake {m['bake_ms']:.0f} ms, light grids {m.get('light_grid_build_ms', 0.0):.0f} ms (once, in the warm-up). \
Times: median of {m['repeats']} warm frames after {m['warmup']} warm-up frames.
Error: pixels valid in the Cycles reference and with geometry in ours; mismatch = |Δ| &gt; {m['threshold']}.
{_mode_note(m)}
Interlaced ray tracing: error of the first frame after a change. Bold: on the Pareto front.</p>
<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>
{_warnings_html(m)}<h2>Error against time</h2>
<p><img src="error_vs_time.png" alt="error against time"></p>
<p>Both axes logarithmic. Red: ray tracing, blue: shadow maps, grey: no shadows; ringed in black: on the
Pareto front (dashed); green line: the Cycles reference's time.</p>
<h2>Masks and differences</h2>
{''.join(grids)}
<p><a href="metrics.json">metrics.json</a></p>
</body></html>
"""
