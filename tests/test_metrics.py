"""Metrics on synthetic masks with known differences; the thesis' frame-rate statistics on known
frame times; the Pareto front; the false-colour difference image."""
import numpy as np
import pytest

from hybrid_shadow_addon.tools import metrics


def masks():
    ref = np.ones((10, 10), np.float32)
    ref[:, :5] = 0.0  # left half shadowed
    ref[0, :] = np.nan  # reference row 0 invalid (10 px)
    ours = ref.copy()
    ours[0, :] = 0.0  # differs where the reference is invalid: must not count
    ours[5, 0:3] = 1.0  # 3 missed shadows (we are lit)
    ours[6, 7:9] = 0.0  # 2 false shadows
    ours[7, 7] = 0.7  # a small difference (0.3): no mismatch, counts in the MAE
    ours[9, 9] = np.nan  # no geometry in ours: not valid
    return ref, ours


def test_mask_error_counts():
    ref, ours = masks()
    e = metrics.mask_error(ref, ours)
    assert e.valid_pixels == 100 - 10 - 1
    assert (e.mismatch_pixels, e.missed_pixels, e.false_pixels) == (5, 3, 2)
    assert e.mismatch_pct == pytest.approx(100 * 5 / 89)
    assert e.missed_pct == pytest.approx(100 * 3 / 89)
    assert e.false_pct == pytest.approx(100 * 2 / 89)
    assert e.mae == pytest.approx((5 + 0.3) / 89, rel=1e-6)
    assert metrics.valid_pixels(ref, ours).sum() == 89


def test_mask_error_identical_and_empty():
    ref, _ = masks()
    e = metrics.mask_error(ref, ref)
    assert e.mismatch_pixels == 0 and e.mae == 0
    nan = np.full((4, 4), np.nan)
    e = metrics.mask_error(nan, np.ones((4, 4)))
    assert e.valid_pixels == 0 and e.mismatch_pct == 0 and e.mae == 0
    with pytest.raises(ValueError):
        metrics.mask_error(np.ones((4, 4)), np.ones((4, 5)))


def test_threshold_is_strict():
    ref = np.zeros((1, 2))
    ours = np.array([[0.5, 0.51]])
    e = metrics.mask_error(ref, ours)
    assert e.mismatch_pixels == 1 and e.missed_pixels == 1


def test_combine_weights_by_valid_pixels():
    a = metrics.mask_error(np.zeros((1, 10)), np.ones((1, 10)))  # 10 valid, all missed
    b = metrics.mask_error(np.zeros((3, 10)), np.zeros((3, 10)))  # 30 valid, exact
    t = metrics.combine([a, b])
    assert t.valid_pixels == 40 and t.mismatch_pixels == 10
    assert t.mismatch_pct == pytest.approx(25.0)
    assert t.mae == pytest.approx(0.25)
    d = t.to_dict()
    assert d["mismatch_pct"] == pytest.approx(25.0) and d["valid_pixels"] == 40


def test_diff_image_colours():
    ref, ours = masks()
    img = metrics.diff_image(ref, ours)
    assert img.shape == (10, 10, 3) and img.dtype == np.uint8
    assert tuple(img[5, 0]) == tuple(metrics.MISSED_COLOUR.astype(np.uint8))
    assert tuple(img[6, 7]) == tuple(metrics.FALSE_COLOUR.astype(np.uint8))
    assert tuple(img[0, 3]) == (0, 0, 0) and tuple(img[9, 9]) == (0, 0, 0)  # invalid
    assert img[2, 2, 0] == img[2, 2, 1] == img[2, 2, 2]  # agreement: grey
    assert img[2, 7, 0] > img[2, 2, 0]  # lit reference brighter than shadowed
    assert img[7, 7, 2] > img[7, 7, 0]  # a small false-shadow tint: bluish, not full colour
    vis = metrics.visibility_image(ours)
    assert vis.shape == (10, 10, 3) and vis[2, 7, 0] > vis[2, 2, 0]


def test_pareto_front():
    pts = [(10, 5.0), (20, 1.0), (15, 6.0), (40, 0.0), (5, 50.0), (20, 2.0), (40, 0.0)]
    front = metrics.pareto_front(pts)
    assert [pts[i] for i in front] == [(5, 50.0), (10, 5.0), (20, 1.0), (40, 0.0), (40, 0.0)]


def test_frame_stats_known_values():
    ms = np.array([[10.0, 20.0, 40.0],
                   [10.0, 25.0, 40.0]])  # fps: [100, 50, 25], [100, 40, 25]
    control = np.array([[5.0, 10.0, 20.0],
                        [5.0, 10.0, 20.0]])
    s = metrics.frame_stats(ms, control)
    assert s["repetitions"] == 2 and s["frames"] == 3
    assert s["min_fps"] == pytest.approx(25.0)
    assert s["max_fps"] == pytest.approx(100.0)
    assert s["avg_fps"] == pytest.approx((100 + 45 + 25) / 3)
    assert s["avg_frame_ms"] == pytest.approx(145 / 6)
    assert s["extra_ms_per_frame"] == pytest.approx([5.0, 12.5, 20.0])
    assert s["extra_ms"] == pytest.approx(37.5 / 3)
    fps = np.array([100, 50, 25, 100, 40, 25.0])
    assert s["std_rel"] == pytest.approx(fps.std(ddof=1) / fps.mean())
    # erraticness, thesis 4.6: sum over passes of |fps - mean| over the mean, per frame
    err = metrics.erraticness(ms)
    assert err == pytest.approx([0.0, (5 + 5) / 45, 0.0])
    assert s["erraticness"] == pytest.approx(err.mean())
    assert s["erraticness_max"] == pytest.approx(10 / 45)


def test_frame_stats_one_pass():
    s = metrics.frame_stats([[10.0, 10.0]])
    assert s["erraticness"] == 0 and s["std_rel"] == 0 and "extra_ms" not in s
    with pytest.raises(ValueError):
        metrics.frame_stats([[1.0, 2.0]], [[1.0]])
