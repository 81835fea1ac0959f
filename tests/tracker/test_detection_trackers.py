"""ByteTrack and OC-SORT adapters (``trackers`` package) on simulated head detections:
exact tracks from perfect detections, identities kept through planted misses, the registry and
runner path, detection feeds, parameters and bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("trackers", reason="needs the optional 'trackers' package ([detect])")

from synth_data.detections import DetectionParams, attach_detections, simulate_detections  # noqa: E402
from synth_data.sequence import InMemorySequence  # noqa: E402
from tracker.baselines.detection import (  # noqa: E402
    ByteTrackParams,
    ByteTrackTracker,
    OCSORTParams,
    OCSORTTracker,
)
from tracker.metrics import evaluate  # noqa: E402
from tracker.registry import make_tracker  # noqa: E402
from tracker.runner import run_tracker  # noqa: E402

T, N, W, H = 30, 6, 256, 96
PERFECT = DetectionParams(
    miss_rate=0.0, false_alarm_rate=0.0, jitter_px=0.0, score_std=0.0, score_mean=0.9
)
KINDS = {"bytetrack": (ByteTrackTracker, ByteTrackParams), "ocsort": (OCSORTTracker, OCSORTParams)}


def _lines(t=T, n=N):
    """``n`` people walking on separate straight lines (30 px apart, 1.1 px/frame)."""
    starts = np.array([[20.0 + 30 * i, 40.0] for i in range(n)])
    pts = starts[None] + np.arange(t)[:, None, None] * np.array([1.0, 0.5])
    return InMemorySequence(
        name="lines",
        frame_rate=25,
        width=W,
        height=H,
        template_size=10,
        frames=[np.zeros((H, W, 3), np.uint8)] * t,
        ids=np.arange(10, 10 + n),
        points=pts,
    )


@pytest.fixture(params=list(KINDS))
def kind(request):
    return request.param


def test_perfect_detections_give_exact_tracks(kind):
    seq = _lines()
    trk = make_tracker(kind, minimum_consecutive_frames=1)
    attach_detections(trk, seq, PERFECT)
    run = run_tracker(trk, seq)
    res, rep = run.result, run.report
    assert len(res.ids) == N and res.positions.shape == (T, N, 2)
    gt_ids, gt = seq.gt_points()
    # own ids: one track per person, exactly on its person in every frame but the first (the
    # library never reports a track in the frame that spawns it)
    assert np.isnan(res.positions[0]).all()
    order = np.argsort(res.positions[1, :, 0])
    np.testing.assert_allclose(res.positions[1:, order], gt[1:], atol=1e-9)
    assert rep["id_mapping"] == "majority"
    found = 100.0 * (T - 1) / T
    assert rep["acc@5"] == pytest.approx(found) and rep["mota"] == pytest.approx(found)
    assert rep["idf1"] == pytest.approx(100.0 * 2 * (T - 1) / (2 * (T - 1) + 1))
    assert rep["hota"] == pytest.approx(found) and rep["idsw"] == 0
    assert run.fps > 0 and set(run.stage_ms) == {"detections", "associate"}


def test_confirmation_delay_is_the_only_loss(kind):
    """With the library's default confirmation (tracks seen in the first frames are
    confirmed at once), only the spawning frame 0 is unreported."""
    seq = _lines()
    trk = make_tracker(kind)
    attach_detections(trk, seq, PERFECT)
    res = run_tracker(trk, seq).result
    assert trk.params.minimum_consecutive_frames > 1 and len(res.ids) == N
    assert np.isnan(res.positions[0]).all() and np.isfinite(res.positions[1:]).all()


def test_identities_survive_planted_misses(kind):
    """30 % of the detections missed: tracks coast through the gaps and keep their ids.

    ByteTrack reports a track again at its next matched detection; OC-SORT (as SORT) only
    after ``minimum_consecutive_frames`` matches in a row, so it reports fewer frames."""
    seq = _lines(t=40)
    trk = make_tracker(kind)
    detector = DetectionParams(
        miss_rate=0.3, false_alarm_rate=0.0, jitter_px=0.5, score_std=0.0, score_mean=0.9, seed=4
    )
    dets = attach_detections(trk, seq, detector)
    run = run_tracker(trk, seq)
    rep = run.report
    detected = sum(len(d) for d in dets) / (40 * N)
    assert 0.6 < detected < 0.8
    assert rep["idsw"] == 0 and len(run.result.ids) == N
    # a person is tracked in a frame only when their detection was matched
    assert rep["acc@15"] <= 100 * detected + 1e-9
    if kind == "bytetrack":
        assert rep["acc@15"] > 100 * detected - 5


def test_deterministic(kind):
    seq = _lines()
    runs = []
    for _ in range(2):
        trk = make_tracker(kind)
        attach_detections(trk, seq, DetectionParams(miss_rate=0.2, jitter_px=1.0, seed=2))
        runs.append(run_tracker(trk, seq, metrics="none").result)
    np.testing.assert_array_equal(runs[0].ids, runs[1].ids)
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)


def test_feed_forms(kind):
    seq = _lines(t=6, n=2)
    gt_ids, gt = seq.gt_points()
    dets = simulate_detections(
        gt_ids,
        gt,
        W,
        H,
        replace(PERFECT, box_px=10.0),
    )
    cls, params = KINDS[kind]
    p = params(minimum_consecutive_frames=1)
    frames = list(seq.frames())
    as_list = cls(p, detections=dets).track(frames, [], np.zeros((0, 2)), 10)
    as_tuples = cls(p, detections=[(d.xyxy, d.confidence) for d in dets]).track(
        frames, [], np.zeros((0, 2)), 10
    )
    as_callable = cls(p, detections=lambda t, frame: dets[t]).track(frames, [], [], 10)
    for other in (as_tuples, as_callable):
        np.testing.assert_array_equal(other.positions, as_list.positions)
    # a mapping with frames missing: no detections there (tracks not reported)
    sparse = cls(p, detections={t: dets[t] for t in (0, 1, 2, 4, 5)}).track(
        frames, [], np.zeros((0, 2)), 10
    )
    assert np.isnan(sparse.positions[3]).all() and np.isfinite(sparse.positions[4:]).all()
    np.testing.assert_array_equal(sparse.ids, as_list.ids)  # same tracks across the gap


def test_missing_and_bad_detections(kind):
    seq = _lines(t=4, n=2)
    frames = list(seq.frames())
    cls, params = KINDS[kind]
    with pytest.raises(ValueError, match="needs detections"):
        run_tracker(kind, seq)
    with pytest.raises(ValueError, match="cover 2 frames"):
        cls(detections=[None, None]).track(frames, [], np.zeros((0, 2)), 10)
    bad = [(np.zeros((1, 3)), np.ones(1))] * 4
    with pytest.raises(ValueError, match=r"xyxy must have shape \(m, 4\)"):
        cls(detections=bad).track(frames, [], np.zeros((0, 2)), 10)
    bad = [(np.array([[0.0, 0, 5, 5]]), np.array([1.5]))] * 4
    with pytest.raises(ValueError, match=r"confidence must lie in \[0, 1\]"):
        cls(detections=bad).track(frames, [], np.zeros((0, 2)), 10)
    with pytest.raises(ValueError, match="callable"):
        cls().use_detections(3)


def test_params_validation_and_set_params(kind):
    cls, params = KINDS[kind]
    with pytest.raises(ValueError, match=f"{params.__name__}.minimum_iou_threshold"):
        params(minimum_iou_threshold=-0.1)
    seq = _lines(t=4, n=2)
    trk = make_tracker(kind)
    attach_detections(trk, seq)
    frames = list(seq.frames())
    (ids, pts), _ = seq.births()
    trk.init(frames[0], ids, pts, 10)
    trk.set_params(replace(trk.params, minimum_iou_threshold=0.42, lost_track_buffer=5))
    assert trk._impl.minimum_iou_threshold == 0.42
    assert trk._impl.maximum_frames_without_update == 5
    trk.step(frames[1])


def test_detector_settings_are_not_tracker_parameters(kind):
    """The detector belongs to the detection source: the tracker refuses its settings by
    name, and the same tracker fed by another detector is what changes the result."""
    for name in ("miss_rate", "false_alarm_rate", "jitter_px", "box_px", "seed"):
        with pytest.raises(ValueError, match=f"tracker {kind!r} has no parameter\\(s\\) {name}"):
            make_tracker(kind, **{name: 1})
    seq = _lines(t=20)
    found = []
    for miss in (0.0, 0.5):
        trk = make_tracker(kind)
        attach_detections(trk, seq, replace(PERFECT, miss_rate=miss, seed=3))
        found.append(run_tracker(trk, seq).report["acc@15"])
    assert found[0] > found[1]
    dets = attach_detections(make_tracker(kind), seq)  # no detector given: DetectionParams()
    gt_ids, gt = seq.gt_points()
    default = simulate_detections(gt_ids, gt, W, H, DetectionParams(), template_size=10)
    for d, e in zip(dets, default, strict=True):
        np.testing.assert_array_equal(d.xyxy, e.xyxy)


def test_registry_and_majority_mapping():
    assert type(make_tracker("bytetrack")) is ByteTrackTracker
    assert type(make_tracker("ocsort")) is OCSORTTracker
    gt_ids, gt = _lines().gt_points()
    relabelled = evaluate(gt_ids, gt, gt_ids + 1000, gt)
    assert relabelled["id_mapping"] == "majority" and relabelled["acc@5"] == 100.0
