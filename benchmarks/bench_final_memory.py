"""GPU memory of a final render: held before it, at its peak and after it, in this tree's
final-render process and, with ``--peer DIR``, in another tree's pipeline (an earlier commit
checked out there) whose context is counted the same way (this tree's ``core/gpu/memory.py``
wraps its allocations), in the same run.

    .venv/bin/python benchmarks/bench_final_memory.py [--scene forest] [--size 3840x2160]
        [--samples 4] [--peer DIR] [--json OUT]

Lights as the scene has them, soft (``hard=False``), ``samples`` rays per pixel (memory does not
depend on it). "after" is what stays once the frame is written: the peer keeps its pipeline,
its targets and its bake for the session.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

MB = float(1 << 20)

_PEER = """
import importlib.util, json, sys, time
sys.path.insert(0, {peer!r})
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
    from hybrid_shadow_addon.core.gpu.remote import FinalRenderer
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
    code = _PEER.format(peer=str(Path(peer_dir).resolve()), memory=str(REPO / "hybrid_shadow_addon/core/gpu/memory.py"),
                        scene=scene_arg, samples=samples, w=w, h=h, MB=MB)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=peer_dir)
    if p.returncode != 0:
        raise SystemExit(p.stderr[-3000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="forest")
    ap.add_argument("--size", default="3840x2160")
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--peer", help="another tree (an earlier commit checked out) measured the same way")
    ap.add_argument("--json", dest="json_out")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
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
