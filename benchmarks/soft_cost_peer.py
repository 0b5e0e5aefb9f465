"""Soft-shadow cost against a peer tree, same run: shadow ms of the default soft render and of
``--hard``, alternating the two trees.

Each measurement is a subprocess in one tree (its own ``Pipeline``) rendering the scene hard and
soft in turn, 4 times each (the first of each is dropped: program compilation), and reporting the
medians. Trees alternate (peer, this, peer, this, ...) ``--alternations`` times, so both see the
same machine load.

    rm -rf /tmp/softpeer && mkdir /tmp/softpeer && git archive <commit> | tar -x -C /tmp/softpeer
    .venv/bin/python -m benchmarks.soft_cost_peer --peer /tmp/softpeer [--scenes soft soft_lights:width=320,height=240]
        [--size 320x240] [--samples 32] [--alternations 3] [--viewport]

Scene ``soft`` is the test suite's hand-made scene (``soft_scene`` in ``tests/helpers/scenes.py``). With
``--viewport`` the soft column is the viewport's first frame after a change (``Settings.accumulate``
after ``reset_history``) instead of a final render.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from benchmarks.trees import run_in_tree

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, statistics, sys
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
spec, size, samples = sys.argv[1], sys.argv[2], int(sys.argv[3])
W, H = (int(v) for v in size.split("x"))
if spec == "soft":
    try:
        from tests.helpers.scenes import soft_scene
    except ImportError:  # a peer tree without tests/helpers (the working directory: the tree)
        import runpy
        soft_scene = runpy.run_path("tests/test_soft_shadows.py")["soft_scene"]
    scene = soft_scene(); scene.resolution = (W, H)
else:
    from hybrid_shadow_addon.blender.load import load_scene
    scene = load_scene(spec)
viewport = sys.argv[4] == "viewport"
pipe = Pipeline(); ms = {True: [], False: []}
for hard in (True, False) * 4:
    pipe.reset_history()
    s = Settings(mode="raytrace", quality="high", hard=hard, samples=samples)
    if viewport and not hard:  # the viewport's first frame after a change
        s = s.replace(accumulate=True)
    f = pipe.render(scene, s, W, H)
    ms[hard].append(f.timings["shadow_ms"])
print(json.dumps({"hard": statistics.median(ms[True][1:]), "soft": statistics.median(ms[False][1:])}))
"""


def measure(root: Path, spec: str, size: str, samples: int, what: str = "final") -> dict:
    p = run_in_tree(root, ["-c", CHILD, spec, size, samples, what])
    if p.returncode != 0:
        raise RuntimeError(f"{root}: {p.stderr[-2000:]}")
    # (the last JSON line: Blender may print its own lines at exit, e.g. about unfreed memory)
    return json.loads([line for line in p.stdout.splitlines() if line.startswith("{")][-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--peer", required=True, help="the tree to compare against")
    ap.add_argument("--scenes", nargs="+", default=["soft", "soft_lights:width=320,height=240"])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--alternations", type=int, default=3)
    ap.add_argument("--viewport", action="store_true",
                    help="the soft column is the viewport's first frame after a change, not a final render")
    args = ap.parse_args(argv)
    what = "viewport" if args.viewport else "final"
    trees = [("peer", Path(args.peer)), ("this", REPO)]
    soft = "viewport first frame ms" if args.viewport else f"soft ms at {args.samples} samples"
    print(f"| scene | tree | hard ms (runs) | {soft} (runs) | soft / hard | soft ms this / peer |")
    print("|---|---|---|---|---:|---:|")
    for spec in args.scenes:
        got = {name: [] for name, _ in trees}
        for _ in range(args.alternations):
            for name, root in trees:
                got[name].append(measure(root, spec, args.size, args.samples, what))
        med = {}
        for name, _ in trees:
            hard = [r["hard"] for r in got[name]]
            soft = [r["soft"] for r in got[name]]
            med[name] = (statistics.median(hard), statistics.median(soft))
        for name, _ in trees:
            h, s = med[name]
            runs_h = ", ".join(f"{r['hard']:.0f}" for r in got[name])
            runs_s = ", ".join(f"{r['soft']:.0f}" for r in got[name])
            rel = f"{s / med['peer'][1]:.2f}" if name == "this" else "1.00"
            print(f"| {spec} | {name} | {h:.0f} ({runs_h}) | {s:.0f} ({runs_s}) | {s / h:.1f} | {rel} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
