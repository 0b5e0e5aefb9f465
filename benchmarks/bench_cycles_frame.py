"""Our whole frame against Cycles' 1-sample shadowed renders of the same scene and lights,
alternating in one process, same run (a script, not a test).

    .venv/bin/python -m benchmarks.bench_cycles_frame [--scenes forest clusters] [--size 320x180]
        [--alternations 3] [--frames 5] [--peer-settings light_grid=False]

Ours: ``raytrace`` at ``high``, hard lights (as the hard Cycles reference renders them), every
shadowed light; the median ``total_ms`` (G-buffer + shadows + lighting + readback) of ``--frames``
warm frames. The light grids are built up front (``eager``; their build time, once per scene and
light, is printed apart: a viewport or an animation pays it once). Cycles: the compare tool's reference recipe
(``blender/cycles_reference.py``: one
light at a time, 1 sample at the pixel centre, ``max_bounces`` 0), each light rendered with its
shadow and without; the shadowed renders' time is half of each light's pair (the two renders of a
pair cost the same to within a few %), so "Cycles ms" is the sum over the lights of half their
pair. ``--peer-settings``: also time our frame with these settings changed (e.g. the tree
instead of the light grids), same run. Ratios are Cycles ms / ours per alternation, then their
median.
"""
from __future__ import annotations

import argparse
import statistics
import sys
from dataclasses import replace


def _value(text: str):
    return {"True": True, "False": False}.get(text, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["forest", "clusters"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--alternations", type=int, default=3)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--peer-settings", nargs="*", default=["light_grid=False"])
    a = ap.parse_args(argv)
    from hybrid_shadow_addon.__main__ import blender_output_to_stderr
    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.frames import current_scene
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    w, h = (int(v) for v in a.size.split("x"))
    ours_settings = Settings(mode="raytrace", quality="high", hard=True)
    peer = dict(kv.split("=", 1) for kv in a.peer_settings)
    peer_settings = ours_settings.replace(**{k: _value(v) for k, v in peer.items()}) if peer else None
    pipe = Pipeline()
    rt = pipe.shadow_pass("raytrace")
    rt.options = replace(rt.options, eager_light_grids=True)
    grids = rt.light_grids
    print(f"## frame against Cycles' 1-sample shadowed renders, {w}x{h}, same run\n")
    head = "| scene | lights | grids' build ms (once) | Cycles ms | ours ms | Cycles / ours |"
    if peer_settings is not None:
        head += f" ours with {', '.join(a.peer_settings)} ms | Cycles / that |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for spec in a.scenes:
        with blender_output_to_stderr():
            bscene = open_scene(spec)
            scene = current_scene(resolution=(w, h))
        pipe.set_scene(scene)
        pipe.render(scene, ours_settings, w, h)
        build_ms = grids.build_ms

        def frame(settings):
            pipe.render(scene, settings, w, h)
            pipe.render(scene, settings, w, h)
            return statistics.median(pipe.render(scene, settings, w, h).timings["total_ms"] for _ in range(a.frames))

        rows = []
        for _ in range(a.alternations):
            with blender_output_to_stderr():
                ref = render_reference(bscene, resolution=(w, h), samples=1, hard=True)
            cyc = sum(ref.render_ms.values()) / 2.0
            ours = frame(ours_settings)
            other = frame(peer_settings) if peer_settings is not None else None
            rows.append((cyc, ours, other))
        cyc = statistics.median(r[0] for r in rows)
        ours = statistics.median(r[1] for r in rows)
        ratio = statistics.median(r[0] / r[1] for r in rows)
        line = f"| {spec} | {len(ref.render_ms)} | {build_ms:.0f} | {cyc:.0f} | {ours:.1f} | **{ratio:.1f}x** |"
        if peer_settings is not None:
            other = statistics.median(r[2] for r in rows)
            line += f" {other:.1f} | {statistics.median(r[0] / r[2] for r in rows):.1f}x |"
        print(line, flush=True)
    pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
