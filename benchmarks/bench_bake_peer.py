"""Bake and incremental-update time against a peer tree, same run.

Each scene is pickled once (a core ``Scene``), then this tree and the peer tree (a checked-out
commit) bake it in alternating subprocesses: ``--repeat`` full bakes (after one warm-up) and
``--repeat`` moves of 1 % of the instances (the same instances and offsets in both trees), each
timed alone. Printed per scene: the median full bake and update of each tree, this tree's over
the peer's, and whether the two trees' textures are byte for byte equal (a SHA-1 of every
texture's data).

Scenes: ``synthetic`` (``bench_bake.py``'s 100 models x 10k triangles x 1000 instances: 1M unique
triangles, 100k instances), ``forest``, ``clusters``, ``city``... (``load_scene`` specs, where
Blender is), or a pickled core scene (``NAME.pkl.gz``, ``tools/pickle_scenes.py``).

    rm -rf /tmp/peer && mkdir /tmp/peer && git archive <commit> | tar -x -C /tmp/peer
    .venv/bin/python -m benchmarks.bench_bake_peer --peer /tmp/peer [--scenes forest synthetic]
        [--repeat 5] [--alternations 2]
"""
from __future__ import annotations

import argparse
import gzip
import json
import pickle
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks.trees import run_in_tree

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import gzip, hashlib, json, pickle, sys, time
import numpy as np
from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
with gzip.open(sys.argv[1], "rb") as fh:
    scene = pickle.load(fh)
repeat = int(sys.argv[2])
cfg = BakeConfig()
baked = bake_scene(scene, cfg)
h = hashlib.sha1()
for name in sorted(baked.textures):
    h.update(name.encode()); h.update(np.ascontiguousarray(baked.textures[name].data).tobytes())
full = []
for _ in range(repeat):
    t = time.perf_counter(); baked = bake_scene(scene, cfg); full.append((time.perf_counter() - t) * 1e3)
rng = np.random.default_rng(5)
n = len(scene.instances)
k = max(1, n // 100)
moves = []
for _ in range(repeat):
    idx = rng.choice(n, k, replace=False)
    M = scene.instances.matrices[idx].copy()
    M[:, :3, 3] += rng.normal(scale=0.05, size=(k, 3)) * max(1.0, float(np.abs(M[:, :3, 3]).max()) * 0.01)
    scene.instances.set_matrices(idx, M)
    t = time.perf_counter(); baked.update_instances(scene, idx); moves.append((time.perf_counter() - t) * 1e3)
print("HS_BAKE " + json.dumps({"full": full, "move": moves, "digest": h.hexdigest()[:12]}), flush=True)
"""


def scene_file(spec: str, tmp: Path) -> Path:
    """A pickled core scene for ``spec`` (written once into ``tmp``)."""
    if spec.endswith(".pkl.gz"):
        return Path(spec)
    if spec == "synthetic":
        from benchmarks.bench_bake import make_scene

        scene, _ = make_scene(100, 10000, 1000)
    else:
        from hybrid_shadow_addon.blender.load import load_scene

        scene = load_scene(spec)
    out = tmp / f"{spec.replace('/', '_').replace(':', '_')}.pkl.gz"
    with gzip.open(out, "wb", compresslevel=1) as fh:
        pickle.dump(scene, fh)
    return out


def measure(tree: Path, path: Path, repeat: int) -> dict:
    out = run_in_tree(tree, ["-c", CHILD, path, repeat])
    if out.returncode != 0:
        raise SystemExit(f"{tree}: {path.name} failed:\n{out.stderr[-3000:]}")
    line = [x for x in out.stdout.splitlines() if x.startswith("HS_BAKE ")][-1]
    return json.loads(line[len("HS_BAKE "):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True, type=Path, help="the peer tree (a checked-out commit)")
    ap.add_argument("--scenes", nargs="+", default=["forest", "synthetic"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--alternations", type=int, default=2)
    a = ap.parse_args(argv)
    if not (a.peer / "hybrid_shadow_addon").is_dir():
        raise SystemExit(f"--peer {a.peer}: not a tree of this project (no hybrid_shadow_addon/)")
    trees = {"peer": a.peer.resolve(), "this": REPO}
    print(f"peer: {trees['peer']}; {a.repeat} bakes and moves of 1 % per run, {a.alternations} alternations")
    print("| scene | peer bake ms | this bake ms | this / peer | peer move ms | this move ms | this / peer "
          "| textures |\n|---|---:|---:|---:|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory(prefix="hs-bake-peer-") as tmp:
        for spec in a.scenes:
            path = scene_file(spec, Path(tmp))
            got = {k: [] for k in trees}
            for _ in range(a.alternations):
                for k, tree in trees.items():
                    got[k].append(measure(tree, path, a.repeat))
            full = {k: statistics.median(x for r in got[k] for x in r["full"]) for k in trees}
            move = {k: statistics.median(x for r in got[k] for x in r["move"]) for k in trees}
            same = "equal" if got["peer"][0]["digest"] == got["this"][0]["digest"] else "differ"
            name = Path(spec).name.replace(".pkl.gz", "")
            print(f"| {name} | {full['peer']:.1f} | {full['this']:.1f} | {full['this'] / full['peer']:.2f}x | "
                  f"{move['peer']:.2f} | {move['this']:.2f} | {move['this'] / move['peer']:.2f}x | {same} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
