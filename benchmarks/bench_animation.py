"""Animation benchmark: per-frame time of a frame range of a scene's animation (default: 24
frames of forest's camera path, balls rolling) rendered with the persistent bake (bake once,
update between frames: ``render --frames``) against baking every frame (what a frame-by-frame
render did), in the same run and process: two pipelines (programs compiled by a warm-up frame first), frame
by frame interleaved, alternating which goes first, so that load on the machine hits both alike.
Each frame: export from bpy, bake or update, G-buffer, shadows, lighting, PNG write.

    .venv/bin/python -m benchmarks.bench_animation [--scene forest] [--frames 1-24]
        [--resolution 640x360] [--mode raytrace] [--quality high] [--repeats 1] [--json OUT]
"""
import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from hybrid_shadow_addon.__main__ import parse_resolution
from hybrid_shadow_addon.core.scene_sync import sync_scene
from hybrid_shadow_addon.core.settings import Settings
from hybrid_shadow_addon.tools.render import frame_path, frame_stats, parse_frames, render_to_files, write_outputs


def frame_step(source, f, settings, out, pipe, prev, persist):
    """One frame as ``render --frames`` does it (``persist``: update the bake from ``prev``) or
    as a fresh render does (bake in full); returns the stats entry and the exported scene."""
    t0 = time.perf_counter()
    scene = source.scene_at(f)
    export_ms = (time.perf_counter() - t0) * 1e3
    if persist:
        sync = sync_scene(pipe, prev, scene, bake=settings.mode == "raytrace",
                          structure=getattr(settings, "structure", None))
        kind, bake_ms = sync.kind, sync.ms
    else:
        kind = "full" if settings.mode == "raytrace" else "none"
        bake_ms = pipe.set_scene(scene) if kind == "full" else 0.0
    w, h = source.resolution or scene.resolution
    frame = pipe.render(scene, settings, w, h)
    write_outputs(Path(frame_path(str(out / ("p_####.png" if persist else "e_####.png")), f)), scene, frame)
    entry = dict(frame_stats(scene, frame, bake_ms), frame=f, bake=kind, export_ms=export_ms,
                 wall_ms=(time.perf_counter() - t0) * 1e3)
    return entry, scene


def summarise(entries):
    def med(key):
        return statistics.median(e[key] for e in entries)

    passes = ("gbuffer_ms", "shadow_ms", "upsample_ms", "lighting_ms", "readback_ms")
    kinds = {k: sum(e["bake"] == k for e in entries) for k in ("full", "incremental", "none")}
    return {"frames": len(entries), "wall_ms_median": med("wall_ms"),
            "wall_ms_mean": statistics.mean(e["wall_ms"] for e in entries),
            "export_ms_median": med("export_ms"), "bake_ms_median": med("bake_ms"),
            "bake_ms_first": entries[0]["bake_ms"],
            "passes_ms_median": statistics.median(sum(e[p] for p in passes) for e in entries),
            "shadow_ms_median": med("shadow_ms"),
            "besides_shadows_ms_median": statistics.median(e["wall_ms"] - e["shadow_ms"] for e in entries),
            "bakes": kinds}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="forest")
    ap.add_argument("--frames", default="1-24")
    ap.add_argument("--resolution", type=parse_resolution, default=None)
    ap.add_argument("--mode", default="raytrace", choices=("raytrace", "shadowmap", "none"))
    ap.add_argument("--quality", default="high", choices=("low", "medium", "high"))
    ap.add_argument("--repeats", type=int, default=1, help="passes of each variant, alternating (default 1)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    from hybrid_shadow_addon.blender.frames import BlenderFrames
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline

    frames = parse_frames(args.frames)
    settings = Settings(mode=args.mode, quality=args.quality, interlace=False, hard=True)
    t0 = time.perf_counter()
    source = BlenderFrames(open_scene(args.scene), name=args.scene, resolution=args.resolution)
    load_s = time.perf_counter() - t0
    pipes = {"persistent": Pipeline(), "every_frame": Pipeline()}
    runs = {"persistent": [], "every_frame": []}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for pipe in pipes.values():  # compile the programs
            render_to_files(source.scene_at(frames[0]), settings, output=str(out / "warmup.png"), pipeline=pipe)
        for _ in range(args.repeats):
            prev = None
            pipes["persistent"].baked = None
            for k, f in enumerate(frames):  # interleaved, alternating which goes first
                order = ("persistent", "every_frame") if k % 2 == 0 else ("every_frame", "persistent")
                for name in order:
                    entry, scene = frame_step(source, f, settings, out, pipes[name], prev, name == "persistent")
                    runs[name].append(entry)
                    if name == "persistent":
                        prev = scene
    s = {k: summarise(v) for k, v in runs.items()}
    scene = source.scene_at(frames[0])
    w, h = args.resolution or scene.resolution
    ratio = s["every_frame"]["wall_ms_median"] / s["persistent"]["wall_ms_median"]
    ratio_rest = s["every_frame"]["besides_shadows_ms_median"] / s["persistent"]["besides_shadows_ms_median"]
    print(f"{args.scene}: frames {args.frames} ({len(frames)}), {w}x{h}, {args.mode}/{args.quality}; "
          f"{len(scene.instances)} instances, {scene.triangle_count} triangles; loaded in {load_s:.1f} s")
    print("| per frame (median ms) | wall | export | bake / update | passes | of which shadows | wall - shadows "
          "| bakes |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for k, label in (("every_frame", "bake every frame"), ("persistent", "persistent bake")):
        v = s[k]
        b = v["bakes"]
        print(f"| {label} | {v['wall_ms_median']:.0f} | {v['export_ms_median']:.0f} | {v['bake_ms_median']:.1f} "
              f"| {v['passes_ms_median']:.0f} | {v['shadow_ms_median']:.0f} | {v['besides_shadows_ms_median']:.0f} "
              f"| {b['full']} full, {b['incremental']} incremental, {b['none']} none |")
    print(f"persistent bake: first (full) bake {s['persistent']['bake_ms_first']:.0f} ms; "
          f"per-frame speed-up x{ratio:.2f} (median wall), x{ratio_rest:.2f} besides the shadow pass (same run)")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": s, "ratio": ratio, "ratio_besides_shadows": ratio_rest,
                                               "frames": runs}, indent=1))


if __name__ == "__main__":
    main()
