"""Simulated head detections: exact boxes on a tiny scene, the planted error rates recovered
from many draws, determinism under a seed, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from synth_data.detections import (
    DetectionParams,
    Detections,
    attach_detections,
    simulate_detections,
)
from synth_data.sequence import InMemorySequence

PERFECT = DetectionParams(
    miss_rate=0.0, false_alarm_rate=0.0, jitter_px=0.0, box_px=6.0, score_std=0.0, score_mean=0.9
)


def _grid(t=20, n=400, w=640, h=480, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([5, 5], [w - 6, h - 6], (t, n, 2))
    return np.arange(100, 100 + n), pts, w, h


def test_exact_boxes_visibility_and_order():
    pts = np.array(
        [
            [[10.0, 10.0], [30.0, 20.0], [np.nan, np.nan], [70.0, 5.0]],
            [[12.0, 10.0], [-3.0, 20.0], [40.0, 40.0], [61.0, 48.0]],  # ids 2 and 4 left the image
        ]
    )
    dets = simulate_detections([1, 2, 3, 4], pts, 64, 48, PERFECT)
    assert [d.gt_id.tolist() for d in dets] == [[1, 2], [1, 3]]
    np.testing.assert_array_equal(dets[0].xyxy, [[7, 7, 13, 13], [27, 17, 33, 23]])
    np.testing.assert_array_equal(dets[1].centers, [[12, 10], [40, 40]])
    assert all(isinstance(d, Detections) and (d.confidence == 0.9).all() for d in dets)
    # boxes are clipped to the image, the template size is the default box side
    edge = simulate_detections(
        [1],
        np.array([[[1.0, 46.0]]]),
        64,
        48,
        DetectionParams(miss_rate=0, false_alarm_rate=0, jitter_px=0),
        template_size=10,
    )
    np.testing.assert_array_equal(edge[0].xyxy, [[0, 41, 6, 48]])


def test_planted_rates_are_recovered():
    ids, pts, w, h = _grid()
    p = DetectionParams(
        miss_rate=0.3,
        false_alarm_rate=5.0,
        jitter_px=2.0,
        box_px=8.0,
        score_mean=0.8,
        score_std=0.05,
        false_score_mean=0.4,
        seed=3,
    )
    dets = simulate_detections(ids, pts, w, h, p)
    true = np.concatenate([d.gt_id >= 0 for d in dets])
    n_true, n_total = true.sum(), pts.shape[0] * pts.shape[1]
    miss = 1 - n_true / n_total
    assert abs(miss - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n_total)
    # false alarms: Poisson, mean 5 per 100 people in view per frame (400 people: 20)
    n_fa = np.array([(d.gt_id < 0).sum() for d in dets])
    assert abs(n_fa.mean() - 20.0) < 4 * np.sqrt(20.0 / len(dets))
    # centre noise of true detections: N(0, 2 px) per axis
    err = np.concatenate(
        [d.centers[d.gt_id >= 0] - pts[t, d.gt_id[d.gt_id >= 0] - 100] for t, d in enumerate(dets)]
    )
    assert abs(err.std() - 2.0) < 0.1 and abs(err.mean()) < 0.1
    conf = np.concatenate([d.confidence for d in dets])
    assert abs(conf[true].mean() - 0.8) < 0.01 and abs(conf[~true].mean() - 0.4) < 0.02
    fa = np.concatenate([d.centers[d.gt_id < 0] for d in dets])
    assert (fa >= 0).all() and (fa[:, 0] <= w - 1).all() and (fa[:, 1] <= h - 1).all()


def test_deterministic_under_seed_and_injected_rng():
    ids, pts, w, h = _grid(t=5, n=50)
    p = DetectionParams(box_px=8.0, seed=11)
    a = simulate_detections(ids, pts, w, h, p)
    b = simulate_detections(ids, pts, w, h, p)
    c = simulate_detections(ids, pts, w, h, p, rng=np.random.default_rng(11))
    d = simulate_detections(ids, pts, w, h, DetectionParams(box_px=8.0, seed=12))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.xyxy, y.xyxy)
        np.testing.assert_array_equal(x.gt_id, y.gt_id)
    assert all(np.array_equal(x.xyxy, y.xyxy) for x, y in zip(a, c, strict=True))
    assert not all(np.array_equal(x.xyxy, y.xyxy) for x, y in zip(a, d, strict=True))


def test_empty_inputs():
    assert simulate_detections([1], np.zeros((0, 1, 2)), 10, 10, PERFECT) == []
    dets = simulate_detections([], np.zeros((3, 0, 2)), 10, 10, PERFECT)
    assert [len(d) for d in dets] == [0, 0, 0] and dets[0].xyxy.shape == (0, 4)


@pytest.mark.parametrize(
    "kw, field",
    [
        (dict(miss_rate=1.5), "miss_rate"),
        (dict(miss_rate=float("nan")), "miss_rate"),
        (dict(false_alarm_rate=-1.0), "false_alarm_rate"),
        (dict(jitter_px=-0.1), "jitter_px"),
        (dict(box_px=0.5), "box_px"),
        (dict(box_px=1e9), "box_px"),
        (dict(score_mean=2.0), "score_mean"),
        (dict(seed=1.5), "seed"),
    ],
)
def test_bad_params_name_the_field(kw, field):
    with pytest.raises(ValueError, match=f"DetectionParams.{field}"):
        DetectionParams(**kw)


def test_bad_arrays():
    with pytest.raises(ValueError, match=r"shape \(T, 2, 2\)"):
        simulate_detections([1, 2], np.zeros((3, 1, 2)), 10, 10, PERFECT)
    with pytest.raises(ValueError, match="template_size"):
        simulate_detections([1], np.zeros((3, 1, 2)), 10, 10, DetectionParams())
    with pytest.raises(ValueError, match="width"):
        simulate_detections([1], np.zeros((3, 1, 2)), 0, 10, PERFECT)


def test_attach_detections_takes_the_detector_explicitly():
    """The detector comes from the caller (the detection source), not from the tracker's
    parameters: a tracker whose params carry detector-like fields does not change it."""

    class Fake:
        def __init__(self):
            # detector-like fields on the tracker must be ignored
            self.params = type("P", (), {"miss_rate": 1.0, "box_px": 2.0})()
            self.feed = None

        def use_detections(self, feed):
            self.feed = feed

    pts = np.array([[[10.0, 10.0]], [[11.0, 10.0]]])
    seq = InMemorySequence(
        name="s",
        frame_rate=25,
        width=32,
        height=24,
        template_size=6,
        frames=[np.zeros((24, 32, 3), np.uint8)] * 2,
        ids=[5],
        points=pts,
    )
    fake = Fake()
    exact = DetectionParams(miss_rate=0.0, false_alarm_rate=0.0, jitter_px=0.0, score_std=0.0)
    dets = attach_detections(fake, seq, exact)
    assert fake.feed is dets and [d.gt_id.tolist() for d in dets] == [[5], [5]]
    np.testing.assert_array_equal(dets[1].xyxy, [[8, 7, 14, 13]])  # template size 6, not 2
    assert [d.confidence.tolist() for d in dets] == [[0.8], [0.8]]
    # no detector given: DetectionParams(), whatever the tracker's params say
    default = attach_detections(Fake(), seq)
    expected = simulate_detections(*seq.gt_points(), 32, 24, DetectionParams(), template_size=6)
    for d, e in zip(default, expected, strict=True):
        np.testing.assert_array_equal(d.xyxy, e.xyxy)
        np.testing.assert_array_equal(d.confidence, e.confidence)
    assert attach_detections(object(), seq, exact) is None  # no use_detections: untouched
    with pytest.raises(ValueError, match="params must be a DetectionParams, got dict"):
        attach_detections(Fake(), seq, {"miss_rate": 0.0})
    no_gt = InMemorySequence(
        name="v",
        frame_rate=25,
        width=32,
        height=24,
        template_size=6,
        frames=[np.zeros((24, 32, 3), np.uint8)],
    )
    with pytest.raises(ValueError, match="no ground truth"):
        attach_detections(Fake(), no_gt)
