"""The outputs of ``compare`` from its metrics dict: the error-against-time plot, the text
table the CLI prints and the HTML report."""
from __future__ import annotations

import html
import json
from pathlib import Path


#: the error axis of the plot is logarithmic: mismatches below this (% of pixels) sit on it
ERROR_FLOOR_PCT = 1e-3


def write_report(m: dict, out) -> None:
    """``error_vs_time.png``, ``metrics.json`` and ``report.html`` into the folder ``out``."""
    out = Path(out)
    plot_error_vs_time(m, out / "error_vs_time.png")
    (out / "metrics.json").write_text(json.dumps(m, indent=2) + "\n")
    (out / "report.html").write_text(report_html(m))


def plot_error_vs_time(m: dict, path) -> None:
    import matplotlib.ticker
    from matplotlib.figure import Figure  # no pyplot: no global backend (safe inside Blender)

    rows = m["variants"]
    fig = Figure(figsize=(8, 5), dpi=110)
    ax = fig.subplots()
    colours = {"raytrace": "tab:red", "shadowmap": "tab:blue", "none": "tab:gray"}
    floor = ERROR_FLOOR_PCT  # (log axis: a variant without error is drawn on the floor)
    for i, r in enumerate(sorted(rows, key=lambda r: r["total_ms"])):
        t, e = r["total_ms"], max(r["overall"]["mismatch_pct"], floor)
        ax.scatter([t], [e], s=46, color=colours.get(r["settings"]["mode"], "k"), zorder=3,
                   edgecolors="k" if r.get("pareto") else "none", linewidths=1.2)
        ax.annotate(r["label"], (t, e), textcoords="offset points", xytext=(6, 4 if i % 2 == 0 else -11), fontsize=8)
    front = sorted((r for r in rows if r.get("pareto")), key=lambda r: r["total_ms"])
    if len(front) > 1:
        xs = [r["total_ms"] for r in front]
        ys = [max(r["overall"]["mismatch_pct"], floor) for r in front]
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
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_ylabel(f"mismatch, % of valid pixels (|Δ| > {m['threshold']}; log, floor {floor:g})")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"{m['scene']} {m['resolution'][0]}x{m['resolution'][1]}: shadow error against run time")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def table_rows(m: dict) -> list:
    """(name, shadow ms, total ms, mismatch %, missed %, false %, MAE) per variant."""
    return [(r["label"], r["shadow_ms"], r["total_ms"], r["overall"]["mismatch_pct"], r["overall"]["missed_pct"],
             r["overall"]["false_pct"], r["overall"]["mae"]) for r in m["variants"]]


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
