"""A whole frame's passes against a peer tree, same run: G-buffer, shadows, lighting and the
frame, per scene, alternating the two trees.

Each measurement is a subprocess in one tree (its own ``Pipeline``) rendering the scene
``--frames`` times (the first two are dropped: program compilation and first uploads) and
reporting the median of each pass. Trees alternate (peer, this, peer, this, ...)
``--alternations`` times, so both see the same machine load; the table gives the median over
the alternations and ``peer / this``.

    rm -rf /tmp/framepeer && mkdir /tmp/framepeer && git archive <commit> | tar -x -C /tmp/framepeer
    .venv/bin/python -m benchmarks.bench_frame --peer /tmp/framepeer [--scenes forest clusters city]
        [--size 320x180] [--soft] [--frames 7] [--alternations 2]

A scene may also be a core ``Scene`` pickled with gzip (``NAME.pkl.gz``, an absolute path), for a
machine without Blender: ``tools/pickle_scenes.py`` writes them.

Lights are hard (as the hard Cycles reference renders them) unless ``--soft``; mode ``raytrace``,
quality ``high``. ``--mode shadowmap`` or ``none`` measures those instead. ``--interlace``: the
shadow pass with interlacing, the first frame after a change and a still view.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from benchmarks.trees import run_in_tree

REPO = Path(__file__).resolve().parents[1]
PASSES = ("gbuffer_ms", "shadow_ms", "lighting_ms", "total_ms")

CHILD = r"""
import json, statistics, sys
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
scene_arg, size, soft, mode, frames = sys.argv[1], sys.argv[2], sys.argv[3] == "1", sys.argv[4], int(sys.argv[5])
interlace = sys.argv[6] == "1"
W, H = (int(v) for v in size.split("x"))
if scene_arg.endswith(".pkl.gz"):  # a core Scene pickled where Blender is (a machine without bpy)
    import gzip, pickle
    with gzip.open(scene_arg, "rb") as fh:
        scene = pickle.load(fh)
else:
    from hybrid_shadow_addon.blender.load import load_scene
    scene = load_scene(scene_arg)
pipe = Pipeline()
pipe.set_scene(scene)
settings = Settings(mode=mode, quality="high", hard=not soft)
if interlace:  # the first frame after a change and a still view (frames 5 on), for this many changes
    inter = Settings(mode=mode, quality="high", hard=not soft, interlace=True)
    for _ in range(2):
        pipe.render(scene, inter, W, H)
    first, still = [], []
    for _ in range(max(1, frames - 2)):
        pipe.reset_history()
        first.append(pipe.render(scene, inter, W, H).timings["shadow_ms"])
        for k in range(7):
            t = pipe.render(scene, inter, W, H).timings["shadow_ms"]
            if k >= 3:
                still.append(t)
    out = {"first_ms": statistics.median(first), "still_ms": statistics.median(still)}
else:
    rows = [pipe.render(scene, settings, W, H).timings for _ in range(frames)][2:]
    out = {k: statistics.median(r.get(k, 0.0) for r in rows) for k in PASSES_TUPLE}
print("HS_FRAME " + json.dumps(out), flush=True)
""".replace("PASSES_TUPLE", repr(PASSES))


def measure(tree: Path, scene: str, size: str, soft: bool, mode: str, frames: int, interlace: bool = False) -> dict:
    out = run_in_tree(tree, ["-c", CHILD, scene, size, "1" if soft else "0", mode, frames, "1" if interlace else "0"])
    if out.returncode != 0:
        raise SystemExit(f"{tree}: {scene} failed:\n{out.stderr[-2000:]}")
    line = [x for x in out.stdout.splitlines() if x.startswith("HS_FRAME ")][-1]
    return json.loads(line[len("HS_FRAME "):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True, type=Path, help="the other tree (a checked-out commit)")
    ap.add_argument("--scenes", nargs="+", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--soft", action="store_true", help="lights with their sizes (default: hard)")
    ap.add_argument("--mode", default="raytrace", choices=("raytrace", "shadowmap", "none"))
    ap.add_argument("--frames", type=int, default=7)
    ap.add_argument("--alternations", type=int, default=2)
    ap.add_argument("--interlace", action="store_true",
                    help="interlacing's shadow ms instead: the first frame after a change, and a still view "
                         "(frames 5-8 after it); --frames - 2 changes")
    a = ap.parse_args(argv)
    if not (a.peer / "hybrid_shadow_addon").is_dir():
        raise SystemExit(f"--peer {a.peer}: not a tree of this project (no hybrid_shadow_addon/)")
    trees = {"peer": a.peer.resolve(), "this": REPO}
    print("| scene | pass | peer ms | this ms | peer / this |\n|---|---|---:|---:|---:|")
    for scene in a.scenes:
        got = {k: [] for k in trees}
        for _ in range(a.alternations):
            for name, tree in trees.items():
                got[name].append(measure(tree, scene, a.size, a.soft, a.mode, a.frames, a.interlace))
        for p in (("first_ms", "still_ms") if a.interlace else PASSES):
            peer = statistics.median(r[p] for r in got["peer"])
            this = statistics.median(r[p] for r in got["this"])
            ratio = f"{peer / this:.2f}x" if this > 0 else "-"
            label = {"first_ms": "interlaced shadows, first frame after a change",
                     "still_ms": "interlaced shadows, a still view"}.get(
                p, p.replace("_ms", "").replace("total", "frame"))
            print(f"| {scene} | {label} | {peer:.1f} | {this:.1f} | {ratio} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
