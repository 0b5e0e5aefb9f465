"""The largest scenes this machine renders: the GL limits of its context, then synthetic scenes
of growing size, each rendered in a process of its own, and a markdown table of what happened.

    .venv/bin/python -m benchmarks.find_limits [--sweeps gl triangles instances lights resolution]
        [--triangles 1000000 4000000 16000000] [--instances 100000 1000000 4000000]
        [--lights 100 1000 max max+1] [--resolutions 3840x2160 7680x4320 16384x8192]
        [--size 320x180] [--timeout 600] [--memory-limit-gb G] [--json OUT]

Sweeps (every scene built in code, the layout of ``test_scenes/scaling.py`` without the Blender
export, which at millions of objects would dominate):

- ``triangles``: one model of N triangles (a torus) over a ground plane, a sun; hard shadows.
  Every triangle is unique: this is the bake's and the scene textures' limit.
- ``instances``: N instances of a 20-triangle model on a square field, random rotations and
  scales (as the scaling scene), a sun; hard shadows.
- ``lights``: a small scene (ground, 16 boxes) under N point lights; hard shadows. ``max`` is
  the most lights this GPU lights (``core/gpu/context.py`` ``max_lights``), ``max+1`` one more.
- ``resolution``: the small scene under a sun (3 degrees wide) and an area light, hard shadows
  (``Settings(hard=True)``) and soft (the default settings) at each resolution.

Each case runs ``Pipeline.set_scene`` (the bake and its upload) and one frame of
``Pipeline.render`` (``frames`` 2 for the small sweeps: the second, warm frame is reported) in a
subprocess with a timeout and an address-space limit (``--memory-limit-gb``, default 3/4 of this
machine's memory: an allocation past it fails in that process instead of waking the kernel's
out-of-memory killer), so that a crash, a hang or running out of memory is a row of the table.
Columns: bake and frame (ms), the process's peak resident memory, the share of the frame's
geometry pixels the first light shadows ("shadowed": a scene texture the GPU refused shows as
0 %, ids that wrap as a wrong share) and the outcome: ``ok``, a GL error left after the frame,
the one-line error it stopped with, a Python traceback's last line, a signal, or a timeout
(``--json`` also keeps the scene's build time, its texture MB and whether the record textures
were buffer textures). ``gl`` also finds the largest RGBA32F texture the driver makes (a software
rasteriser refuses large ones with GL_OUT_OF_MEMORY, which moderngl does not raise).

The default run takes about 6-7 minutes on a 2-core machine with llvmpipe and at most ~8 GB per
case. ``--sweeps triangles instances --triangles 32000000 64000000 --instances 8000000 16000000``
finds where memory ends (about 7 minutes, up to ~14 GB per case): the largest of each renders and
the next stops with the bake's memory check.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

RESULT = "RESULT "


# ------------------------------------------------------------------------------ scenes --
def torus(n_tri: int, major: float = 1.0, minor: float = 0.35, name: str = "torus"):
    """A closed torus of about ``n_tri`` triangles (2 per quad, 3 times more quads around than
    across), lying flat, its centre at the origin."""
    from hybrid_shadow_addon.core.scene import Model

    m = max(3, int(round(math.sqrt(n_tri / 6.0))))
    n = max(3, int(round(n_tri / (2.0 * m))))
    u = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False, dtype=np.float32)
    v = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False, dtype=np.float32)
    cu, su = np.cos(u)[:, None], np.sin(u)[:, None]
    cv, sv = np.cos(v)[None, :], np.sin(v)[None, :]
    r = major + minor * cv
    verts = np.stack([np.broadcast_to(r * cu, (n, m)), np.broadcast_to(r * su, (n, m)),
                      np.broadcast_to(minor * sv, (n, m))], axis=-1).reshape(-1, 3).astype(np.float32)
    i = np.arange(n, dtype=np.uint32)[:, None]
    j = np.arange(m, dtype=np.uint32)[None, :]
    a = i * m + j
    b = ((i + 1) % n) * m + j
    c = ((i + 1) % n) * m + (j + 1) % m
    d = i * m + (j + 1) % m
    tris = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2).reshape(-1, 3)
    return Model(name, verts, tris)


def icosahedron(name: str = "ico"):
    from hybrid_shadow_addon.core.scene import Model

    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], np.float32) / np.float32(math.hypot(1, t))
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    return Model(name, v, np.array(f, np.uint32))


def plane(half: float):
    from hybrid_shadow_addon.core.scene import Model

    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]], np.float32)
    return Model("ground", v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32))


def box():
    from hybrid_shadow_addon.core.scene import Model

    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return Model("box", v, np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.uint32))


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def translate_scale(pos, scale) -> np.ndarray:
    n = len(pos)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, [0, 1, 2], [0, 1, 2]] = np.asarray(scale, np.float64).reshape(n, -1)
    m[:, :3, 3] = pos
    return m


def rotations(rng, n) -> np.ndarray:
    """``n`` random rotation matrices (unit quaternions)."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)


def sun(angle_deg: float = 0.0):
    from hybrid_shadow_addon.core.scene import Light

    return Light("sun", "SUN", power=3.0, matrix=look_at((-4.0, -6.0, 10.0), (0, 0, 0)), angle=math.radians(angle_deg))


def scene_of(name, models, model_ids, matrices, lights, camera_eye, camera_target, size):
    from hybrid_shadow_addon.core.scene import Camera, Instances, Scene

    n = len(model_ids)
    inst = Instances(names=[f"{name}.{k}" for k in range(n)], model_ids=np.asarray(model_ids, np.int32),
                     matrices=matrices)
    cam = Camera(matrix=look_at(camera_eye, camera_target), lens=30.0, clip_start=0.1,
                 clip_end=100.0 * float(np.linalg.norm(np.subtract(camera_eye, camera_target))))
    return Scene(name=name, models=models, instances=inst, lights=lights, camera=cam,
                 world_color=(0.3, 0.35, 0.45), resolution=tuple(size))


def triangles_scene(n_tri: int, size):
    """One torus of ``n_tri`` triangles, 1.5 m above a 10 m ground, under a sun."""
    mats = translate_scale(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.5]]), [(5, 5, 1), (1.5, 1.5, 1.5)])
    return scene_of("triangles", [plane(1.0), torus(n_tri)], [0, 1], mats, [sun()], (6.0, -8.0, 6.0),
                    (0.0, 0.0, 0.5), size)


def instances_scene(n_inst: int, size, seed: int = 4):
    """``n_inst`` instances of a 20-triangle model on a square field (3 m apart, randomly turned
    and scaled, as ``test_scenes/scaling.py``) over a ground, under a sun; the camera sees all."""
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n_inst))
    field = side * 3.0
    i = np.arange(n_inst)
    pos = np.stack([(i % side + 0.5) * 3.0 - field / 2, (i // side + 0.5) * 3.0 - field / 2, np.ones(n_inst)], 1)
    pos[:, :2] += rng.uniform(-0.5, 0.5, (n_inst, 2))
    m = np.tile(np.eye(4), (n_inst + 1, 1, 1))
    m[0, 0, 0] = m[0, 1, 1] = field / 2 + 5.0
    s = rng.uniform(0.6, 1.2, n_inst)
    m[1:, :3, :3] = rotations(rng, n_inst) * s[:, None, None]
    m[1:, :3, 3] = pos
    ids = np.ones(n_inst + 1, np.int32)
    ids[0] = 0
    return scene_of("instances", [plane(1.0), icosahedron()], ids, m, [sun()],
                    (0.9 * field, -0.9 * field, 0.8 * field), (0.0, 0.0, 0.0), size)


def small_scene(lights, size):
    """A 16 m ground and 16 boxes in a 4 x 4 square."""
    g = (np.arange(4) - 1.5) * 3.0
    xy = np.array([(x, y) for x in g for y in g])
    pos = np.concatenate([[[0.0, 0.0, 0.0]], np.column_stack([xy, np.full(len(xy), 0.8)])])
    scale = np.concatenate([[[8.0, 8.0, 1.0]], np.tile([0.6, 0.6, 0.8], (len(xy), 1))])
    return scene_of("small", [plane(1.0), box()], [0] + [1] * len(xy), translate_scale(pos, scale), lights,
                    (9.0, -12.0, 9.0), (0.0, 0.0, 0.5), size)


def point_lights(n: int):
    from hybrid_shadow_addon.core.scene import Light

    side = math.ceil(math.sqrt(n))
    out = []
    for k in range(n):
        x = ((k % side) + 0.5) / side * 14.0 - 7.0
        y = ((k // side) + 0.5) / side * 14.0 - 7.0
        m = np.eye(4)
        m[:3, 3] = (x, y, 4.0)
        out.append(Light(f"point.{k}", "POINT", power=2000.0 / n, matrix=m))
    return out


def resolution_lights():
    from hybrid_shadow_addon.core.scene import Light

    area = Light("area", "AREA", power=400.0, matrix=look_at((3.0, -2.0, 5.0), (0, 0, 0)), size=1.5)
    return [sun(3.0), area]


# --------------------------------------------------------------------------------- child --
def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def probe_texture_bytes(ctx) -> dict:
    """The largest RGBA32F 2D texture (as many rows as the driver takes, ``GL_MAX_TEXTURE_SIZE``
    wide) the driver makes without GL_OUT_OF_MEMORY, by making them (llvmpipe clears each: this
    takes seconds and as much memory), to compare with the proxy queries the checks use."""
    side = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
    lo, hi = 1, side
    while lo < hi:
        mid = (lo + hi + 1) // 2
        _ = ctx.error
        t = ctx.texture((side, mid), 4, dtype="f4")
        ok = ctx.error == "GL_NO_ERROR"
        t.release()
        lo, hi = (mid, hi) if ok else (lo, mid - 1)
    return {"rgba32f_rows": lo, "max_texture_bytes": lo * side * 16}


def gl_case() -> dict:
    from hybrid_shadow_addon.core.gpu import context
    from hybrid_shadow_addon.core.gpu.buffer_textures import max_texels

    ctx = context.create_context()
    out = context.gpu_limits(ctx)
    out["max_texture_buffer_size"] = max_texels(ctx)
    out["max_uniform_block_size"] = int(ctx.info.get("GL_MAX_UNIFORM_BLOCK_SIZE", 0))
    out["max_lights"] = context.max_lights(ctx)
    out.update(probe_texture_bytes(ctx))
    out["proxy_rgba32f_rows"] = context.largest_rows(ctx, out["max_texture_size"])  # (what the checks ask)
    out["host_memory_bytes"] = context.host_memory_bytes()
    return out


def shadowed_share(frame, light: int = 0) -> float | None:
    """The share of the geometry pixels that light ``light`` leaves below half lit."""
    if light not in frame.masks:
        return None
    m = frame.mask_array(light)
    valid = np.isfinite(m)
    return float((m[valid] < 0.5).mean()) if valid.any() else None


def light_count(n, ctx) -> int:
    """``n``, or for ``"max"`` / ``"max+K"`` / ``"max-K"`` the lights this GPU can light plus K."""
    if isinstance(n, str) and n.startswith("max"):
        from hybrid_shadow_addon.core.gpu.context import max_lights

        return max_lights(ctx) + int(n[3:] or 0)
    return int(n)


def run_case(case: dict) -> dict:
    from hybrid_shadow_addon.core.errors import HybridShadowError
    from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
    from hybrid_shadow_addon.core.settings import Settings

    if case["kind"] == "gl":
        return {"status": "ok", "gl": gl_case(), "peak_rss_mb": peak_rss_mb()}
    row = {"status": "ok"}
    size = tuple(case.get("size", (320, 180)))
    try:
        pipe = Pipeline()
        t0 = time.perf_counter()
        kind, n = case["kind"], light_count(case.get("n", 0), pipe.ctx)
        if kind == "triangles":
            scene = triangles_scene(n, size)
        elif kind == "instances":
            scene = instances_scene(n, size)
        elif kind == "lights":
            scene = small_scene(point_lights(n), size)
        else:
            scene = small_scene(resolution_lights(), size)
        row["build_ms"] = (time.perf_counter() - t0) * 1e3
        row["triangles"] = scene.triangle_count
        row["unique_triangles"] = scene.unique_triangle_count
        row["instances"] = len(scene.instances)
        row["lights"] = len(scene.lights)
        scene.validate()
        row["bake_ms"] = pipe.set_scene(scene)
        row["texture_mb"] = pipe.scene_textures.nbytes / 2**20
        row["buffer_textures"] = pipe.scene_textures.using_buffers
        settings = Settings(hard=bool(case.get("hard", True)))
        for _ in range(int(case.get("frames", 1))):
            t1 = time.perf_counter()
            frame = pipe.render(scene, settings, *size)
            row["frame_ms"] = (time.perf_counter() - t1) * 1e3
        row["shadowed"] = shadowed_share(frame)
        row["image_finite"] = bool(np.isfinite(frame.image).all())
        row["gl_error"] = pipe.ctx.error
        if row["gl_error"] != "GL_NO_ERROR":
            row["status"] = f"GL error {row['gl_error']}"
    except HybridShadowError as e:
        row["status"] = "stopped"
        row["message"] = f"{type(e).__name__}: {e}"
    except Exception as e:  # (what the table reports as a traceback: no one-line error)
        row["status"] = "traceback"
        row["message"] = f"{type(e).__name__}: {' '.join(str(e).split())[:300]}"
    row["peak_rss_mb"] = peak_rss_mb()
    return row


def child(case_json: str) -> None:
    row = run_case(json.loads(case_json))
    sys.stdout.write(RESULT + json.dumps(row) + "\n")
    sys.stdout.flush()
    os._exit(0)


# -------------------------------------------------------------------------------- parent --
def spawn(case: dict, timeout: float, memory_limit: int) -> dict:
    """Run ``case`` in a subprocess; its result, or what ended it (signal, timeout)."""
    def limit():
        if memory_limit > 0:
            resource.setrlimit(resource.RLIMIT_AS, (memory_limit, memory_limit))

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "benchmarks.find_limits", "--case", json.dumps(case)],
                                stdout=out, stderr=err, preexec_fn=limit, cwd=str(REPO))
        status, usage, timed_out = None, None, False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - t0 > timeout:
                proc.kill()
                _, status, usage = os.wait4(proc.pid, 0)
                timed_out = True
                break
            time.sleep(0.2)
        proc.returncode = os.waitstatus_to_exitcode(status)  # (wait4 reaped it)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        lines = [ln for ln in out.read().splitlines() if ln.startswith(RESULT)]
        tail = [ln for ln in err.read().splitlines() if ln.strip()]
    row = json.loads(lines[-1][len(RESULT):]) if lines else {}
    row["wall_s"] = wall
    row["peak_rss_mb"] = usage.ru_maxrss / 1024.0
    if timed_out:
        row["status"] = "timeout"
        row["message"] = f"no result after {timeout:.0f} s"
    elif not lines:
        code = proc.returncode
        if code < 0:
            name = signal.Signals(-code).name
            row["status"] = "killed"
            row["message"] = f"{name}" + (" (out of memory?)" if -code == signal.SIGKILL else "")
        else:
            row["status"] = "crashed"
            row["message"] = f"exit code {code}: {tail[-1] if tail else ''}"[:300]
    return row


def fmt(v, spec=".0f", none="-"):
    return none if v is None else format(v, spec)


def outcome(r: dict) -> str:
    if r.get("status") == "ok":
        return "ok"
    msg = r.get("message", "")
    return f"{r.get('status')}: {msg}" if msg else str(r.get("status"))


def table(rows) -> str:
    head = ("| case | triangles (unique) | instances | lights | size | bake ms | frame ms | peak RSS MB "
            "| shadowed | outcome |")
    lines = [head, "|" + "---|" * 10]
    for c, r in rows:
        tri = f"{fmt(r.get('triangles'), ',')} ({fmt(r.get('unique_triangles'), ',')})" if "triangles" in r else "-"
        sh = r.get("shadowed")
        lines.append(f"| {c['label']} | {tri} | {fmt(r.get('instances'), ',')} | {fmt(r.get('lights'), ',')} "
                     f"| {c.get('size', (320, 180))[0]}x{c.get('size', (320, 180))[1]} "
                     f"| {fmt(r.get('bake_ms'), ',.0f')} | {fmt(r.get('frame_ms'), ',.0f')} "
                     f"| {fmt(r.get('peak_rss_mb'), ',.0f')} | {'-' if sh is None else f'{100 * sh:.1f} %'} "
                     f"| {outcome(r).replace('|', '/')} |")
    return "\n".join(lines)


def parse_size(text: str) -> tuple[int, int]:
    w, h = (int(v) for v in text.lower().split("x"))
    return w, h


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--sweeps", nargs="+", default=["gl", "triangles", "instances", "lights", "resolution"])
    ap.add_argument("--triangles", type=int, nargs="*", default=[1_000_000, 4_000_000, 16_000_000])
    ap.add_argument("--instances", type=int, nargs="*", default=[100_000, 1_000_000, 4_000_000])
    ap.add_argument("--lights", nargs="*", default=["100", "1000", "max", "max+1"],
                    help="light counts; 'max' (+/-K): the most this GPU lights (plus K)")
    ap.add_argument("--resolutions", type=parse_size, nargs="*",
                    default=[(3840, 2160), (7680, 4320), (16384, 8192)])
    ap.add_argument("--size", type=parse_size, default=(320, 180), help="resolution of the scene sweeps")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per case")
    ap.add_argument("--memory-limit-gb", type=float, default=None,
                    help="address space of each case (default 3/4 of this machine's memory; 0: none)")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    if args.case:
        child(args.case)
        return
    if args.memory_limit_gb is None:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        memory_limit = int(0.75 * total)
    else:
        memory_limit = int(args.memory_limit_gb * 2**30)

    cases = []
    size = list(args.size)
    if "gl" in args.sweeps:
        cases.append({"kind": "gl", "label": "GL limits"})
    if "triangles" in args.sweeps:
        cases += [{"kind": "triangles", "n": n, "size": size, "frames": 2, "label": f"triangles {n:,}"}
                  for n in args.triangles]
    if "instances" in args.sweeps:
        cases += [{"kind": "instances", "n": n, "size": size, "frames": 2, "label": f"instances {n:,}"}
                  for n in args.instances]
    if "lights" in args.sweeps:
        cases += [{"kind": "lights", "n": n if n.startswith("max") else int(n), "size": size, "frames": 1,
                   "label": f"lights {n}"} for n in args.lights]
    if "resolution" in args.sweeps:
        for w, h in args.resolutions:
            for hard in (True, False):
                cases.append({"kind": "resolution", "size": [w, h], "hard": hard, "frames": 1,
                              "label": f"{w}x{h} {'hard' if hard else 'soft'}"})
    print(f"{len(cases)} cases, {args.timeout:.0f} s each at most, address space "
          f"{'unlimited' if memory_limit <= 0 else f'{memory_limit / 2**30:.1f} GiB'} per case", flush=True)
    rows = []
    t_all = time.perf_counter()
    for case in cases:
        r = spawn(case, args.timeout, memory_limit)
        rows.append((case, r))
        if case["kind"] == "gl":
            print(json.dumps(r.get("gl", r), indent=1), flush=True)
            continue
        print(f"{case['label']:<24} bake {fmt(r.get('bake_ms'), '>8.0f')} ms  "
              f"frame {fmt(r.get('frame_ms'), '>8.0f')} ms  peak {fmt(r.get('peak_rss_mb'), '>6.0f')} MB  "
              f"{r['wall_s']:>5.0f} s  {outcome(r)}", flush=True)
    print()
    print(table([(c, r) for c, r in rows if c["kind"] != "gl"]))
    print(f"\n{time.perf_counter() - t_all:.0f} s in all")
    if args.json:
        Path(args.json).write_text(json.dumps([{"case": c, "result": r} for c, r in rows], indent=1) + "\n")


if __name__ == "__main__":
    main()
