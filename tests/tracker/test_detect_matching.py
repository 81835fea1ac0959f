"""Point matching of head detections (tracker.detect.matching): hand-built scenes with exact
pairs, the radius boundary, empty and NaN inputs, accumulation over frames, and a property
test against brute force."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker.detect.matching import DetectionScore, match_points, score_frame


def _as_lists(result):
    p, g, d = result
    return p.tolist(), g.tolist(), np.round(d, 9).tolist()


def test_optimal_total_distance_where_greedy_is_worse():
    # Nearest-first would take pred 0 - gt 0 (1.4), leaving pred 1 - gt 1 at 4.7: total 6.1.
    # The optimum crosses over: pred 0 - gt 1 (1.7) + pred 1 - gt 0 (1.6) = 3.3.
    pred = [[0.0, 0.0], [3.0, 0.0]]
    gt = [[1.4, 0.0], [-1.7, 0.0]]
    assert _as_lists(match_points(pred, gt, 5.0)) == ([0, 1], [1, 0], [1.7, 1.6])


def test_maximum_cardinality_before_distance():
    # Nearest-first takes pred 0 - gt 0 (1.9) and strands pred 1 (gt 1 is 7 px away): 1 pair.
    # Two pairs exist: pred 0 - gt 1 (3.0) and pred 1 - gt 0 (2.1), though their sum is larger.
    pred = [[0.0, 0.0], [4.0, 0.0]]
    gt = [[1.9, 0.0], [-3.0, 0.0]]
    assert _as_lists(match_points(pred, gt, 5.0)) == ([0, 1], [1, 0], [3.0, 2.1])
    score = score_frame(pred, gt, 5.0)
    assert (score.tp, score.fp, score.fn) == (2, 0, 0)
    assert score.error_sum_px == pytest.approx(5.1)


def test_radius_is_inclusive():
    pred = [[0.0, 0.0]]
    assert _as_lists(match_points(pred, [[3.0, 4.0]], 5.0)) == ([0], [0], [5.0])
    assert _as_lists(match_points(pred, [[3.0, 4.0001]], 5.0)) == ([], [], [])
    assert _as_lists(match_points(pred, [[3.0, 4.0]], 4.999)) == ([], [], [])


def test_each_point_matched_once():
    # Two predictions on one head: one is a true positive, the other a false alarm.
    pred = [[10.0, 10.0], [11.0, 10.0], [40.0, 40.0]]
    gt = [[10.5, 10.0]]
    p, g, d = match_points(pred, gt, 5.0)
    assert len(p) == 1 and g.tolist() == [0] and d.tolist() == [0.5]
    s = score_frame(pred, gt, 5.0)
    assert (s.tp, s.fp, s.fn) == (1, 2, 0)


@pytest.mark.parametrize(
    ("pred", "gt", "counts", "precision", "recall", "f1"),
    [
        ([], [], (0, 0, 0), 1.0, 1.0, 1.0),
        (np.zeros((0, 2)), [[1.0, 2.0]], (0, 0, 1), 1.0, 0.0, 0.0),
        ([[1.0, 2.0]], np.zeros((0, 2)), (0, 1, 0), 0.0, 1.0, 0.0),
        ([[1.0, 2.0]], [[np.nan, np.nan]], (0, 1, 0), 0.0, 1.0, 0.0),
        ([[0.0, 0.0]], [[50.0, 0.0]], (0, 1, 1), 0.0, 0.0, 0.0),
    ],
)
def test_empty_inputs(pred, gt, counts, precision, recall, f1):
    p, g, d = match_points(pred, gt)
    assert p.shape == g.shape == d.shape == (0,)
    assert p.dtype == g.dtype == np.int64
    s = score_frame(pred, gt)
    assert (s.tp, s.fp, s.fn) == counts
    assert (s.precision, s.recall, s.f1) == (precision, recall, f1)
    assert math.isnan(s.mean_error_px)


def test_nan_gt_rows_are_ignored_and_indices_kept():
    # Pred 2 is near the origin, where a NaN turned into 0 would wrongly be matched.
    pred = [[5.0, 5.0], [20.0, 20.0], [0.0, 1.0]]
    gt = [[np.nan, np.nan], [20.0, 21.0], [np.nan, np.nan], [5.0, 7.0]]
    assert _as_lists(match_points(pred, gt)) == ([0, 1], [3, 1], [2.0, 1.0])
    s = score_frame(pred, gt)
    assert s == DetectionScore(tp=2, fp=1, fn=0, error_sum_px=3.0)
    assert s.mean_error_px == 1.5


@pytest.mark.parametrize(
    ("pred", "gt", "radius", "match"),
    [
        ([[np.nan, 1.0]], [[1.0, 1.0]], 5.0, "pred must be finite"),
        ([[1.0, 1.0]], [[np.nan, 1.0]], 5.0, "gt must be finite or NaN in both"),
        ([[1.0, 1.0]], [[np.inf, 1.0]], 5.0, "gt must be finite or NaN in both"),
        ([1.0, 1.0, 2.0], [[1.0, 1.0]], 5.0, r"pred must have shape \(k, 2\)"),
        ([[1.0, 1.0]], [[1.0, 1.0]], 0.0, "match_points.radius must be"),
        ([[1.0, 1.0]], [[1.0, 1.0]], float("nan"), "match_points.radius must be"),
    ],
)
def test_bad_input(pred, gt, radius, match):
    with pytest.raises(ValueError, match=match):
        match_points(pred, gt, radius)


def test_scores_accumulate_over_frames():
    f1 = score_frame([[0.0, 0.0], [9.0, 9.0]], [[1.0, 0.0]])  # tp 1, fp 1
    f2 = score_frame([[0.0, 0.0]], [[0.0, 3.0], [30.0, 30.0], [60.0, 0.0]])  # tp 1, fn 2
    total = f1 + f2
    assert total == DetectionScore(tp=2, fp=1, fn=2, error_sum_px=4.0)
    assert sum([f1, f2]) == total  # builtin sum starts from 0
    # Pooled counts, not the mean of per-frame ratios (which would be (0.5 + 1) / 2).
    assert total.precision == pytest.approx(2 / 3)
    assert total.recall == pytest.approx(2 / 4)
    assert total.f1 == pytest.approx(2 * (2 / 3) * 0.5 / (2 / 3 + 0.5))
    assert total.mean_error_px == 2.0


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"tp": -1}, "tp"),
        ({"fp": 1.5}, "fp"),
        ({"fn": float("nan")}, "fn"),
        ({"error_sum_px": -0.1}, "error_sum_px"),
    ],
)
def test_score_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=f"DetectionScore.{field} must be"):
        DetectionScore(**kwargs)


def test_thousands_of_points():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0, [1280, 720], (5000, 2))
    pred = gt + rng.normal(0.0, 1.0, gt.shape)
    p, g, d = match_points(pred, gt, 5.0)
    assert len(np.unique(p)) == len(p) and len(np.unique(g)) == len(g)
    assert len(p) >= 4990 and d.max() <= 5.0


def _brute_force(pred: np.ndarray, gt: np.ndarray, radius: float) -> tuple[int, float]:
    """(largest number of pairs, smallest total distance among matchings of that size)."""
    d = np.hypot(*(pred[:, None, :] - gt[None, :, :]).transpose(2, 0, 1))
    best = (0, 0.0)

    def walk(i: int, used: frozenset, k: int, total: float) -> None:
        nonlocal best
        if i == len(pred):
            if k > best[0] or (k == best[0] and total < best[1]):
                best = (k, total)
            return
        walk(i + 1, used, k, total)
        for j in range(len(gt)):
            if j not in used and d[i, j] <= radius:
                walk(i + 1, used | {j}, k + 1, total + d[i, j])

    walk(0, frozenset(), 0, 0.0)
    return best


_coords = st.lists(
    st.tuples(st.integers(0, 12), st.integers(0, 12)).map(lambda t: (t[0] / 2, t[1] / 2)),
    max_size=6,
)


@settings(max_examples=200, deadline=None)
@given(pred=_coords, gt=_coords, radius=st.sampled_from([1.0, 2.0, 2.5, 4.0]))
def test_matching_agrees_with_brute_force(pred, gt, radius):
    pred = np.array(pred, dtype=float).reshape(-1, 2)
    gt = np.array(gt, dtype=float).reshape(-1, 2)
    p, g, d = match_points(pred, gt, radius)
    assert len(set(p.tolist())) == len(p) and len(set(g.tolist())) == len(g)  # one-to-one
    assert np.allclose(d, np.hypot(*(pred[p] - gt[g]).T))
    assert np.all(d <= radius)
    k, total = _brute_force(pred, gt, radius)
    assert len(p) == k
    assert d.sum() == pytest.approx(total, abs=1e-9)


LOOPED = [
    # five predictions (two at one spot) against three heads within 4 px
    ([[0.5, 3.5], [2.5, 4.5], [2.5, 4.5], [5.0, 0.5], [2.5, 0.0]], [[1, 4], [6, 5], [2, 2.5]], 4.0),
    (
        [[4, 2], [2, 5], [3, 2.5], [1.5, 1.5], [3, 3], [0.5, 1.5]],
        [[5.5, 5.5], [5.5, 4], [5, 1.5], [0.5, 5], [2.5, 3], [2.5, 2.5]],
        4.0,
    ),
]


def test_matching_returns_on_scenes_where_the_solver_looped_on_fractional_costs():
    """SciPy's LAPJVsp never returned on these scenes with the distances as costs; whole-number
    costs make it exact. In a child process, so that a regression fails instead of hanging."""
    code = (
        "from tracker.detect.matching import match_points\n"
        f"for pred, gt, radius in {LOOPED!r}:\n"
        "    p, g, d = match_points(pred, gt, radius)\n"
        "    print(len(p), round(float(d.sum()), 9))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    want = [_brute_force(np.array(p, float), np.array(g, float), r) for p, g, r in LOOPED]
    assert out.stdout.split() == [v for k, t in want for v in (str(k), str(round(t, 9)))]


def test_the_most_pairs_come_first_even_through_an_augmenting_path():
    """Prediction 0 is nearer head 1 (1 px) than head 0 (4 px), but only taking head 0 lets
    prediction 1 pair too: two pairs at 4 px beat one at 1 px."""
    p, g, d = match_points([[4.0, 0.0], [9.0, 0.0]], [[0.0, 0.0], [5.0, 0.0]], radius=4.0)
    assert (p.tolist(), g.tolist(), d.tolist()) == ([0, 1], [0, 1], [4.0, 4.0])
