"""The papers' accuracy metric, TrackEval CLEAR/IDF1/HOTA and MOT point I/O."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker.metrics import (
    THRESHOLDS,
    accuracy_curve,
    evaluate,
    format_table,
    plot_accuracy,
    point_errors,
    trackeval_metrics,
)
from tracker.mot_io import (
    births_from_ground_truth,
    births_from_points,
    mot_rows_to_tracks,
    read_points_csv,
    tracks_to_mot_rows,
)


def _gt(t=6, n=4, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(20, 200, (t, n, 2))
    pts[:2, 3] = np.nan  # id 4 enters at frame 2
    return np.arange(1, n + 1), pts


def test_accuracy_curve_exact():
    ids, gt = _gt()
    tr = gt.copy()
    tr[:, 0] += [3.0, 4.0]  # id 1 off by exactly 5 px everywhere
    tr[4:, 1] = np.nan  # id 2 lost for the last two frames
    curve = accuracy_curve(ids, gt, ids, tr)
    total = np.isfinite(gt).all(-1).sum()  # 22 points
    assert curve.shape == (26,)
    assert curve[4] == pytest.approx(100 * (total - 6 - 2) / total)
    assert curve[5] == pytest.approx(100 * (total - 2) / total)  # "within" includes 5 px
    assert curve[25] == curve[5]
    assert (np.diff(curve) >= 0).all()


def test_ids_are_matched_not_nearest_points():
    ids, gt = _gt()
    swapped = gt[:, [1, 0, 2, 3]]
    curve = accuracy_curve(ids, gt, ids, swapped)
    err = point_errors(ids, gt, ids, swapped)
    assert np.isinf(err).sum() == 0 and (err[:, 2] == 0).all() and (err[:, 0] > 0).all()
    assert curve[0] < 100


def test_missing_ids_frames_and_unknown_ids():
    ids, gt = _gt()
    assert accuracy_curve(ids, gt, ids[:0], np.zeros((6, 0, 2)))[25] == 0
    assert accuracy_curve(ids, gt, ids, gt[:3])[0] < 100  # shorter tracks are padded
    with pytest.raises(ValueError, match="unknown to the ground truth"):
        accuracy_curve(ids, gt, np.array([1, 99]), gt[:, :2], strict=True)
    with pytest.raises(ValueError, match="frames"):
        accuracy_curve(ids, gt, ids, np.concatenate([gt, gt]))
    empty = accuracy_curve(ids[:0], np.zeros((3, 0, 2)), ids[:0], np.zeros((3, 0, 2)))
    assert (empty == 0).all()


def test_trackeval_perfect_and_degraded():
    ids, gt = _gt(t=10, n=6)
    perfect = trackeval_metrics(ids, gt, ids, gt)
    assert perfect["mota"] == pytest.approx(100) and perfect["idf1"] == pytest.approx(100)
    assert perfect["hota"] == pytest.approx(100) and perfect["idsw"] == 0
    tr = gt.copy()
    tr[5:, [0, 1]] = gt[5:, [1, 0]]  # identity switch halfway
    tr[:, 2] += 30.0  # far off: a miss and a false positive in every frame
    r = trackeval_metrics(ids, gt, ids, tr)
    assert r["idsw"] == 2
    assert r["mota"] < 100 and r["idf1"] < 100 and r["hota"] < 100


def test_evaluate_report_and_table(tmp_path):
    ids, gt = _gt()
    rep = evaluate(ids, gt, ids, gt)
    for key in ("acc@5", "acc@15", "mota", "idf1", "hota", "curve"):
        assert key in rep
    assert [c["T"] for c in rep["curve"]] == list(THRESHOLDS)
    assert "acc@15" in format_table({"bqp": rep})
    plot_accuracy({"bqp": [c["acc"] for c in rep["curve"]], "ncc": np.linspace(0, 90, 26)},
                  tmp_path / "curve.png")
    assert (tmp_path / "curve.png").read_bytes()[:4] == b"\x89PNG"


def test_mot_rows_round_trip_and_errors():
    ids, gt = _gt()
    rows = tracks_to_mot_rows(ids, gt, 10)
    assert rows.shape == (np.isfinite(gt).all(-1).sum(), 10)
    back_ids, back = mot_rows_to_tracks(rows, length=6)
    np.testing.assert_array_equal(back_ids, ids)
    np.testing.assert_allclose(back, gt)
    with pytest.raises(ValueError, match="outside the sequence"):
        mot_rows_to_tracks(rows, length=4)
    with pytest.raises(ValueError, match="appears twice"):
        mot_rows_to_tracks(np.concatenate([rows, rows[:1]]), length=6)


def test_points_csv(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("frame,id,x,y\n1,5,10,12\n1,6,30,40\n3,9,50,60\n")
    frames, ids, pts = read_points_csv(p)
    (i_ids, i_pts), births = births_from_points(frames, ids, pts)
    assert i_ids.tolist() == [5, 6] and list(births) == [2]
    assert births[2][0].tolist() == [9]
    p.write_text("id,x,y\n1,2,3\n")
    assert read_points_csv(p)[0].tolist() == [1]
    for text, msg in [("", "empty"), ("a,b\n", "header"), ("id,x,y\n1,2\n", "columns"),
                      ("id,x,y\n1,two,3\n", "non-numeric"), ("id,x,y\n1,2,3\n1,4,5\n", "once")]:
        p.write_text(text)
        with pytest.raises(ValueError, match=msg):
            read_points_csv(p)


def test_births_from_ground_truth():
    ids, gt = _gt()
    (i_ids, i_pts), births = births_from_ground_truth(ids, gt)
    assert i_ids.tolist() == [1, 2, 3]
    assert list(births) == [2] and births[2][0].tolist() == [4]
    np.testing.assert_allclose(births[2][1], gt[2, [3]])


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(0, 5), st.integers(0, 2**31 - 1), st.floats(0, 40))
def test_accuracy_curve_properties(t, n, seed, noise):
    rng = np.random.default_rng(seed)
    gt = rng.uniform(0, 100, (t, n, 2))
    gt[rng.random((t, n)) < 0.2] = np.nan
    tr = gt + rng.normal(0, noise, gt.shape)
    tr[rng.random((t, n)) < 0.2] = np.nan
    ids = np.arange(n)
    curve = accuracy_curve(ids, gt, ids, tr)
    assert ((curve >= 0) & (curve <= 100)).all() and (np.diff(curve) >= 0).all()
    assert accuracy_curve(ids, gt, ids, gt)[0] == (100.0 if np.isfinite(gt).any() else 0.0)
    rows = tracks_to_mot_rows(ids, tr, 10)
    back_ids, back = mot_rows_to_tracks(rows, length=t)
    full = np.full_like(tr, np.nan)
    cols = np.searchsorted(ids, back_ids)
    full[:, cols] = back
    np.testing.assert_allclose(full, tr)
