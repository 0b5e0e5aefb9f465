"""Bake benchmark: 100 models x 10k triangles, each instanced 1000 times (100k instances, 1M unique
triangles, 1e9 instanced triangles). Prints full-bake time, texture memory, and the time to move 1%
of the instances (incremental update) with its ratio to the full bake.

    .venv/bin/python -m benchmarks.bench_bake [--structure bvh|grid] [--models 100] [--tris 10000]
        [--per-model 1000] [--repeat 3]

``--structure`` picks the acceleration structure (default ``bvh``, the add-on's default; ``grid``
for the hierarchical grid). Times: the best and the median of ``--repeat`` runs.
"""
import argparse
import time

import numpy as np

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.bake.structures import DEFAULT_STRUCTURE, STRUCTURES
from hybrid_shadow_addon.core.scene import Instances, Model, Scene


def make_scene(n_models, n_tris, per_model, seed=0):
    rng = np.random.default_rng(seed)
    models = []
    side = int(np.ceil(np.sqrt(n_tris / 2)))
    for m in range(n_models):
        # a bumpy height-field patch of ~n_tris triangles, 2 m wide
        xs = np.linspace(-1, 1, side + 1)
        X, Y = np.meshgrid(xs, xs)
        Z = 0.3 * np.sin(3 * X + m) * np.cos(2 * Y - m) + 0.5
        v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
        i = np.arange(side)
        a = (i[None, :] + (side + 1) * i[:, None]).ravel()
        tris = np.concatenate([np.stack([a, a + 1, a + side + 2], 1), np.stack([a, a + side + 2, a + side + 1], 1)])
        models.append(Model(f"m{m}", v, tris[:n_tris]))
    n = n_models * per_model
    M = np.tile(np.eye(4), (n, 1, 1))
    ang = rng.uniform(0, 2 * np.pi, n)
    s = rng.uniform(0.5, 2.0, n)
    M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1] = np.cos(ang) * s, -np.sin(ang) * s, np.sin(ang) * s, np.cos(ang) * s
    M[:, 2, 2] = s
    extent = np.sqrt(n) * 4.0
    M[:, 0, 3] = rng.uniform(-extent / 2, extent / 2, n)
    M[:, 1, 3] = rng.uniform(-extent / 2, extent / 2, n)
    M[:, 2, 3] = rng.uniform(0, 3, n)
    inst = Instances(names=[f"o{i}" for i in range(n)], model_ids=np.repeat(np.arange(n_models), per_model),
                     matrices=M, sphere=rng.random(n) < 0.05)
    return Scene(models=models, instances=inst), rng


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", type=int, default=100)
    ap.add_argument("--tris", type=int, default=10000)
    ap.add_argument("--per-model", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--structure", choices=tuple(STRUCTURES), default=DEFAULT_STRUCTURE,
                    help="acceleration structure to bake (default: the add-on's)")
    args = ap.parse_args()
    cfg = BakeConfig(structure=args.structure)
    t = time.perf_counter()
    scene, rng = make_scene(args.models, args.tris, args.per_model)
    print(f"scene: {len(scene.instances)} instances, {scene.unique_triangle_count} unique triangles, "
          f"{scene.triangle_count} instanced (built in {time.perf_counter() - t:.2f} s)")
    fulls = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        baked = bake_scene(scene, cfg)
        ms = (time.perf_counter() - t) * 1e3
        fulls.append(ms)
    best, med = min(fulls), float(np.median(fulls))
    st = baked.stats
    timings = ", ".join(f"{k[:-3]} {st[k]:.0f}" for k in st if k.endswith("_ms") and k != "bake_ms")
    print(f"full bake: {best:.0f} ms (best of {args.repeat}, median {med:.0f}; {timings} ms)  target < 2000 ms")
    counts = ("bvh_nodes", "bvh_max_depth", "tlas_nodes", "tlas_max_depth", "grid_levels", "grid_dims", "grid_nodes",
              "grid_nodes_nonempty", "max_objects_per_node")
    print(f"{baked.structure}: " + ", ".join(f"{k} {st[k]}" for k in counts if k in st))
    print("textures:")
    for name, tex in baked.textures.items():
        print(f"  {name:11s} {tex.gl_internal_format:9s} {tex.width}x{tex.height}x{tex.layers:<3d} "
              f"{tex.nbytes / 2**20:8.2f} MB")
    print(f"  {'total':11s} {'':9s} {'':15s} {st['total_bytes'] / 2**20:8.2f} MB")

    n = len(scene.instances)
    k = max(1, n // 100)
    times = []
    for _ in range(args.repeat):
        idx = rng.choice(n, k, replace=False)
        M = scene.instances.matrices[idx].copy()
        M[:, :2, 3] += rng.normal(scale=3.0, size=(k, 2))
        M[:, 2, 3] += rng.normal(scale=0.3, size=k)
        scene.instances.set_matrices(idx, M)
        t = time.perf_counter()
        rep = baked.update_instances(scene, idx)
        times.append((time.perf_counter() - t) * 1e3)
    up, up_med = min(times), float(np.median(times))
    print(f"move 1% ({k} instances): {up:.1f} ms (best of {args.repeat}, median {up_med:.1f}) = "
          f"{100 * up / best:.2f}% of the full bake (medians: {100 * up_med / med:.2f}%) "
          f"(target <= 5%); {rep.nodes_changed} nodes, {len(rep.ranges)} row ranges, "
          f"{rep.texels_changed(baked)} texels to re-upload, regrid={rep.regrid}")

    print()
    test_scene_table(args.repeat, cfg)


def test_scene_table(repeat: int, cfg=None) -> None:
    """Bake ms (best of ``repeat``) and texture MB of every built-in test scene."""
    from hybrid_shadow_addon.blender.load import builtin_scenes, load_scene

    print(f"{'scene':16s} {'instances':>9s} {'triangles':>10s} {'bake ms':>8s} {'textures MB':>12s}")
    for name in builtin_scenes():
        if "/" in name:
            continue
        scene = load_scene(name)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            baked = bake_scene(scene, cfg)
            times.append((time.perf_counter() - t) * 1e3)
        print(f"{name:16s} {len(scene.instances):9d} {scene.triangle_count:10d} {min(times):8.1f} "
              f"{baked.stats['total_bytes'] / 2**20:12.2f}")


if __name__ == "__main__":
    main()
