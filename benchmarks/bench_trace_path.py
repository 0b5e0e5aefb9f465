"""The trace paths (``Settings.trace_path``) against each other and against a peer tree, same
run: the shadow pass's ms per configuration and scene, and digests of the masks.

Three subjects alternate, each a subprocess with its own ``Pipeline`` that loads the scene once
and renders every configuration: the peer tree as it is (a checked-out commit, e.g. the tree
before the compute path), this tree on the compute path and this tree on the fragment path.
Each configuration renders ``--frames`` frames; the first two (compiles, first uploads, a light
grid's build) are dropped and the median of the rest is taken; the table gives the median over
``--alternations`` and the ratios. The last frame's masks are digested (SHA-1 of the float32
masks, -0 taken as 0: a light the fragment path leaves out as reaching no pixel gets +0 where
its trace writes -0, as the compute path's does): equal digests are equal masks.

Configurations (hard lights, as the hard Cycles references; mode ``raytrace``):

- ``high cold``: quality high, no light grids (the tree: the first frames after a change, lights
  that move, alpha-cut casters);
- ``high grids``: quality high, each hard light's grid built at first sight (a viewport's steady
  state);
- ``medium``, ``low``: the refinement's qualities, no light grids; their ratio to ``high cold``
  of the same subject is printed too.

- ``viewport``: the viewport's frames (``Pipeline.timing`` ``"frame"``: no wait between passes, the
  rays uncounted) at high with light grids and reuse, the camera moving a little every frame;
  its ms are the frames' total, and ``waits`` / ``read_back`` the most waits and bytes read back
  beyond the RGBA32F image of one of its timed frames (the tree before: not counted).

``--layouts`` adds this tree on both paths with its single rays walking 4-wide nodes and binary
nodes (``BVHConfig.wide`` True and False; "compute" and "fragment" take the context's
default: binary on a software rasteriser), as four more subjects.

``--soft`` adds ``soft lanes`` and ``soft packets``: lights with their sizes at high, 64 samples,
on the compute path a pixel's samples spread over lanes (a GPU's default) or walking the scene as
packets (a software rasteriser's default; ``RaytraceOptions.soft_lanes``); the peer and the
fragment path take no such choice, so they run the same work twice.

    rm -rf /tmp/peer && mkdir /tmp/peer && git archive <commit> | tar -x -C /tmp/peer
    .venv/bin/python -m benchmarks.bench_trace_path --peer /tmp/peer [--scenes forest clusters city]
        [--size 640x360] [--frames 5] [--alternations 2] [--soft] [--json OUT]

A scene may be a core ``Scene`` pickled with gzip (``NAME.pkl.gz``, an absolute path; see
``tools/pickle_scenes.py``), for a machine without Blender.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from benchmarks.trees import run_in_tree

REPO = Path(__file__).resolve().parents[1]

CONFIGS = {
    "high cold": ({"quality": "high", "light_grid": False}, False),
    "high grids": ({"quality": "high", "light_grid": True}, True),
    "medium": ({"quality": "medium", "light_grid": False}, False),
    "low": ({"quality": "low", "light_grid": False}, False),
    "viewport": ({"quality": "high", "light_grid": True, "viewport": True}, False),
}
SOFT = {f"soft {k}": ({"quality": "high", "hard": False, "samples": 64, "light_grid": False, "soft_lanes": v}, False)
        for k, v in (("lanes", True), ("packets", False))}

CHILD = r"""
import dataclasses, hashlib, json, statistics, sys
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
scene_arg, size, frames, path = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
configs = json.loads(sys.argv[5])
path, _, layout = path.partition(" ")
W, H = (int(v) for v in size.split("x"))
if scene_arg.endswith(".pkl.gz"):
    import gzip, pickle
    with gzip.open(scene_arg, "rb") as fh:
        scene = pickle.load(fh)
else:
    from hybrid_shadow_addon.blender.load import load_scene
    scene = load_scene(scene_arg)
known = {f.name for f in dataclasses.fields(Settings)}
out = {}
for name, (kw, eager) in configs.items():
    pipe = Pipeline()
    if layout:
        pipe.bake_options["bvh"] = {"wide": layout == "wide"}
    pipe.set_scene(scene)
    rt = pipe.shadow_pass("raytrace")
    rt.options = dataclasses.replace(rt.options, eager_light_grids=eager)
    kw = dict(kw, mode="raytrace", hard=kw.get("hard", True))
    viewport = kw.pop("viewport", False)
    lanes = kw.pop("soft_lanes", None)
    if lanes is not None and hasattr(rt.options, "soft_lanes"):
        rt.options = dataclasses.replace(rt.options, soft_lanes=lanes)
    if viewport:
        pipe.timing, pipe.reuse = "frame", True
    if path != "peer":
        kw["trace_path"] = path
    settings = Settings(**{k: v for k, v in kw.items() if k in known})
    ms, counts, frame = [], [], None
    for i in range(frames):
        seen = scene
        if viewport:  # (a camera move: 1 cm a frame)
            cam = dataclasses.replace(scene.camera, matrix=scene.camera.matrix.copy())
            cam.matrix[0, 3] += 0.01 * i
            seen = dataclasses.replace(scene, camera=cam)
        frame = pipe.render(seen, settings, W, H)
        ms.append(frame.timings["total_ms" if viewport else "shadow_ms"])
        counts.append((frame.stats.get("waits"), frame.stats.get("bytes_read_back")))
    h = hashlib.sha1()
    for li in frame.lights:
        h.update((frame.mask_array(li).astype("float32") + 0.0).tobytes())  # (-0 and 0 as one)
    timed = [c for c in counts[2:] if c[0] is not None]
    out[name] = {"shadow_ms": statistics.median(ms[2:]), "digest": h.hexdigest()[:12],
                 "rays_traced": frame.stats.get("rays_traced", 0),
                 "waits": max((c[0] for c in timed), default=None),
                 "read_back": max((c[1] - W * H * 16 for c in timed), default=None)}
    pipe.release()
print("HS_PATHS " + json.dumps(out), flush=True)
"""


def measure(tree: Path, scene: str, size: str, frames: int, path: str, configs: dict) -> dict:
    out = run_in_tree(tree, ["-c", CHILD, scene, size, frames, path, json.dumps(configs)])
    if out.returncode != 0:
        raise SystemExit(f"{tree} ({path}): {scene} failed:\n{out.stderr[-3000:]}")
    line = [x for x in out.stdout.splitlines() if x.startswith("HS_PATHS ")][-1]
    return json.loads(line[len("HS_PATHS "):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True, type=Path, help="the peer tree (a checked-out commit)")
    ap.add_argument("--scenes", nargs="+", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--alternations", type=int, default=2)
    ap.add_argument("--soft", action="store_true", help="add soft lights at high (64 samples)")
    ap.add_argument("--layouts", action="store_true",
                    help="also this tree with its single rays on 4-wide and on binary nodes (BVHConfig.wide)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--configs", nargs="+", default=None, help=f"a subset of {list(CONFIGS)} (and soft)")
    a = ap.parse_args(argv)
    if not (a.peer / "hybrid_shadow_addon").is_dir():
        raise SystemExit(f"--peer {a.peer}: not a tree of this project (no hybrid_shadow_addon/)")
    configs = {**CONFIGS, **(SOFT if a.soft else {})}
    if a.configs:
        configs = {k: v for k, v in configs.items() if k in a.configs}
    subjects = {"peer": a.peer.resolve(), "compute": REPO, "fragment": REPO}
    if a.layouts:
        subjects.update({f"{p} {k}": REPO for k in ("wide", "binary") for p in ("compute", "fragment")})
    print(f"{a.size}, {a.frames} frames (first 2 dropped), {a.alternations} alternations; "
          f"peer: {subjects['peer']}")
    more = [k for k in subjects if " " in k]
    print("| scene | configuration | peer ms | compute ms | fragment ms | peer / compute | fragment / compute "
          + "".join(f"| {k} ms | peer / {k} " for k in more) + "| masks |\n|---|---|---:|---:|---:|---:|---:|"
          + "---:|---:|" * len(more) + "---|")
    record = {}
    for scene in a.scenes:
        got = {k: [] for k in subjects}
        for _ in range(a.alternations):
            for name, tree in subjects.items():
                got[name].append(measure(tree, scene, a.size, a.frames, name, configs))
        rows = record[scene] = {}
        for c in configs:
            ms = {k: statistics.median(r[c]["shadow_ms"] for r in got[k]) for k in subjects}
            digests = {k: got[k][-1][c]["digest"] for k in subjects}
            extra = "".join(f"| {ms[k]:.1f} | {ms['peer'] / ms[k]:.2f}x " for k in more)
            same = ("all equal" if len(set(digests.values())) == 1 else
                    "compute = fragment" if digests["compute"] == digests["fragment"] else
                    "compute = peer" if digests["compute"] == digests["peer"] else "all differ")
            rows[c] = dict(ms=ms, digests=digests, rays={k: got[k][-1][c]["rays_traced"] for k in subjects},
                           counts={k: (got[k][-1][c].get("waits"), got[k][-1][c].get("read_back")) for k in subjects})
            print(f"| {scene} | {c} | {ms['peer']:.1f} | {ms['compute']:.1f} | {ms['fragment']:.1f} | "
                  f"{ms['peer'] / ms['compute']:.2f}x | {ms['fragment'] / ms['compute']:.2f}x {extra}| {same} |",
                  flush=True)
    if "viewport" in configs:
        print("\nviewport frames, the most of one (waits; bytes read back beyond the image):")
        print("| scene | compute | fragment |\n|---|---|---|")
    for scene, rows in record.items():
        if "viewport" not in rows:
            continue
        c = rows["viewport"]["counts"]
        print(f"| {scene} | {c['compute'][0]}; {c['compute'][1]} | {c['fragment'][0]}; {c['fragment'][1]} |")
    print("\nof high cold's shadow ms, same subject (medium, low):")
    print("| scene | subject | medium | low |\n|---|---|---:|---:|")
    for scene, rows in record.items():
        if not {"high cold", "medium", "low"} <= set(rows):
            continue
        for k in subjects:
            hi = rows["high cold"]["ms"][k]
            print(f"| {scene} | {k} | {rows['medium']['ms'][k] / hi:.2f} | {rows['low']['ms'][k] / hi:.2f} |")
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
