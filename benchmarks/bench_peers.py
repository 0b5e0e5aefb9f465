"""What an artist would use instead, timed the way they would use it: same run, scene and size.

- **Cycles**: one render with every light, 1 sample, direct light only (``max_bounces`` 0), no
  denoising, nothing written; cold (Persistent Data off: every render pays the scene's sync
  and its BVH build) and warm (Persistent Data on: the median of the renders after the first).
- **EEVEE** at its default shadow settings and **Workbench** with shadows, the same way, where
  this Blender can render them (a bpy wheel on a machine without a GPU cannot: the table says
  so).
- **Ours** (``raytrace``, ``high``, hard lights): cold is the export, the bake and the first
  frame of a new pipeline (its shaders compiled, light grids as the viewport builds them: in
  the background, once they pay); warm is the median frame once the grids it started are built
  and in use. Each is timed on the host, around the whole call.

Mismatch: ours against Cycles' one-light references (``compare``'s recipe: one light at a time,
pixel-centre samples), the share of pixels valid in both whose shadow differs, over all
lights. Cycles' one render is the reference's own renderer (its shadows are the reference's
at 1 sample); EEVEE's and Workbench's shadows are not separated per light here.

    .venv/bin/python -m benchmarks.bench_peers [--scenes forest clusters] [--size 320x180]
        [--frames 3] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

#: EEVEE's engine name in Blender 4.x and 5.x
EEVEE = ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE")


def _cycles(bscene) -> None:
    cy = bscene.cycles
    cy.device = "CPU"
    cy.samples = 1
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.max_bounces = 0


def _workbench(bscene) -> None:
    bscene.display.shading.show_shadows = True


def _render_ms(bpy, bscene, engines: tuple, setup, persistent: bool, count: int) -> list:
    """ms of ``count`` renders of ``bscene`` with the first of ``engines`` this Blender has (an
    exception where it has none or cannot render)."""
    r = bscene.render
    saved = (r.engine, r.use_persistent_data)
    try:
        for engine in engines:
            try:
                r.engine = engine
            except TypeError:  # (not an engine of this Blender)
                continue
            if r.engine == engine:
                break
        else:
            raise RuntimeError(f"none of {', '.join(engines)} in this Blender")
        if setup is not None:
            setup(bscene)
        r.use_persistent_data = persistent
        out = []
        for _ in range(count):
            t0 = time.perf_counter()
            bpy.ops.render.render(scene=bscene.name)
            out.append((time.perf_counter() - t0) * 1e3)
        return out
    finally:
        r.engine, r.use_persistent_data = saved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["forest", "clusters"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--frames", type=int, default=3, help="warm frames / renders timed (median)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    import bpy

    from hybrid_shadow_addon.__main__ import blender_output_to_stderr
    from hybrid_shadow_addon.blender.cycles_reference import render_reference
    from hybrid_shadow_addon.blender.frames import current_scene
    from hybrid_shadow_addon.blender.load import open_scene
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings
    from hybrid_shadow_addon.tools.metrics import mask_error

    w, h = (int(v) for v in a.size.split("x"))
    settings = Settings(mode="raytrace", quality="high", hard=True)
    record = {}
    print(f"## peers as artists would use them, {w}x{h}, same run\n")
    print("| scene | peer | cold ms | warm ms | warm / ours warm | mismatch % |\n|---|---|---:|---:|---:|---:|")
    for spec in a.scenes:
        with blender_output_to_stderr():
            bscene = open_scene(spec)
        r = bscene.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
        rows = {}
        t0 = time.perf_counter()
        with blender_output_to_stderr():
            scene = current_scene(resolution=(w, h))
        pipe = Pipeline()
        pipe.set_scene(scene)
        frame = pipe.render(scene, settings, w, h)
        cold = (time.perf_counter() - t0) * 1e3
        grids = pipe.shadow_pass("raytrace").light_grids
        for _ in range(3):  # (the grids the first frames start, built and taken up)
            pipe.render(scene, settings, w, h)
            grids.wait()
        warm = []
        for _ in range(a.frames + 2):
            t1 = time.perf_counter()
            frame = pipe.render(scene, settings, w, h)
            warm.append((time.perf_counter() - t1) * 1e3)
        with blender_output_to_stderr():
            ref = render_reference(bscene, resolution=(w, h), samples=1, hard=True)
        bad = valid = 0
        for li in frame.lights:
            name = scene.lights[li].name
            if name in ref.visibility:
                e = mask_error(ref.visibility[name], frame.mask_array(li))
                bad += e.mismatch_pct * e.valid_pixels / 100.0
                valid += e.valid_pixels
        pipe.release()
        ours_warm = statistics.median(warm[2:])
        rows["ours"] = dict(cold=cold, warm=ours_warm, mismatch=100.0 * bad / max(valid, 1))
        peers = [("Cycles", ("CYCLES",), _cycles), ("EEVEE", EEVEE, None),
                 ("Workbench", ("BLENDER_WORKBENCH",), _workbench)]
        for label, names, setup in peers:
            try:
                with blender_output_to_stderr():
                    c = _render_ms(bpy, bscene, names, setup, False, 1)
                    # (EEVEE on a software rasteriser takes tens of seconds a render: one warm one)
                    wr = _render_ms(bpy, bscene, names, setup, True, 2 if label == "EEVEE" else a.frames + 1)
                rows[label] = dict(cold=c[0], warm=statistics.median(wr[1:]), mismatch=None)
            except Exception as exc:  # (an engine this Blender cannot run here)
                rows[label] = dict(cold=None, warm=None, mismatch=None, error=str(exc).splitlines()[0][:120])
        record[spec] = rows
        for label, row in rows.items():
            if row.get("error"):
                print(f"| {spec} | {label} | – | – | – | not rendered here: {row['error']} |")
                continue
            mm = ("(the reference's renderer)" if label == "Cycles" else "–") if row["mismatch"] is None \
                else f"{row['mismatch']:.3f}"
            print(f"| {spec} | {label} | {row['cold']:.0f} | {row['warm']:.1f} | {row['warm'] / ours_warm:.1f}x | "
                  f"{mm} |", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
