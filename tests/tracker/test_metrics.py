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
    map_track_ids,
    mapped_positions,
    plot_accuracy,
    point_errors,
    trackeval_metrics,
)
from tracker.mot_io import mot_rows_to_tracks, tracks_to_mot_rows


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
    plot_accuracy(
        {"bqp": [c["acc"] for c in rep["curve"]], "ncc": np.linspace(0, 90, 26)},
        tmp_path / "curve.png",
    )
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


# ---------------------------------------------------------------- any track ids (own-id trackers)
def test_perfect_tracker_with_its_own_ids():
    ids, gt = _gt(t=10, n=6)
    own = np.array([70, 3, 900, 41, 5, 12])  # relabelled; 3 and 5 even collide with gt ids
    rep = evaluate(ids, gt, own, gt, id_mapping="majority")
    assert rep["mota"] == pytest.approx(100) and rep["idf1"] == pytest.approx(100)
    assert rep["hota"] == pytest.approx(100) and rep["idsw"] == 0
    assert rep["acc@5"] == 100.0 and rep["curve"][0]["acc"] == 100.0
    assert rep["id_mapping"] == "majority"
    # "auto" maps as soon as one id is unknown; "same" takes the ids at their word
    assert evaluate(ids, gt, own, gt)["id_mapping"] == "majority"
    same = evaluate(ids, gt, own, gt, id_mapping="same", strict=False)
    assert same["acc@15"] < 50 and same["mota"] == rep["mota"]
    with pytest.raises(ValueError, match="unknown to the ground truth"):
        evaluate(ids, gt, own, gt, id_mapping="same", strict=True)
    with pytest.raises(ValueError, match="id_mapping"):
        evaluate(ids, gt, own, gt, id_mapping="nearest")


def test_one_id_switch_with_own_ids():
    """Person 1 is followed by track 100, then by a new track 101: one IDSW."""
    ids = np.array([1, 2])
    gt = np.stack(
        [
            np.stack([np.arange(10.0), np.full(10, 20.0)], 1),
            np.stack([np.arange(10.0), np.full(10, 80.0)], 1),
        ],
        axis=1,
    )  # (10, 2, 2)
    tr = np.full((10, 3, 2), np.nan)
    tr[:5, 0] = gt[:5, 0]
    tr[5:, 1] = gt[5:, 0]
    tr[:, 2] = gt[:, 1] + [1.0, 0.0]
    rep = evaluate(ids, gt, [100, 101, 102], tr)
    assert rep["idsw"] == 1 and rep["mota"] == pytest.approx(100 * (1 - 1 / 20))
    assert rep["curve"][1]["acc"] == 100.0  # both tracks map to person 1
    best, votes = map_track_ids(ids, gt, [100, 101, 102], tr)
    assert best.tolist() == [1, 1, 2] and votes.tolist() == [5, 5, 10]


def test_majority_vote_and_mapped_positions_exact():
    gt_ids = np.array([7, 8])
    gt = np.zeros((4, 2, 2))
    gt[:, 1, 0] = 100.0
    tr = np.full((4, 3, 2), np.nan)
    tr[:, 0] = gt[:, 0] + [3.0, 0.0]  # follows 7 all along
    tr[:3, 1] = gt[:3, 1] + [0.0, 4.0]  # follows 8 for three frames...
    tr[3, 1] = gt[3, 0]  # ...then jumps onto 7 (votes 3 : 1 -> stays 8)
    tr[1:3, 2] = gt[1:3, 0] + [0.0, 1.0]  # a second, weaker track on 7 (2 votes)
    tr[0, 2] = [500.0, 500.0]  # far from everyone: no vote
    best, votes = map_track_ids(gt_ids, gt, [0, 1, 2], tr)
    assert best.tolist() == [7, 8, 7] and votes.tolist() == [4, 3, 2]
    pos = mapped_positions(gt_ids, gt, [0, 1, 2], tr)
    np.testing.assert_array_equal(pos[:, 0], tr[:, 0])  # 7: the 4-vote track wins every frame
    np.testing.assert_array_equal(pos[:3, 1], tr[:3, 1])
    np.testing.assert_array_equal(pos[3, 1], gt[3, 0])  # 8: its track, wherever it went
    curve = accuracy_curve(gt_ids, gt, [0, 1, 2], tr, id_mapping="majority")
    assert curve[2] == 0.0 and curve[3] == pytest.approx(50.0)
    assert curve[4] == pytest.approx(7 / 8 * 100) and curve[25] == pytest.approx(7 / 8 * 100)
    far = map_track_ids(gt_ids, gt, [0], tr[:, 2:] + 100.0)
    assert far[0].tolist() == [-1] and far[1].tolist() == [0]
    assert np.isnan(mapped_positions(gt_ids, gt, [0], tr[:, 2:] + 100.0)).all()


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 6), st.integers(1, 5), st.integers(0, 2**31 - 1))
def test_clear_idf1_hota_do_not_depend_on_the_ids(t, n, seed):
    rng = np.random.default_rng(seed)
    gt = rng.uniform(0, 200, (t, n, 2))
    gt[rng.random((t, n)) < 0.2] = np.nan
    tr = gt + rng.normal(0, 3, gt.shape)
    tr[rng.random((t, n)) < 0.2] = np.nan
    ids = np.arange(n)
    own = rng.permutation(np.arange(1000, 1000 + n))
    a = trackeval_metrics(ids, gt, ids, tr)
    b = trackeval_metrics(ids, gt, own, tr)
    assert a == pytest.approx(b)
