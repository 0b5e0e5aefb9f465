"""The models behind figures in BENCHMARKS.md that are counted, not timed: the refinement's
lock-step cost (``benchmarks/profile_refinement.py``) and the loose grid's work
(``benchmarks/model_loose_grid.py``)."""
import numpy as np


def test_refinement_profile_cost_model():
    """benchmarks/profile_refinement.py's lock-step model (BENCHMARKS.md's bound on what the
    refinement can save): a 4x2 block costs its slowest traced lane; a list costs 8 rays at a
    time in llvmpipe's shading order."""
    from benchmarks import profile_refinement as pr

    steps = np.arange(1, 33, dtype=np.int64).reshape(4, 8)  # row 0 the top row
    everything = np.ones_like(steps, bool)
    # GL rows 0-1 are the image's rows 3 and 2: blocks (cols 0-3, 4-7) cost 28 and 32, then 12 and 16
    assert pr.block_cost(steps, everything) == 28 + 32 + 12 + 16
    one = np.zeros_like(everything)
    one[0, 5] = True  # a single marked lane: its block costs that lane's steps
    assert pr.block_cost(steps, one) == 6
    assert pr.list_cost(steps, one) == 6
    # a list of 9 rays: two groups of 8, each its slowest
    nine = np.zeros_like(everything)
    nine[3, :] = True
    nine[2, 0] = True
    got = pr.list_cost(steps, nine)
    lanes = sorted(steps[nine])
    assert lanes[-1] <= got <= lanes[-1] + lanes[-2]
    assert pr.list_cost(steps, np.zeros_like(everything)) == 0


def test_loose_grid_model_reaches_exactly_the_boxes_a_ray_crosses():
    """The loose grid files each box by its centre in a level whose grown cells hold it, so a
    walk over the grown cells a ray crosses finds every box the ray crosses (a brute-force
    slab test over all boxes), and tests at least those."""
    from benchmarks import model_loose_grid as lg

    rng = np.random.default_rng(3)
    n = 400
    centre = rng.uniform(-50, 50, (n, 3)) * [1, 1, 0.1]
    half = rng.uniform(0.1, 1.0, (n, 3)) * np.where(rng.random((n, 1)) < 0.1, 12.0, 1.0)
    lo, hi = centre - half, centre + half
    for base in (0.5, 2.0, 7.0):
        grid = lg.LooseGrid(lo, hi, base)
        for _ in range(60):
            o = rng.uniform(-60, 60, 3) * [1, 1, 0.1]
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            tmax = float(rng.uniform(5, 150))
            cells, tested, reached = grid.walk(o, d, tmax)
            with np.errstate(divide="ignore", invalid="ignore"):
                t0, t1 = (lo - o) / d, (hi - o) / d
            tn = np.maximum(np.nan_to_num(np.minimum(t0, t1), nan=-np.inf).max(1), 0.0)
            tf = np.minimum(np.nan_to_num(np.maximum(t0, t1), nan=np.inf).min(1), tmax)
            want = int((tn <= tf).sum())
            assert reached == want, (base, reached, want)
            assert tested >= reached and cells >= (1 if reached else 0)
