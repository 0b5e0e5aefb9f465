"""A loose hierarchical grid as the top level, against the two-level BVH's top level: the work
each would do for the same shadow rays (a model; the loose grid is not built).

The traversal issue names a loose hierarchical grid as a candidate for the walk's top level:
objects filed by their centre, each in the level whose cells are at least its size, every cell's
bounds grown by half a cell on each side (so an object never moves up a level for crossing a
border), walked level by level. This script counts what it would cost on the frame's own rays:

- the rays: ``high``'s shadow rays of each light (hard lights, 320×180), rebuilt from the
  G-buffer (``core/oracle/rays.py``), at most ``--rays`` of each light (a fixed random sample);
  only the rays that nothing occludes, which walk their whole length in both structures (an
  occluded ray stops at its first hit in either);
- the BVH: the top-level node steps of the numpy mirror of the walk (``core/oracle/tracer/twolevel.py``:
  one fetch each, the same nodes the shader visits);
- the loose grid, counted generously: the xy grid of the thesis (levels of cells 2^k times the
  base size, a cell's z range that of its objects), and for each ray only the cells whose grown
  box it crosses (no walk visits fewer), one fetch per cell, one fetch per object of a crossed
  cell that holds any (its box and instance in one texel), for the best of several base cell
  sizes.

Entering an instance (its transform and model tree) costs the same in both and is left out;
the instances each structure lets a ray reach are printed (the grid's boxes are exact, the
BVH's are rounded outward: a ray leaving a flat ground enters the ground's own tree). The last
column is the most the grid could save of the whole walk (top level and model trees, one fetch
a step), were its count exact.

    .venv/bin/python -m benchmarks.model_loose_grid [forest clusters city "scaling:..."] [--rays 1500]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.oracle import tracer
from hybrid_shadow_addon.core.oracle.rays import shadow_rays
from hybrid_shadow_addon.core.settings import Settings


def instance_boxes(scene) -> tuple:
    """World-space boxes (lo, hi) of the instances that cast shadows."""
    inst = scene.instances
    keep = np.nonzero(np.asarray(inst.casts_shadow, bool))[0]
    lo = np.zeros((len(keep), 3))
    hi = np.zeros((len(keep), 3))
    for j, k in enumerate(keep):
        m = scene.models[int(inst.model_ids[k])]
        bmin = np.asarray(m.bounds_min if m.bounds_min is not None else m.vertices.min(0), np.float64)
        bmax = np.asarray(m.bounds_max if m.bounds_max is not None else m.vertices.max(0), np.float64)
        c = np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1]) for z in (bmin[2], bmax[2])])
        w = c @ inst.matrices[k][:3, :3].T + inst.matrices[k][:3, 3]
        lo[j], hi[j] = w.min(0), w.max(0)
    return lo, hi


class LooseGrid:
    """Objects by centre in 2D levels of cells ``base * 2**k``; a cell's grown box is the cell
    plus half a cell on each side in x and y, and its objects' z range."""

    def __init__(self, lo, hi, base: float):
        self.lo, self.hi = lo, hi
        self.origin = lo[:, :2].min(0) - base
        size = np.maximum(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
        lvl = np.maximum(0, np.ceil(np.log2(np.maximum(size, 1e-9) / base))).astype(int)
        self.levels = []
        for k in np.unique(lvl):
            s = base * 2.0 ** k
            objs = np.nonzero(lvl == k)[0]
            centre = (lo[objs, :2] + hi[objs, :2]) * 0.5
            cell = np.floor((centre - self.origin) / s).astype(np.int64)
            cells: dict = {}
            for o, (cx, cy) in zip(objs, cell):
                cells.setdefault((int(cx), int(cy)), []).append(int(o))
            keys = np.array(list(cells), np.int64)
            zlo = np.array([lo[v, 2].min() for v in cells.values()])
            zhi = np.array([hi[v, 2].max() for v in cells.values()])
            counts = np.array([len(v) for v in cells.values()])
            self.levels.append((s, keys, zlo, zhi, counts, list(cells.values())))

    def walk(self, o, d, tmax) -> tuple:
        """(cells crossed, objects tested, objects whose box the ray crosses) for one ray."""
        cells = tested = 0
        reached = set()
        inv = 1.0 / np.where(np.abs(d) < 1e-30, 1e-30, d)
        for s, keys, zlo, zhi, counts, objs in self.levels:
            # every cell of the level's grown boxes that the ray crosses (occupied or not): the
            # cells between the segment's ends in xy, one more on each side
            a = o[:2] + d[:2] * 0.0
            b = o[:2] + d[:2] * tmax
            c0 = np.floor((np.minimum(a, b) - self.origin) / s - 0.5).astype(np.int64)
            c1 = np.floor((np.maximum(a, b) - self.origin) / s + 0.5).astype(np.int64)
            nx, ny = c1 - c0 + 1
            if nx * ny > 4_000_000:
                raise ValueError("a ray spans too many cells of a level; raise the base size")
            gx, gy = np.meshgrid(np.arange(c0[0], c1[0] + 1), np.arange(c0[1], c1[1] + 1), indexing="ij")
            gx, gy = gx.ravel(), gy.ravel()
            blo = np.stack([self.origin[0] + (gx - 0.5) * s, self.origin[1] + (gy - 0.5) * s], 1)
            bhi = blo + 2.0 * s
            t0 = (blo - o[:2]) * inv[:2]
            t1 = (bhi - o[:2]) * inv[:2]
            tn = np.maximum(np.minimum(t0, t1).max(1), 0.0)
            tf = np.minimum(np.maximum(t0, t1).min(1), tmax)
            crossed = tn <= tf
            cells += int(crossed.sum())
            # the occupied ones, whose z range the ray also reaches
            if not len(keys):
                continue
            sel = np.nonzero(crossed)[0]
            key = gx[sel] * 1_000_003 + gy[sel]
            kk = keys[:, 0] * 1_000_003 + keys[:, 1]
            pos = np.searchsorted(np.sort(kk), key)
            order = np.argsort(kk)
            ks = kk[order]
            pos = np.clip(pos, 0, len(ks) - 1)
            occ = ks[pos] == key
            for j, p in zip(sel[occ], order[pos[occ]]):
                zt0 = (zlo[p] - o[2]) * inv[2]
                zt1 = (zhi[p] - o[2]) * inv[2]
                if max(tn[j], min(zt0, zt1)) > min(tf[j], max(zt0, zt1)):
                    continue
                tested += int(counts[p])
                for ob in objs[p]:
                    u0 = (self.lo[ob] - o) * inv
                    u1 = (self.hi[ob] - o) * inv
                    if max(np.minimum(u0, u1).max(), 0.0) <= min(np.maximum(u0, u1).min(), tmax):
                        reached.add(ob)
        return cells, tested, len(reached)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["forest", "clusters", "city"])
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--rays", type=int, default=1500, help="rays per light (a fixed random sample)")
    ap.add_argument("--bases", default="0.5,1,2,4", help="base cell sizes, in units of the median instance size")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    rng = np.random.default_rng(7)
    pipe = Pipeline()
    print("| scene | unoccluded rays | BVH steps/ray: top level of all | instances entered/ray "
          "| best loose grid (base) | cells + objects = fetches/ray | instances reached/ray "
          "| loose grid / BVH top level | at most saved of the walk |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|")
    try:
        for spec in args.scenes:
            scene = load_scene(spec)
            pipe.set_scene(scene, "bvh")
            frame = pipe.render(scene, Settings(mode="raytrace", quality="high", structure="bvh", hard=True), w, h)
            baked = pipe.baked
            lo, hi = instance_boxes(scene)
            o_parts, d_parts, t_parts = [], [], []
            for k, li in enumerate(frame.lights):
                valid = ~np.isnan(frame.mask_array(k))
                rows, cols = np.nonzero(valid)
                o, d, tmax, facing = shadow_rays(frame.gbuffer, (rows, cols), scene.lights[li], baked.origin)
                idx = np.nonzero(facing)[0]
                if len(idx) > args.rays:
                    idx = np.sort(rng.choice(idx, args.rays, replace=False))
                o_parts.append(o[idx]), d_parts.append(d[idx]), t_parts.append(np.broadcast_to(tmax, facing.shape)[idx])
            o, d, tmax = np.concatenate(o_parts), np.concatenate(d_parts), np.concatenate(t_parts)
            occ = tracer.trace_structured(baked, o, d, tmax)
            o, d, tmax = o[~occ], d[~occ], tmax[~occ]
            st: dict = {}
            tracer.trace_structured(baked, o, d, tmax, st)
            n = len(o)
            # a ray to the sun ends where it leaves the casters' boxes
            o64, d64 = o.astype(np.float64), d.astype(np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / d64
                t0, t1 = (lo.min(0) - o64) * inv, (hi.max(0) - o64) * inv
                t_exit = np.nan_to_num(np.maximum(t0, t1), nan=np.inf, posinf=np.inf).min(1)
            tm = np.minimum(tmax.astype(np.float64), np.maximum(t_exit, 0.0))
            med = float(np.median(np.maximum(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])))
            best = None
            for f in (float(v) for v in args.bases.split(",")):
                grid = LooseGrid(lo, hi, max(med * f, 1e-3))
                tot = np.zeros(3)
                for r in range(n):
                    tot += grid.walk(o64[r], d64[r], tm[r])
                cost = (tot[0] + tot[1]) / n
                if best is None or cost < best[0]:
                    best = (cost, f, tot / n)
            cost, f, per = best
            top = st["tlas_nodes"] / n
            allsteps = st["iterations"] / n
            print(f"| {spec} | {n} | {top:.1f} of {allsteps:.1f} | {st['objects'] / n:.2f} | {f:g} × median size | "
                  f"{per[0]:.1f} + {per[1]:.1f} = {cost:.1f} | {per[2]:.2f} | {cost / top:.2f} | "
                  f"{max(0.0, top - cost) / allsteps:.0%} |", flush=True)
    finally:
        pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
