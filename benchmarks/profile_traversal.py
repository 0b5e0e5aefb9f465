"""Where the two-level BVH walk spends its steps: a profile of the shadow rays of a frame.

For each scene (hard lights, ``high``, ``--structure bvh``) the rays the GPU traces are rebuilt
from the frame's G-buffer (``core/oracle/rays.py``) and walked by the numpy mirror of the shader
(``core/oracle/tracer/twolevel.py``, which visits the same nodes in the same order), counting per light:
dependent fetches per ray (a node a step, then an instance record or a leaf's triangles where a
step enters one: the chain a GPU thread waits on), node steps per ray (top level and model
trees; occluded and unoccluded rays apart), triangle tests, the model trees that take most of
the steps, the lock-step cost of llvmpipe's SIMD groups (each fragment-shader invocation runs 8
pixels, a 4x2 block, until its slowest ray is done: 8 x the block's largest step count over the
sum) and a GPU warp model: the mean share of active lanes in 32-lane groups of 8x4 pixels, each
running as long as its slowest ray (fetches). Each scene also gets the surface-area (SAH) cost of
its model trees (traversal and cluster test 1 each, per unit of the root's area) with this
builder and with the Morton-run builder it replaced (``spatial_min=0``). With ``--orders`` it
also re-lays every tree out with another child order (the stackless walk visits the first child first) and counts again:
the current order, front-to-back along the sun's direction (suns only), low boxes first, high
boxes first, larger boxes first. Deterministic (no timing): step counts are what the GPU walk
executes, whatever the machine. With ``--wide`` the same trees are walked as 4- and 8-wide nodes
with a stack (``core/oracle/tracer/wide.py``): the dependent fetches such a layout would take.

    .venv/bin/python -m benchmarks.profile_traversal [forest clusters city scaling:triangles=1000000]
        [--size 320x180] [--orders] [--wide]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.lights import light_ray_uniforms
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle import tracer
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings

LEAF = np.uint32(0x80000000)


def lane_waste(steps_img: np.ndarray, bw: int = 4, bh: int = 2) -> float:
    """8 x the largest step count of each 4x2 block over the sum (1.0: no lane waits)."""
    h, w = steps_img.shape
    b = steps_img[: h // bh * bh, : w // bw * bw].reshape(h // bh, bh, w // bw, bw)
    tot = b.sum()
    return float(b.max(axis=(1, 3)).sum() * bw * bh / tot) if tot else 1.0


def active_lanes(fetch_img: np.ndarray, bw: int = 8, bh: int = 4) -> float:
    """The mean share of active lanes of ``bw`` x ``bh`` pixel groups that run until their
    slowest ray is done (pixels without a ray are idle lanes): the sum of the work over the
    groups' lanes times their longest."""
    h, w = fetch_img.shape
    b = fetch_img[: h // bh * bh, : w // bw * bw].reshape(h // bh, bh, w // bw, bw)
    span = b.max(axis=(1, 3)).sum() * bw * bh
    return float(b.sum() / span) if span else 1.0


#: the wide layouts counted by ``--wide``: (label, binary levels per node, child order)
WIDE = (("4-wide, nearest first", 2, "distance"), ("4-wide, farthest first", 2, "far"),
        ("4-wide, tree order", 2, "tree"), ("8-wide, nearest first", 3, "distance"), ("8-wide, tree order", 3, "tree"))


def wide_table(spec, baked, rays) -> None:
    """Dependent fetches per ray of each light with the binary walk and with the layouts of
    WIDE (answers checked equal to the binary walk's), and the 8x4 warp model's active lanes."""
    from hybrid_shadow_addon.core.oracle.tracer.wide import trace_wide, trace_wide_packed

    print(f"\n{spec}: dependent fetches per ray as wide nodes (the same trees; a wide node's children's boxes "
          "one fetch; active lanes of 8x4 groups in brackets; the packed walk: [wide], the shaders' HS_BVH_WIDE)\n")
    print("| light | binary | packed 4-wide | " + " | ".join(label for label, *_ in WIDE) + " |")
    print("|---|---:|---:|" + "---:|" * len(WIDE))
    tot = np.zeros(2 + len(WIDE))
    n_all = 0
    for light, o, d, tm, occ, _mean, fetch_b, where in rays:
        row = [f"{fetch_b.mean():.1f} ({active_lanes(image_of(fetch_b, where)):.2f})"]
        tot[0] += fetch_b.sum()
        st = {}
        occ_p = trace_wide_packed(baked, o, d, tm, stats=st)
        assert (occ_p == occ).all(), f"{light.name}: the packed wide walk changed an answer"
        fp = st["ray_fetches"]
        tot[1] += fp.sum()
        row.append(f"{fp.mean():.1f} ({active_lanes(image_of(fp, where)):.2f}; stack {st['max_stack']})")
        for j, (_label, levels, order) in enumerate(WIDE):
            occ_w, fw, _ = trace_wide(baked, o, d, tm, levels, order)
            assert (occ_w == occ).all(), f"{light.name}: the wide walk changed an answer"
            tot[2 + j] += fw.sum()
            row.append(f"{fw.mean():.1f} ({active_lanes(image_of(fw, where)):.2f})")
        n_all += len(o)
        print(f"| {light.name} | " + " | ".join(row) + " |", flush=True)
    labels = ["packed 4-wide"] + [label for label, *_ in WIDE]
    ratios = ", ".join(f"{label} {tot[0] / tot[1 + j]:.2f}x fewer" for j, label in enumerate(labels))
    print(f"\nall lights: binary {tot[0] / n_all:.1f} fetches per ray; {ratios}")


def image_of(values, where) -> np.ndarray:
    """``values`` of the rays at pixels ``where`` ((rows, cols), shape) as an image (0 elsewhere)."""
    (rows, cols), shape = where
    img = np.zeros(shape, np.int64)
    img[rows, cols] = values
    return img


def sah_costs(scene, baked) -> str:
    """The model trees' SAH cost (mean weighted by triangles; the largest model's) with this
    builder and the one before."""
    from hybrid_shadow_addon.core.bake.sah import sah_cost
    from hybrid_shadow_addon.core.bake.structures.blas import BLAS_SPATIAL_MIN, build_blas, leaf_size

    models = [m for m in scene.models if m.triangle_count]
    if not models:
        return "no meshes"
    tc = np.array([m.triangle_count for m in models], np.float64)
    big = int(np.argmax(tc))
    out = []
    for name, sm in (("binned SAH", BLAS_SPATIAL_MIN or 8), ("Morton runs (before)", 0)):
        cost = sah_cost(build_blas(models, leaf_size(baked.config), spatial_min=sm).build)
        out.append(f"{name}: {(cost * tc).sum() / tc.sum():.1f} (largest, {models[big].name}: {cost[big]:.1f})")
    return "; ".join(out)


def boxes(nodes: np.ndarray):
    lo = np.stack([nodes[:, 0] & 0xFFFF, nodes[:, 0] >> 16, nodes[:, 1] & 0xFFFF], 1).astype(np.float64)
    hi = np.stack([nodes[:, 1] >> 16, nodes[:, 2] & 0xFFFF, nodes[:, 2] >> 16], 1).astype(np.float64)
    return lo, hi


def relayout(nodes: np.ndarray, start: int, end: int, key) -> np.ndarray:
    """Tree [start, end) in depth-first pre-order with each inner node's children ordered by
    ``key(node index)`` (smaller first); escapes recomputed, leaves unchanged."""
    out = []

    def sub_end(i):
        return i + 1 if nodes[i, 3] & LEAF else int(nodes[i, 3])

    stack = [("node", start)]
    while stack:
        kind, i = stack.pop()
        if kind == "close":
            out[i][3] = start + len(out)
            continue
        if nodes[i, 3] & LEAF:
            out.append(nodes[i].copy())
            continue
        pos = len(out)
        out.append(nodes[i].copy())
        a = i + 1
        b = sub_end(a)
        first, second = (a, b) if key(a) <= key(b) else (b, a)
        stack += [("close", pos), ("node", second), ("node", first)]
    res = np.array(out, np.uint32)
    assert len(res) == end - start
    return res


def tree_ranges(baked) -> dict:
    """{(root, end): model id} of the model trees, plus the top level as (root, end): -1."""
    models = baked.accel.models
    u = baked.uniforms
    out = {(int(u["hs_tlas_root"]), int(u["hs_tlas_end"])): -1}
    for m, (s, c) in enumerate(zip(models.node_start, models.node_count)):
        if c > 0:
            out[(int(s), int(s + c))] = m
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["forest", "clusters", "city", "scaling:triangles=1000000"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--orders", action="store_true", help="also count the steps under other child orders")
    ap.add_argument("--wide", action="store_true",
                    help="also count the fetches of the same trees walked as 4- and 8-wide nodes with a stack "
                         "(core/oracle/tracer/wide.py), nearest or farthest child first or in tree order")
    ap.add_argument("--blas-spatial-min", type=int, default=None,
                    help="bake the model trees with this spatial_min (0: the Morton-run builder before)")
    ap.add_argument("--tlas-spatial-min", type=int, default=None,
                    help="bake the top level with this spatial_min (4096: the builder before)")
    args = ap.parse_args(argv)
    from hybrid_shadow_addon.core.bake.structures import blas, tlas

    if args.blas_spatial_min is not None:
        blas.BLAS_SPATIAL_MIN = args.blas_spatial_min
    if args.tlas_spatial_min is not None:
        tlas.TLAS_SPATIAL_MIN = args.tlas_spatial_min
    w, h = (int(v) for v in args.size.lower().split("x"))
    pipe = Pipeline()
    pipe.bake_options["bvh"] = {"wide": True}  # (the packed 4-wide walk reads [wide])
    for spec in args.scenes:
        scene = load_scene(spec)
        pipe.set_scene(scene, "bvh")
        frame = pipe.render(scene, Settings(mode="raytrace", quality="high", structure="bvh", hard=True), w, h)
        baked = pipe.baked
        trees = tree_ranges(baked)
        end_to_model = {e: m for (s, e), m in trees.items() if m >= 0}
        n_tris = sum(mm.triangle_count for mm in scene.models)
        print(f"\n## {spec} {w}x{h}: {len(scene.instances)} instances, {len(scene.models)} models, "
              f"{n_tris} triangles\n")
        print(f"SAH cost of the model trees: {sah_costs(scene, baked)}\n")
        print("| light | rays | occluded | fetches/ray | steps/ray | occluded / unoccluded rays | top level / model "
              "trees | triangle tests/ray | model trees by steps (share) | 4x2 lane waste | 8x4 active lanes |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")
        rays = []
        totals = np.zeros(2)
        for k, li in enumerate(frame.lights):
            light = scene.lights[li]
            m = frame.mask_array(k)
            cov = ~np.isnan(m)
            rows, cols = np.nonzero(cov)
            o, d, tmax, facing = shadow_rays(frame.gbuffer, (rows, cols), light, baked.origin)
            if not facing.any():
                continue
            stats = {"per_ray": True}
            occ = tracer.trace_structured(baked, o[facing], d[facing], tmax[facing], stats)
            n = int(facing.sum())
            steps = stats["ray_iterations"]
            img = np.zeros(m.shape, np.int64)
            img[rows[facing], cols[facing]] = steps
            fetches = stats["ray_fetches"]
            fimg = np.zeros(m.shape, np.int64)
            fimg[rows[facing], cols[facing]] = fetches
            totals += (fetches.sum(), n)
            by = sorted(stats["tree_nodes"].items(), key=lambda kv: -kv[1])
            tot_b = max(stats["bvh_nodes"], 1)
            top = ", ".join(f"{scene.models[end_to_model[e]].name} {100 * c / tot_b:.0f}%" for e, c in by[:3]
                            if e in end_to_model)
            occ_s = f"{steps[occ].mean():.0f}" if occ.any() else "-"
            un_s = f"{steps[~occ].mean():.0f}" if (~occ).any() else "-"
            print(f"| {light.name} | {n} | {100 * occ.mean():.0f}% | {fetches.mean():.0f} | {steps.mean():.0f} | "
                  f"{occ_s} / {un_s} | {stats['tlas_nodes'] / n:.0f} / {stats['bvh_nodes'] / n:.0f} | "
                  f"{stats['triangles'] / n:.1f} | {top} | {lane_waste(img):.2f} | {active_lanes(fimg):.2f} |",
                  flush=True)
            rays.append((light, o[facing], d[facing], tmax[facing], occ, float(steps.mean()), fetches,
                         ((rows[facing], cols[facing]), m.shape)))
        if totals[1]:
            print(f"\nall lights: {totals[0] / totals[1]:.1f} dependent fetches per ray")
        if args.wide and rays:
            wide_table(spec, baked, rays)
        if args.orders and rays:
            node = baked.textures["node"].linear()
            saved = node.copy()
            lo, hi = boxes(saved)
            cen = lo + hi
            ext = hi - lo
            area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
            orders = {"low boxes first": lambda i: cen[i, 2], "high boxes first": lambda i: -cen[i, 2],
                      "larger boxes first": lambda i: -area[i]}
            print(f"\n{spec}: node steps per ray under other child orders (occlusion unchanged)\n")
            print("| light | current | " + " | ".join(orders) + " | front-to-back along the sun |")
            print("|---|---:|" + "---:|" * (len(orders) + 1))
            results = {r[0].name: [f"{r[5]:.0f}"] for r in rays}
            def count(key, which):
                node[:] = saved
                for (s_, e_) in trees:
                    node[s_:e_] = relayout(saved, s_, e_, key)
                for light, o, d, tm, occ, *_ in which:
                    stats = {"per_ray": True}
                    occ2 = tracer.trace_structured(baked, o, d, tm, stats)
                    assert (occ2 == occ).all(), "a child order changed an answer"
                    results[light.name].append(f"{stats['ray_iterations'].mean():.0f}")

            try:
                for key in orders.values():
                    count(key, rays)
                for r in rays:
                    local, vec = light_ray_uniforms(r[0], baked.origin)
                    if local:
                        results[r[0].name].append("-")
                    else:
                        dn = np.asarray(vec, np.float64) / np.linalg.norm(vec)
                        count(lambda i, dn=dn: float(cen[i] @ dn), [r])
            finally:
                node[:] = saved
            for name, row in results.items():
                print(f"| {name} | " + " | ".join(row) + " |")
    pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
