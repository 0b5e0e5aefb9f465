"""Shadow-ray traversal benchmark: a peer tree's ``render`` against this tree's, per structure.

Each run is the CLI (``python -m hybrid_shadow_addon render SCENE --mode raytrace --quality high
--resolution 640x360 --stats ... --masks-dir ...``) in a subprocess: the peer's with cwd = the peer
tree, ours once per ``--structure``. Runs are interleaved (peer, grid, bvh, peer, ...) and repeated;
the table shows median shadow ms (the ray pass, shader compilation included, as the CLI reports
it), the ratio peer / ours, and how many mask pixels equal the peer's (NaN = NaN).

    .venv/bin/python -m benchmarks.bench_traversal [--peer /tmp/peer12] [--repeats 3]
        [--scenes forest clusters city scaling:triangles=1000000,instances=1000]
        [--structures grid bvh] [--markdown out.md]
"""
from __future__ import annotations

import argparse
import functools
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENES = ["forest", "clusters", "city", "scaling:triangles=1000000,instances=1000"]


def run(cwd: Path, scene: str, out: Path, structure: str | None, resolution: str, quality: str) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "hybrid_shadow_addon", "render", scene, "--mode", "raytrace",
           "--quality", quality, "--resolution", resolution, "--output", str(out / "image.npy"),
           "--stats", str(out / "stats.json"), "--masks-dir", str(out / "masks")]
    if structure is not None:
        cmd += ["--structure", structure]
    if _has_hard(cwd):  # hard lights: the same rays as a peer from before soft shadows
        cmd += ["--hard"]
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} (cwd {cwd}) failed:\n{p.stderr[-2000:]}")
    return json.loads((out / "stats.json").read_text())


@functools.cache
def _has_hard(cwd: Path) -> bool:
    """Whether the tree's ``render`` knows ``--hard`` (a tree from before soft shadows is hard)."""
    p = subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", "render", "--help"], cwd=cwd,
                       capture_output=True, text=True)
    return "--hard" in p.stdout


def masks(folder: Path) -> dict:
    return {f.name: np.load(f) for f in sorted((folder / "masks").glob("*.npy"))}


def agreement(a: dict, b: dict) -> float:
    eq = n = 0
    for name, m in a.items():
        o = b.get(name)
        if o is None or o.shape != m.shape:
            return float("nan")
        same = (m == o) | (np.isnan(m) & np.isnan(o))
        eq += int(same.sum())
        n += same.size
    return 100.0 * eq / max(n, 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--peer", default="/tmp/peer12", help="the tree to compare against (its CLI, cwd)")
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--structures", nargs="+", default=["grid", "bvh"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resolution", default="640x360")
    ap.add_argument("--quality", default="high")
    ap.add_argument("--masks-dir", default=None, help="keep the runs' outputs here (default: a temp folder)")
    ap.add_argument("--markdown", default=None, help="also write the table as Markdown here")
    args = ap.parse_args()
    peer = Path(args.peer)
    root = Path(args.masks_dir) if args.masks_dir else Path(tempfile.mkdtemp(prefix="bench_traversal_"))
    variants = [("peer", peer, None)] + [(s, REPO, s) for s in args.structures]
    rows = []
    for scene in args.scenes:
        tag = scene.replace(":", "_").replace(",", "_").replace("=", "")
        ms = {v[0]: [] for v in variants}
        for r in range(args.repeats):
            for name, cwd, structure in variants:
                st = run(cwd, scene, root / tag / name, structure, args.resolution, args.quality)
                ms[name].append(float(st["shadow_ms"]))
                print(f"  {scene} {name} run {r + 1}: shadow {st['shadow_ms']:.0f} ms", flush=True)
        ref = masks(root / tag / "peer")
        peer_ms = float(np.median(ms["peer"]))
        for name, _, _ in variants:
            med = float(np.median(ms[name]))
            agree = 100.0 if name == "peer" else agreement(ref, masks(root / tag / name))
            rows.append((scene, name, med, peer_ms / med, agree, ms[name]))
    head = "| scene | tree | shadow ms (median) | peer / this | masks equal to peer | runs |"
    lines = [head, "|---|---|---:|---:|---:|---|"]
    for scene, name, med, ratio, agree, runs in rows:
        lines.append(f"| {scene} | {name} | {med:.0f} | {ratio:.2f}x | {agree:.4f}% | "
                     f"{', '.join(f'{x:.0f}' for x in runs)} |")
    table = "\n".join(lines)
    print(table)
    if args.markdown:
        Path(args.markdown).write_text(table + "\n")
    print(f"outputs in {root}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
