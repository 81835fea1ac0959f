"""One contract suite over every registered tracker (STYLE habit 8).

Every name in :mod:`tracker.registry` runs through: tiny hand-built scenes with exact expected
positions, edge cases (zero targets, empty frames, image border, leaving targets, people who
vanish inside the view, births), bad inputs, ``set_params`` (every parameter takes effect;
fixed ones are refused by name), and plant-and-recover on a rendered crowd with a stored
accuracy floor (``accuracy_floor.json``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tracker import registry
from tracker.base import Tracker, TrackResult
from tracker.metrics import accuracy_curve
from tracker.testing import check_set_params, make_scene

FLOOR = json.loads((Path(__file__).parent / "accuracy_floor.json").read_text())


def _keeps_ids(name: str) -> bool:
    return getattr(registry.get(name).tracker_class(), "id_mapping", "same") == "same"


KEEPS_IDS = [n for n in registry.names() if _keeps_ids(n)]
"""Trackers that follow the given targets (point trackers). Tracking-by-detection trackers
(``id_mapping = "majority"``) find people in detections and name them themselves: they are
checked by ``test_detection_trackers.py`` and by the registry-wide tests below."""


TOLERANCE_PX = {"meanshift": 3.0}
"""Position tolerance of the exact-scene checks: 0 except for mean-shift, whose integer
search window (cv2.meanShift) stops 1-2 px short of a blob's centre by design and so lags a
moving one by up to 3 px. The same lag keeps its window inside the image when a person
walks out, so its track ends on lost evidence (``max_lost`` frames later), not at once."""


@pytest.fixture(params=KEEPS_IDS)
def make(request):
    entry = registry.get(request.param)
    return entry.create, request.param


def assert_positions(name: str, got: np.ndarray, want: np.ndarray) -> None:
    """Equal NaN pattern; positions equal within the tracker's tolerance (exact for most)."""
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=TOLERANCE_PX.get(name, 0.0))


def test_every_point_tracker_has_a_floor():
    assert set(FLOOR) - {"_comment"} == set(KEEPS_IDS)


@pytest.mark.parametrize("name", registry.names())
def test_set_params_takes_effect_for_every_parameter(name):
    factory = registry.get(name).create
    checked = check_set_params(factory)
    assert checked, name
    tr = factory()
    assert isinstance(tr.params, type(tr).params_class)
    with pytest.raises(ValueError, match="takes"):
        tr.set_params(object())


def test_tracks_end_where_people_vanish_in_view(make):
    factory, name = make
    sc = make_scene(
        [[20, 20], [110, 20], [100, 70], [30, 70]],
        [[2, 1], [0, 1], [-1, 0], [1, -1]],
        n_frames=20,
        death_frames=[20, 8, 20, 20],
    )
    tr = factory()
    res = _track(tr, sc)
    max_lost = tr.params.max_lost
    assert max_lost > 0
    # id 2 vanishes at frame 8 on textured ground: its track ends max_lost frames later
    assert np.isnan(res.positions[8 + max_lost :, 1]).all()
    assert_positions(name, res.positions[:8, 1], sc.points[:8, 1])
    for j in (0, 2, 3):
        assert_positions(name, res.positions[:, j], sc.points[:, j])


def test_unknown_tracker_name_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid trackers: bqp"):
        registry.make_tracker("kalman")
    with pytest.raises(ValueError, match="no parameter"):
        registry.make_tracker("bqp", zetaa=1.0)


def _track(tracker: Tracker, sc, births=None) -> TrackResult:
    (ids, pts) = (sc.ids, sc.points[0])
    present = np.isfinite(pts).all(1)
    return tracker.track(sc.frames, ids[present], pts[present], sc.template_size, births=births)


def test_exact_positions_on_hand_built_scene(make):
    factory, name = make
    sc = make_scene(
        [[20, 20], [90, 20], [100, 75], [25, 75]], [[2, 1], [-2, 1], [-2, 0], [1, -1]], n_frames=12
    )
    res = _track(factory(), sc)
    assert isinstance(res, TrackResult)
    assert res.positions.shape == (12, 4, 2)
    np.testing.assert_array_equal(res.ids, sc.ids)
    assert_positions(name, res.positions, sc.points)
    assert res.timings["total"] > 0


def test_zero_targets(make):
    factory, _ = make
    sc = make_scene(np.zeros((0, 2)), np.zeros((0, 2)), n_frames=4)
    res = factory().track(sc.frames, [], np.zeros((0, 2)), 8)
    assert res.positions.shape == (4, 0, 2) and res.ids.shape == (0,)


def test_empty_frames_give_finite_points(make):
    factory, _ = make
    flat = [np.full((60, 80, 3), 100, np.uint8)] * 5
    res = factory().track(flat, [1, 2], np.array([[20.0, 20.0], [60.0, 40.0]]), 8)
    assert np.isfinite(res.positions).all()
    assert np.abs(res.positions - res.positions[0]).max() <= 4 * 5


def test_targets_at_the_border(make):
    factory, _ = make
    sc = make_scene([[3, 3], [124, 50]], [[2, 0], [0, 2]], n_frames=8, shape=(96, 128))
    res = _track(factory(), sc)
    assert np.isfinite(res.positions).all()
    assert np.abs(res.positions - sc.points).max() <= 2


def test_leaving_targets_are_terminated_and_births_added(make):
    factory, name = make
    sc = make_scene(
        [[110, 30], [30, 60], [60, 20]],
        [[3, 0], [1, 0], [0, 2]],
        n_frames=14,
        shape=(96, 128),
        birth_frames=[0, 0, 5],
    )
    births = {5: (sc.ids[2:], sc.points[5, 2:])}
    tr = factory()
    res = _track(tr, sc, births=births)
    np.testing.assert_array_equal(res.ids, sc.ids)
    gone = np.flatnonzero(np.isnan(sc.points[:, 0, 0]))[0]  # id 1 leaves on the right
    lag = tr.params.max_lost if name in TOLERANCE_PX else 0
    assert np.isnan(res.positions[gone + 1 + lag :, 0]).all()
    assert np.isnan(res.positions[:5, 2]).all()
    assert_positions(name, res.positions[5:, 2], sc.points[5:, 2])
    assert_positions(name, res.positions[:, 1], sc.points[:, 1])


def test_bad_inputs(make):
    factory, _ = make
    sc = make_scene([[20, 20]], [[1, 0]], n_frames=3)
    tr = factory()
    with pytest.raises(ValueError, match="init"):
        tr.step(sc.frames[0])
    with pytest.raises(ValueError, match="duplicate"):
        tr.init(sc.frames[0], [1, 1], np.zeros((2, 2)), 8)
    with pytest.raises(ValueError, match="outside"):
        tr.init(sc.frames[0], [1], np.array([[500.0, 5.0]]), 8)
    with pytest.raises(ValueError, match="template_size"):
        tr.init(sc.frames[0], [1], np.array([[5.0, 5.0]]), 1)
    tr.init(sc.frames[0], [1], sc.points[0], 8)
    with pytest.raises(ValueError, match="mismatched frame sizes"):
        tr.step(sc.frames[1][:50])
    with pytest.raises(ValueError, match="already used"):
        tr.step(sc.frames[1], births=(np.array([1]), np.array([[40.0, 40.0]])))
    with pytest.raises(ValueError, match="uint8"):
        tr.step(sc.frames[1].astype(np.float32))
    with pytest.raises(ValueError, match="no frames"):
        tr.track([], [1], sc.points[0], 8)


def test_deterministic(make):
    factory, _ = make
    sc = make_scene([[20, 20], [26, 28], [60, 50]], [[2, 1], [2, 1], [-1, 1]], n_frames=10)
    a = _track(factory(), sc).positions
    b = _track(factory(), sc).positions
    np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def crowd():
    from synth_data.sequence import synthetic_crowd

    return synthetic_crowd(
        150, 20, seed=3, template_px=10, size=(320, 240), contrast=0.2, noise_sigma=10, speed=2.6
    )


def test_plant_and_recover_accuracy_floor(make, crowd):
    factory, name = make
    (ids, pts), births = crowd.births()
    gt_ids, gt_pts = crowd.gt_points()
    res = factory().track(crowd.frames(), ids, pts, crowd.template_size, births=births)
    curve = accuracy_curve(gt_ids, gt_pts, res.ids, res.positions, strict=True)
    assert np.isfinite(res.positions[np.isfinite(res.positions)]).all()
    assert curve[5] >= FLOOR[name]["acc@5"], (name, curve[5])
    assert curve[15] >= FLOOR[name]["acc@15"], (name, curve[15])
