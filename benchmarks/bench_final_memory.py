"""GPU memory of a final render: held before it, at its peak and after it, in this tree's
final-render process and, with ``--peer DIR``, in another tree's pipeline (an earlier commit
checked out there) whose context is counted the same way (this tree's ``core/gpu/memory.py``
wraps its allocations), in the same run.

    .venv/bin/python -m benchmarks.bench_final_memory [--scene forest] [--size 3840x2160]
        [--samples 4] [--peer DIR] [--json OUT] [--renders N]

With ``--renders N`` it measures instead of counting: N final renders of the scene in one
renderer process (as N F12 renders in one Blender session), and after each the process's resident
memory (``/proc``) and the driver's figure of video memory where it has one, for this tree and the
peer, each in the same way.

Lights as the scene has them, soft (``hard=False``), ``samples`` rays per pixel (memory does not
depend on it). "after" is what stays once the frame is written: the peer keeps its pipeline,
its targets and its bake for the session.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from benchmarks.trees import run_in_tree

REPO = Path(__file__).resolve().parents[1]

MB = float(1 << 20)

_PEER = """
import importlib.util, json, sys, time
spec = importlib.util.spec_from_file_location("hs_memory", {memory!r})
memory = importlib.util.module_from_spec(spec); spec.loader.exec_module(memory)
from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.context import create_context
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
scene = load_scene({scene!r})
ctx = create_context()
ledger = memory.track(ctx)
pipe = Pipeline(ctx)
t0 = time.perf_counter()
pipe.render(scene, Settings(samples={samples}), {w}, {h})
print(json.dumps({{"before_mb": 0.0, "peak_mb": ledger.peak / {MB}, "after_mb": ledger.bytes / {MB},
                  "seconds": time.perf_counter() - t0}}))
"""


def ours(scene_arg: str, w: int, h: int, samples: int) -> dict:
    from hybrid_shadow_addon.blender.load import load_scene
    from hybrid_shadow_addon.core.runtime.remote import FinalRenderer
    from hybrid_shadow_addon.core.settings import Settings

    scene = load_scene(scene_arg)
    renderer = FinalRenderer()
    try:
        t0 = time.perf_counter()
        data = renderer.render(scene, Settings(samples=samples), w, h, max_draw_ms=100.0,
                               want=("depth", "shading_normal", "albedo"))
        s = data.stats
        return {"before_mb": s["gpu_memory_before_mb"], "peak_mb": s["gpu_peak_mb"],
                "after_mb": s["gpu_memory_after_mb"], "seconds": time.perf_counter() - t0,
                "shadowed_lights": s["shadowed_lights"]}
    finally:
        renderer.close()


def peer(peer_dir: str, scene_arg: str, w: int, h: int, samples: int) -> dict:
    code = _PEER.format(memory=str(REPO / "hybrid_shadow_addon/core/gpu/memory.py"), scene=scene_arg, samples=samples,
                        w=w, h=h, MB=MB)
    p = run_in_tree(peer_dir, ["-c", code])
    if p.returncode != 0:
        raise SystemExit(p.stderr[-3000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


_SERIES = """
import json, sys, time
from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.runtime.remote import FinalRenderer
from hybrid_shadow_addon.core.settings import Settings

def rss(pid):
    with open(f"/proc/{{pid}}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0

scene = load_scene({scene!r})
renderer = FinalRenderer()
out = []
try:
    for _ in range({n}):
        data = renderer.render(scene, Settings(samples={samples}), {w}, {h}, max_draw_ms=100.0, want=("depth",))
        time.sleep(0.3)  # (the renderer trims its heap once the frame is sent)
        out.append({{"rss_mb": rss(renderer.pid), "driver_mb": data.stats.get("gpu_driver_used_mb"),
                     "dropped": data.stats.get("gpu_dropped")}})
finally:
    renderer.close()
print(json.dumps(out))
"""


def series(tree: Path, scene_arg: str, w: int, h: int, samples: int, n: int) -> list:
    """``n`` final renders in one renderer process of ``tree``: after each, the process's RSS,
    the driver's used video memory (None where it reports none) and the objects dropped."""
    code = _SERIES.format(scene=scene_arg, samples=samples, w=w, h=h, n=n)
    p = run_in_tree(tree, ["-c", code])
    if p.returncode != 0:
        raise SystemExit(p.stderr[-3000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


def main_series(args, w: int, h: int) -> dict:
    trees = {"this tree": REPO}
    if args.peer:
        trees["peer"] = Path(args.peer)
    cases = {name: series(tree, args.scene, w, h, args.samples, args.renders) for name, tree in trees.items()}
    print(f"{args.scene} {w}x{h}, soft, {args.samples} samples, {args.renders} final renders in one process")
    print(f"{'tree':<10} {'RSS 1st MB':>11} {'RSS max MB':>11} {'RSS last MB':>12} {'max/1st':>8} {'driver MB':>10}")
    for name, runs in cases.items():
        rss = [r["rss_mb"] for r in runs]
        drv = [r["driver_mb"] for r in runs if r["driver_mb"] is not None]
        dtext = f"{drv[0]:.0f}->{max(drv):.0f}" if drv else "none"
        print(f"{name:<10} {rss[0]:>11.1f} {max(rss[1:] or rss):>11.1f} {rss[-1]:>12.1f} "
              f"{max(rss[1:] or rss) / rss[0]:>8.3f} {dtext:>10}")
    out = {"scene": args.scene, "size": [w, h], "samples": args.samples, "renders": args.renders, "series": cases}
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="forest")
    ap.add_argument("--size", default="3840x2160")
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--peer", help="another tree (an earlier commit checked out) measured the same way")
    ap.add_argument("--json", dest="json_out")
    ap.add_argument("--renders", type=int, default=0, help="measure the process over this many renders")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    if args.renders:
        return main_series(args, w, h)
    cases = {"this tree": ours(args.scene, w, h, args.samples)}
    if args.peer:
        cases["peer"] = peer(args.peer, args.scene, w, h, args.samples)
    print(f"{args.scene} {w}x{h}, soft, {args.samples} samples")
    print(f"{'tree':<10} {'before MB':>10} {'peak MB':>10} {'after MB':>10} {'seconds':>8}")
    for name, c in cases.items():
        print(f"{name:<10} {c['before_mb']:>10.1f} {c['peak_mb']:>10.1f} {c['after_mb']:>10.1f} {c['seconds']:>8.1f}")
    out = {"scene": args.scene, "size": [w, h], "samples": args.samples, "cases": cases}
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
