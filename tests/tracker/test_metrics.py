"""The papers' accuracy metric, TrackEval CLEAR/IDF1/HOTA and MOT point I/O."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker.metrics import (
    SIMILARITY_SCALE,
    THRESHOLDS,
    accuracy_curve,
    evaluate,
    format_table,
    map_track_ids,
    mapped_positions,
    plot_accuracy,
    point_errors,
    resolve_id_mapping,
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
    far = np.array([[1e12, 1, 0, 0, 5, 5, 1, -1, -1]])  # asked for 14.6 TiB of NaN
    with pytest.raises(ValueError, match="tracks of 1 ids over 1000000000000 frames needs"):
        mot_rows_to_tracks(far)


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
    own = np.array([70, 3, 900, 41, 2, 12])  # relabelled; 3 and 2 collide with gt ids
    rep = evaluate(ids, gt, own, gt, id_mapping="majority")
    assert rep["mota"] == pytest.approx(100) and rep["idf1"] == pytest.approx(100)
    assert rep["hota"] == pytest.approx(100) and rep["idsw"] == 0
    assert rep["acc@5"] == 100.0 and rep["curve"][0]["acc"] == 100.0
    assert rep["id_mapping"] == "majority"
    # "auto" maps: the two known ids (3 and 2) lie on persons 2 and 5, not on their own;
    # "same" takes the ids at their word
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


# ---------------------------------------------------------------- hand-computed metric wiring
def _one_person_off_then_lost():
    """Two people over 4 frames: A (id 1) tracked exactly; B (id 2) tracked 5 px off in
    frames 0-1, then lost (no tracked point) in frames 2-3."""
    ids = np.array([1, 2])
    gt = np.zeros((4, 2, 2))
    gt[:, 0] = np.stack([10.0 + np.arange(4), np.full(4, 20.0)], 1)
    gt[:, 1] = np.stack([np.full(4, 100.0), 60.0 + 2 * np.arange(4)], 1)
    tr = gt.copy()
    tr[:2, 1] += [3.0, 4.0]  # 5 px off
    tr[2:, 1] = np.nan  # lost
    return ids, gt, tr


def test_metrics_on_a_hand_computed_degraded_case():
    """Every metric by hand, at the documented similarity max(0, 1 - d / T_sim), T_sim = 15.

    B's two tracked points have similarity s = 1 - 5/15 = 2/3 (>= 0.5: CLEAR and IDF1 match
    them). 8 gt points, 6 tracked, none false: MOTA = 1 - 2/8; MOTP = mean similarity of the
    matches = (4 + 2 s) / 6 = 8/9; IDF1 = 2 IDTP / (2 IDTP + IDFN + IDFP) = 12 / 14.
    HOTA at each alpha of 0.05 .. 0.95 (19): for alpha <= 2/3 (13 alphas) DetA = 6/8 and
    AssA = (4 * 4/4 + 2 * 2/4) / 6 = 5/6 (B's track covers 2 of B's 4 points); above (6
    alphas) B's matches drop: TP 4, FN 4, FP 2, DetA = 4/10, AssA = 1. HOTA = sqrt(DetA AssA)
    averaged over the alphas. acc@T: A's 4 points at 0 px, B's 2 at 5 px, 2 untracked."""
    ids, gt, tr = _one_person_off_then_lost()
    rep = evaluate(ids, gt, ids, tr)
    assert SIMILARITY_SCALE == 15.0 and rep["similarity_px"] == 15.0
    s = 1 - 5 / 15
    assert rep["mota"] == pytest.approx(100 * (1 - 2 / 8))
    assert rep["motp"] == pytest.approx(100 * (4 + 2 * s) / 6)
    assert rep["idf1"] == pytest.approx(100 * 12 / 14)
    low, high = 13, 6
    hota = (low * np.sqrt(6 / 8 * 5 / 6) + high * np.sqrt(4 / 10 * 1.0)) / 19
    assert rep["hota"] == pytest.approx(100 * hota)
    assert rep["deta"] == pytest.approx(100 * (low * 6 / 8 + high * 4 / 10) / 19)
    assert rep["assa"] == pytest.approx(100 * (low * 5 / 6 + high * 1.0) / 19)
    assert (rep["idsw"], rep["mt"], rep["ml"], rep["frag"]) == (0, 1, 0, 0)
    curve = [c["acc"] for c in rep["curve"]]
    assert curve[:6] == [50.0, 50.0, 50.0, 50.0, 50.0, 75.0] and curve[25] == 75.0
    assert rep["acc@5"] == 75.0 and rep["acc@15"] == 75.0
    assert rep["id_mapping"] == "same" and rep["unknown_ids"] == 0
    # the similarity scale is the one asked for: at T_sim = 30, s = 5/6
    wide = evaluate(ids, gt, ids, tr, similarity_scale=30.0)
    assert wide["motp"] == pytest.approx(100 * (4 + 2 * 5 / 6) / 6)


@pytest.mark.parametrize("mapping", ["auto", "same", "majority"])
def test_track_ids_in_unsorted_order_change_no_metric(mapping):
    ids, gt, tr = _one_person_off_then_lost()
    want = evaluate(ids, gt, ids, tr, id_mapping=mapping)
    for order in ([1, 0], [0, 1]):
        got = evaluate(ids, gt, ids[order], tr[:, order], id_mapping=mapping)
        assert got == want, order
    # own ids (not the ground truth's), unsorted: the same figures under majority mapping
    own = evaluate(ids, gt, np.array([907, 15]), tr[:, [1, 0]], id_mapping="majority")
    assert {k: v for k, v in own.items() if k != "id_mapping"} == {
        k: v
        for k, v in evaluate(ids, gt, ids, tr, id_mapping="majority").items()
        if k != "id_mapping"
    }


# ------------------------------------------------------- result ids unknown to the ground truth
def _drifting_scene():
    """Five people far apart over 6 frames. Tracks 1-4 sit on their own person; track 5
    follows person 5 for 2 frames, then sits 2 px from person 4 for 4 frames. With the ids
    taken as they are, acc@15 = (24 + 2) / 30; a majority mapping gives track 5 to person 4
    (4 votes to 2) and leaves person 5 untracked: 24 / 30."""
    ids = np.arange(1, 6)
    gt = np.zeros((6, 5, 2))
    gt[..., 0] = 100.0 * ids
    gt[..., 1] = 50.0 + np.arange(6)[:, None]
    tr = gt.copy()
    tr[2:, 4] = gt[2:, 3] + [2.0, 0.0]
    return ids, gt, tr


def test_one_unknown_id_keeps_the_known_ids_scored_as_known():
    ids, gt, tr = _drifting_scene()
    same = evaluate(ids, gt, ids, tr)
    assert same["id_mapping"] == "same" and same["acc@15"] == pytest.approx(100 * 26 / 30)
    assert evaluate(ids, gt, ids, tr, id_mapping="majority")["acc@15"] == pytest.approx(80.0)
    for stray in (99, -1, 0):  # one stray row with an id the ground truth does not know
        extra = np.full((6, 1, 2), np.nan)
        extra[3, 0] = [250.0, 53.0]
        rep = evaluate(ids, gt, np.r_[ids, stray], np.concatenate([tr, extra], 1))
        assert rep["id_mapping"] == "same", stray
        assert rep["unknown_ids"] == 1
        assert rep["acc@15"] == pytest.approx(100 * 26 / 30), stray  # the stray is unmatched
        assert rep["curve"] == same["curve"]
    # asking for "same" strictly still refuses unknown ids
    with pytest.raises(ValueError, match="unknown to the ground truth"):
        evaluate(ids, gt, np.r_[ids, 99], np.concatenate([tr, extra], 1), id_mapping="same")


def test_own_ids_stay_on_majority_mapping():
    ids, gt, tr = _drifting_scene()
    exact = gt.copy()
    # ByteTrack-style ids 0, 1, 2, ...: four of them are ground-truth ids by number only
    shifted = ids - 1
    rep = evaluate(ids, gt, shifted, exact)
    assert rep["id_mapping"] == "majority" and rep["unknown_ids"] == 0
    assert rep["curve"][0]["acc"] == 100.0  # each track mapped to the person it sits on
    # all ids unknown: majority as well
    assert evaluate(ids, gt, ids + 1000, exact)["id_mapping"] == "majority"
    assert resolve_id_mapping(ids, shifted, "auto", gt, exact) == "majority"
    assert resolve_id_mapping(ids, np.r_[ids, -1], "auto", gt, np.concatenate(
        [exact, exact[:, :1]], 1)) == "same"  # fmt: skip
    with pytest.raises(ValueError, match="needs the points"):
        resolve_id_mapping(ids, shifted, "auto")


def test_majority_map_ties_go_to_the_earlier_person_and_the_earlier_track():
    """A track with as many votes for two people maps to the earlier gt column; two tracks
    with as many votes for one person: the earlier track gives the person's position."""
    gt = np.array([[[0.0, 0.0], [100.0, 0.0]], [[0.0, 0.0], [100.0, 0.0]]])
    ids, votes = map_track_ids([7, 8], gt, [0], np.array([[[1.0, 0.0]], [[101.0, 0.0]]]))
    assert ids.tolist() == [7] and votes.tolist() == [1]
    one = np.array([[[0.0, 0.0]], [[0.0, 0.0]]])
    two = np.array([[[1.0, 0.0], [2.0, 0.0]], [[1.0, 0.0], [2.0, 0.0]]])
    assert mapped_positions([7], one, [0, 1], two).tolist() == [[[1.0, 0.0]], [[1.0, 0.0]]]


def test_mot_rows_take_the_centre_of_non_square_boxes():
    """A MOT row's point is its box centre: (x + w / 2, y + h / 2), h not w for y."""
    rows = np.array(
        [[1, 7, 6.0, 16.0, 8.0, 12.0, 1, -1, -1, -1], [2, 7, 7.0, 10.0, 4.0, 2.0, 1, -1, -1, -1]]
    )
    ids, pos = mot_rows_to_tracks(rows)
    assert ids.tolist() == [7]
    np.testing.assert_array_equal(pos[:, 0], [[10.0, 22.0], [9.0, 11.0]])


def test_mot_rows_reject_frame_zero():
    """MOT frames are 1-based: a frame-0 row is refused, not read as the last frame."""
    rows = np.array(
        [[0, 1, 0.0, 0.0, 8.0, 8.0, 1, -1, -1, -1], [2, 1, 0.0, 0.0, 8.0, 8.0, 1, -1, -1, -1]]
    )
    with pytest.raises(ValueError, match=r"frame 0 is outside the sequence \(1..2\)"):
        mot_rows_to_tracks(rows)


def test_mot_rows_refuse_a_fractional_or_missing_frame():
    """Frame 1.5 is refused by name, not truncated to frame 1; so is a NaN frame."""
    for frame in (1.5, np.nan):
        rows = np.array([[frame, 1, 0.0, 0.0, 8.0, 8.0, 1, -1, -1, -1]])
        with pytest.raises(ValueError, match=r"row 1: frame .* is not a whole number"):
            mot_rows_to_tracks(rows)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda gt: evaluate([1, 2], gt, [1.2, 1.7], gt), "tr_ids: 1.2 is not a whole number"),
        (
            lambda gt: accuracy_curve([1, 2], gt, [1, 1], gt, thresholds=[0]),
            "tr_ids: id 1 appears more than once",
        ),
        (lambda gt: evaluate([np.nan, 2], gt, [1, 2], gt), "gt_ids: nan is not a whole number"),
        (lambda gt: evaluate([1, 2], gt, [1e30, 2], gt), "tr_ids: 1e+30 is not a whole number"),
        (
            lambda gt: accuracy_curve([1, 2], gt, [1, 2], gt, thresholds=[np.nan, 5]),
            "thresholds must be a 1-D array of finite px",
        ),
        (
            lambda gt: accuracy_curve([1, 2], gt, [1, 2], gt, thresholds="5"),
            "thresholds must be a 1-D array of finite px",
        ),
    ],
)
def test_ids_that_are_not_distinct_whole_numbers_are_refused_by_name(call, message):
    """Two tracks with ids 1.2 and 1.7 had both become track 1 after the duplicate check,
    and scored 100 %: ids are refused, never truncated or wrapped."""
    import re

    gt = np.array([[[10.0, 10.0], [50.0, 50.0]]] * 3)
    with pytest.raises(ValueError, match=re.escape(message)):
        call(gt)
    assert evaluate([1, 2], gt, [1.0, 2.0], gt)["acc@5"] == 100.0  # whole floats are ids


def test_mot_rows_that_are_not_boxes_are_refused_by_name():
    """Fewer than 6 columns, a 1-D row, a NaN or empty box, a negative or fractional length:
    one message naming the row or the argument (an IndexError, a half-NaN point, or a
    silently truncated length before)."""
    import re

    good = tracks_to_mot_rows(np.array([7]), np.array([[[10.0, 20.0]]]), 8)
    for rows, length, message in [
        (good[:, :5], None, "MOT rows need at least 6 columns"),
        (good[0], None, "MOT rows need at least 6 columns"),
        (np.r_[good[0, :4], np.nan, 8.0][None], None, "row 1: box [6.0, 16.0, nan, 8.0]"),
        (np.r_[good[0, :4], 0.0, 8.0][None], None, "is not a finite box of positive size"),
        (good, -1, "length must be"),
        (good, 3.5, "length must be"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            mot_rows_to_tracks(rows, length)
    for ids, size, message in [
        ([1.5], 8, "ids: 1.5 is not a whole number"),
        ([7], 0, "template_size must be"),
        ([7], float("nan"), "template_size must be"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            tracks_to_mot_rows(np.array(ids), np.array([[[10.0, 20.0]]]), size)


def test_a_target_id_beyond_int64_is_refused_not_wrapped():
    from tracker.registry import make_tracker

    frame = np.zeros((20, 20, 3), np.uint8)
    for ids in ([1e30], np.array([2**63 + 5], np.uint64)):
        with pytest.raises(ValueError, match="beyond int64"):
            make_tracker("ncc").init(frame, ids, np.array([[5.0, 5.0]]), 8)


def test_trackeval_tables_are_sized_before_they_are_built():
    """3,500 people in each of 100 frames: TrackEval's dense tables would need about 12.8
    GiB; refused with the estimate at once (a stress sequence had run out of memory)."""
    import time

    from tracker.metrics import trackeval_bytes, trackeval_metrics

    ids = np.arange(3500)
    pts = np.zeros((100, 3500, 2))
    assert trackeval_bytes(pts, pts) == 8 * (
        100 * 3500**2 + 6 * 3500**2 + 22 * 3500**2 + 12 * 3500**2
    )
    t0 = time.perf_counter()
    with pytest.raises(
        ValueError, match=r"of 100 frames with 3500 people and 3500 tracks need about 12\.8 GiB"
    ):
        trackeval_metrics(ids, pts, ids, pts)
    assert time.perf_counter() - t0 < 5
    small = trackeval_bytes(pts[:2, :10], pts[:2, :10])  # ids present in no frame count 0
    assert small == 8 * (2 * 100 + 6 * 100 + 22 * 100 + 3 * 20**2)


def test_known_id_numbers_on_other_people_are_mapped_by_majority():
    """A head detector's 1..N and an annotator's 1..N share their numbers by chance: when
    every track id is a ground-truth id but follows another person, auto maps by majority
    (it had scored acc@5 1.3 % against MOTA 95.5 % on such a file)."""
    from tracker.metrics import evaluate

    t = np.arange(6.0)[:, None]
    gt = np.stack([np.hstack([10 + t, 0 * t + 10]), np.hstack([10 + t, 0 * t + 60])], axis=1)
    rep = evaluate([1, 2], gt, [2, 1], gt, id_mapping="auto")
    assert rep["id_mapping"] == "majority" and rep["acc@5"] == 100.0
    same = evaluate([1, 2], gt, [1, 2], gt, id_mapping="auto")
    assert same["id_mapping"] == "same" and same["acc@5"] == 100.0
    far = gt + 100.0  # known ids near nobody: no evidence, taken at their word
    assert evaluate([1, 2], gt, [1, 2], far, id_mapping="auto")["id_mapping"] == "same"


def test_auto_mapping_judges_known_ids_where_their_tracks_start():
    """Two people 100 px apart whose tracks (the people's own ids) swap from the second frame
    on: only frame 1 is right, acc@15 10 %. Judged on every frame, the ids had looked like a
    tracker's own and the majority vote scored 90 %; swapping later scored lower than that."""
    t = 10
    gt = np.zeros((t, 2, 2))
    gt[:, 1, 0] = 100.0
    swapped = gt[:, ::-1].copy()
    swapped[0] = gt[0]
    rep = evaluate([1, 2], gt, [1, 2], swapped, trackeval=False)
    assert rep["id_mapping"] == "same" and rep["acc@15"] == pytest.approx(10.0)
    later = gt[:, ::-1].copy()
    later[:2] = gt[:2]
    assert evaluate([1, 2], gt, [1, 2], later, trackeval=False)["acc@15"] == pytest.approx(20.0)
    # a tracker's own 0, 1 start on the people 1, 2: not their ids, majority vote
    assert evaluate([1, 2], gt, [0, 1], gt, trackeval=False)["id_mapping"] == "majority"


def test_acc_at_t_never_moves_with_trackevals_similarity_scale():
    """Own ids, each track 10 px off its person: acc@15 100 % whatever T_sim is (at T_sim 8
    the majority vote had matched no track: 0 %)."""
    gt = np.zeros((5, 2, 2))
    gt[:, 1, 0] = 100.0
    tr = gt + [10.0, 0.0]
    for scale in (8.0, 15.0, 25.0):
        rep = evaluate([1, 2], gt, [11, 12], tr, similarity_scale=scale, trackeval=False)
        assert rep["acc@15"] == 100.0 and rep["id_mapping"] == "majority"


def test_ids_past_2_53_are_refused_not_merged():
    """float64 reads 2^53 + 1 as 2^53: two tracks would have become one."""
    rows = np.array([[1, 2.0**53, 0, 0, 5, 5, 1, -1, -1]])
    with pytest.raises(ValueError, match=r"id 9.0072e\+15 is not a whole number below 2\^53"):
        mot_rows_to_tracks(rows)
    rows[0, 1] = 2.0**53 - 1
    assert mot_rows_to_tracks(rows)[0].tolist() == [2**53 - 1]


def test_gt_ids_counts_the_people_of_the_frames_scored():
    gt = np.full((4, 2, 2), np.nan)
    gt[:2, 0] = 0.0
    gt[2:, 1] = 50.0
    assert evaluate([1, 2], gt[:2], [1, 2], gt[:2], trackeval=False)["gt_ids"] == 1


def test_majority_votes_and_auto_evidence_stop_at_the_radius():
    """A tracked point votes for a person within ``radius`` px (15 by default) and not beyond;
    ``"auto"`` counts as evidence only first points within ``radius`` px of someone."""
    gt_ids = np.array([7, 8])
    gt = np.zeros((3, 2, 2))
    gt[:, 1, 0] = 100.0
    tr = np.stack([gt[:, 0] + [14.0, 0.0], gt[:, 1] + [0.0, 16.0]], axis=1)
    best, votes = map_track_ids(gt_ids, gt, [0, 1], tr)
    assert best.tolist() == [7, -1] and votes.tolist() == [3, 0]
    best, votes = map_track_ids(gt_ids, gt, [0, 1], tr, radius=16.5)
    assert best.tolist() == [7, 8] and votes.tolist() == [3, 3]
    # one known id whose track starts 16 px from the other person: no evidence either way,
    # so the id is taken at its word; 14 px from that person, it is evidence of another id
    ids = np.array([1, 2])
    off = gt[:, [1]] + [0.0, 16.0]
    assert resolve_id_mapping(ids, [1], "auto", gt, off) == "same"
    assert resolve_id_mapping(ids, [1], "auto", gt, off - [0.0, 2.0]) == "majority"


def test_auto_mapping_needs_more_than_the_agreement_share():
    """``"same"`` needs *more than* ``ID_AGREEMENT`` (10 %) of the evidence on its own ids:
    10 tracks near people, 1 on its own person (exactly 10 %) is majority, 2 are same."""
    from tracker.metrics import ID_AGREEMENT

    assert ID_AGREEMENT == 0.1
    ids = np.arange(1, 11)
    gt = np.zeros((2, 10, 2))
    gt[..., 0] = 100.0 * np.arange(10)
    one = [0, 2, 3, 4, 5, 6, 7, 8, 9, 1]  # track 1 on person 1, the others shifted by one
    two = [0, 1, 3, 4, 5, 6, 7, 8, 9, 2]
    assert resolve_id_mapping(ids, ids, "auto", gt, gt[:, one]) == "majority"
    assert resolve_id_mapping(ids, ids, "auto", gt, gt[:, two]) == "same"


def test_accuracy_plot_shows_a_curve_at_100_percent_inside_its_frame(tmp_path, monkeypatch):
    """A tracker at 100 % (every curve of an easy sequence past a few px) and the markers at
    T = 0 and 25 px lay on the axes' frame, half hidden; every point now lies inside it, the
    axes are labelled and the legend names each curve."""
    from tracker import metrics

    drawn = []
    real = metrics.save_figure
    monkeypatch.setattr(
        metrics, "save_figure", lambda fig, path, dpi: drawn.append(fig) or real(fig, path, dpi)
    )
    curves = {"perfect": np.full(26, 100.0), "ncc": np.linspace(0, 90, 26)}
    plot_accuracy(curves, tmp_path / "curve.png")
    (ax,) = drawn[0].axes
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    for line in ax.get_lines():
        x, y = line.get_data()
        assert x0 < np.min(x) and np.max(x) < x1
        assert y0 < np.min(y) and np.max(y) < y1
    assert ax.get_xlabel() == "pixel threshold T (px)"
    assert ax.get_ylabel() == "tracking accuracy (%)"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["perfect", "ncc"]
    assert [t for t in ax.get_yticks() if y0 <= t <= y1] == [0, 20, 40, 60, 80, 100]


def _trackeval_on_files(root, name, similarity=None):
    """TrackEval's own MOTChallenge pipeline (its file reader and preprocessing) on the
    sequence ``root/gt/name`` and the results ``root/tr/mine/data/name.txt``; with
    ``similarity`` (a function of the gt and result boxes) in place of its IoU."""
    import trackeval
    from trackeval.datasets import MotChallenge2DBox

    class Dataset(MotChallenge2DBox):
        def _calculate_similarities(self, gt_dets_t, tracker_dets_t):
            if similarity is None:
                return super()._calculate_similarities(gt_dets_t, tracker_dets_t)
            return similarity(gt_dets_t, tracker_dets_t)

    quiet = {"PRINT_CONFIG": False}
    evaluator = trackeval.Evaluator(
        {
            **quiet,
            "USE_PARALLEL": False,
            "PRINT_RESULTS": False,
            "TIME_PROGRESS": False,
            "OUTPUT_SUMMARY": False,
            "OUTPUT_DETAILED": False,
            "PLOT_CURVES": False,
            "BREAK_ON_ERROR": True,
            "RETURN_ON_ERROR": False,
            "LOG_ON_ERROR": None,
        }
    )
    dataset = Dataset(
        {
            **quiet,
            "GT_FOLDER": str(root / "gt"),
            "TRACKERS_FOLDER": str(root / "tr"),
            "SKIP_SPLIT_FOL": True,
            "SEQ_INFO": {name: None},  # its length read from seqinfo.ini
            "TRACKERS_TO_EVAL": ["mine"],
        }
    )
    metrics = [trackeval.metrics.HOTA(), trackeval.metrics.CLEAR(quiet)]
    metrics.append(trackeval.metrics.Identity(quiet))
    out, _ = evaluator.evaluate([dataset], metrics)
    return out["Dataset"]["mine"][name]["pedestrian"]


def test_trackevals_own_mot_reader_scores_our_files_as_evaluate_does(tmp_path):
    """The files a crowdsim sequence and ``track --out`` hold, read by TrackEval's own
    MOTChallenge reader: with the point similarity they score exactly what ``evaluate``
    says; with TrackEval's default IoU the same ground truth counts, and lower scores (the
    README's "Scoring with outside tools")."""
    from synth_data.mot import read_mot_file, read_sequence, write_mot, write_seqinfo

    ids, gt = _gt(t=8, n=5, seed=3)
    s = 10
    seq = tmp_path / "gt" / "seq"
    (seq / "gt").mkdir(parents=True)
    write_seqinfo(seq, name="seq", frame_rate=25, length=8, width=240, height=240, template_size=s)
    rows = tracks_to_mot_rows(ids, gt, s)[:, :9]
    rows[:, 7:9] = 1.0  # class pedestrian, fully visible
    write_mot(seq / "gt" / "gt.txt", rows)
    tr = gt + np.random.default_rng(4).normal(0, 2.5, gt.shape)  # some pass 7.5 px
    tr[4:, [0, 1]] = tr[4:, [1, 0]]  # an identity switch
    tr[6, 2] = np.nan  # a miss
    (tmp_path / "tr" / "mine" / "data").mkdir(parents=True)
    results = tmp_path / "tr" / "mine" / "data" / "seq.txt"
    write_mot(results, tracks_to_mot_rows(np.r_[ids[:4], 99], tr, s))  # a stray id 99

    sequence = read_sequence(seq)
    gt_ids, gt_pts = sequence.gt_points()
    tr_ids, tr_pts = mot_rows_to_tracks(read_mot_file(results), sequence.length)
    ours = evaluate(gt_ids, gt_pts, tr_ids, tr_pts)

    def point_similarity(g, t):  # max(0, 1 - d / T_sim) between the boxes' centres
        centre_g, centre_t = g[:, :2] + g[:, 2:] / 2, t[:, :2] + t[:, 2:] / 2
        d = np.linalg.norm(centre_g[:, None] - centre_t[None], axis=-1)
        return np.maximum(0.0, 1.0 - d / SIMILARITY_SCALE)

    theirs = _trackeval_on_files(tmp_path, "seq", point_similarity)
    assert 100 * theirs["CLEAR"]["MOTA"] == pytest.approx(ours["mota"], abs=1e-9)
    assert 100 * theirs["Identity"]["IDF1"] == pytest.approx(ours["idf1"], abs=1e-9)
    assert 100 * np.mean(theirs["HOTA"]["HOTA"]) == pytest.approx(ours["hota"], abs=1e-9)
    assert theirs["CLEAR"]["IDSW"] == ours["idsw"] > 0
    assert ours["mota"] < 100
    iou = _trackeval_on_files(tmp_path, "seq")
    assert iou["CLEAR"]["CLR_TP"] + iou["CLEAR"]["CLR_FN"] == ours["gt_points"]
    assert 100 * iou["CLEAR"]["MOTA"] < ours["mota"]
