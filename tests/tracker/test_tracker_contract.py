"""One contract suite over every registered tracker (STYLE habit 8).

The contract itself ships with the library (:func:`tracker.testing.check_tracker_contract`:
tiny hand-built scenes with exact expected positions, edge cases, bad inputs, determinism and
``set_params``), so outside tracker authors run the same checks; this file parametrises it over
the registry, one test per (tracker, check), and adds plant-and-recover on a rendered crowd
with a stored accuracy floor (``accuracy_floor.json``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tracker import registry
from tracker.baselines.ncc import NCCTracker
from tracker.metrics import accuracy_curve
from tracker.testing import check_tracker_contract, contract_checks

FLOOR = json.loads((Path(__file__).parent / "accuracy_floor.json").read_text())

# the package's own trackers (an installed plug-in is its author's to test, with the same
# check_tracker_contract)
CASES = [
    (name, check)
    for name in registry.TRACKERS
    for check in contract_checks(registry.get(name).create)
]


@pytest.mark.parametrize(("name", "check"), CASES, ids=[f"{n}: {c}" for n, c in CASES])
def test_contract(name, check):
    factory = registry.get(name).create
    contract_checks(factory)[check](factory)


KEEPS_IDS = [n for n, e in registry.TRACKERS.items() if e.tracker_class().id_mapping == "same"]
"""Trackers that follow the given targets (point trackers). Tracking-by-detection trackers
(``id_mapping = "majority"``) find people in detections and name them themselves: they are
checked by ``test_detection_trackers.py`` too."""


def test_every_point_tracker_has_a_floor():
    missing = sorted(set(KEEPS_IDS) - set(FLOOR))
    assert not missing, (
        f"add a floor for {missing} to tests/tracker/accuracy_floor.json: a few points under "
        "the acc@5 and acc@15 that test_plant_and_recover_accuracy_floor measures for it"
    )
    assert set(FLOOR) - {"_comment"} == set(KEEPS_IDS)


def test_unknown_tracker_name_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid trackers: bqp"):
        registry.make_tracker("kalman")
    with pytest.raises(ValueError, match="no parameter"):
        registry.make_tracker("bqp", zetaa=1.0)


def test_params_given_as_anything_but_the_dataclass_are_validated_or_refused():
    """A mapping goes through the parameter dataclass (validated, the variant's overrides
    kept); another tracker's parameters or any other object is refused naming its type. Once,
    ``make_tracker("bqp", params={"zeta": -5})`` built a tracker around the raw dict."""
    import re

    from tracker.bqp.params import BQPParams
    from tracker.bqp.tracker import BQPTracker

    tr = registry.make_tracker("bqp-ncc", params={"zeta": 0.5}, eta=0.1)
    assert isinstance(tr.params, BQPParams)
    assert (tr.params.zeta, tr.params.eta, tr.params.appearance) == (0.5, 0.1, "ncc")
    for params, needle in (
        ({"zeta": -5}, "BQPParams.zeta must be a finite number >= 0, got -5"),
        ({"zetaa": 1}, "tracker 'bqp' has no parameter(s) zetaa"),
        (3, "tracker 'bqp' takes params as a BQPParams or a mapping of its fields, got int"),
        (BQPParams(), None),
    ):
        if needle is None:
            assert registry.make_tracker("bqp", params=params).params == params
            continue
        with pytest.raises(ValueError, match=re.escape(needle)):
            registry.make_tracker("bqp", params=params)
    with pytest.raises(ValueError, match="takes params as a PNMCParams .* got BQPParams"):
        registry.make_tracker("pnmc", params=BQPParams())
    with pytest.raises(ValueError, match=r"no parameter\(s\) zetaa"):
        registry.make_tracker("bqp", params=BQPParams(), zetaa=1.0)
    with pytest.raises(
        ValueError, match=r"BQPParams.search_factor must .* in \(1, 8\], got 1000000.0"
    ):
        registry.make_tracker("bqp", params=BQPParams(), search_factor=1e6)
    frame = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(ValueError, match="tracker 'bqp' takes BQPParams, got dict"):
        BQPTracker({"zeta": -5}).init(frame, [1], np.array([[9.0, 9.0]]), 8)


class _Frozen(NCCTracker):
    """A planted bug: never moves its points."""

    def _step(self, frame):
        return self.points.copy()


class _Forgets(NCCTracker):
    """A planted bug: set_params replaces params but the search radius stays the initial one."""

    def _apply_params(self, old, changed):
        pass


class _OneColumn(NCCTracker):
    """A planted bug: _step returns (n, 1)."""

    def _step(self, frame):
        return super()._step(frame)[:, :1]


class _NoBirths(NCCTracker):
    """A planted bug: drops every birth after the start (the born target's check fails on a
    single target's track, which the check itself once failed to unpack)."""

    def step(self, frame, births=None):
        return super().step(frame, None)


@pytest.mark.parametrize(
    ("cls", "match"),
    [
        (_Frozen, "exact positions"),
        (_Forgets, "set_params"),
        (
            _OneColumn,
            "exact positions on a hand-built scene: ValueError: _OneColumn._step returned",
        ),
        (_NoBirths, "leaving targets end, births start: births: ids"),
    ],
)
def test_the_shipped_contract_catches_a_broken_tracker(cls, match):
    # what an outside author sees: one call, an error naming the broken part of the contract
    with pytest.raises(AssertionError, match=match):
        check_tracker_contract(lambda params=None: cls(params))


def test_a_step_that_returns_no_positions_is_refused_by_name_and_ints_become_floats():
    frame = np.zeros((40, 40, 3), np.uint8)
    frame[::4] = 200
    bad = _OneColumn()
    bad.init(frame, [1, 2], np.array([[10.0, 10.0], [30.0, 20.0]]), 8)
    with pytest.raises(
        ValueError, match=r"_OneColumn._step returned float64 \(2, 1\); expected \(2, 2\)"
    ):
        bad.step(frame)

    class Rounds(NCCTracker):
        def _step(self, frame):
            return np.rint(super()._step(frame)).astype(np.int64)

    good = Rounds()
    good.init(frame, [1, 2], np.array([[10.0, 10.0], [30.0, 20.0]]), 8)
    _, points = good.step(frame)
    assert points.dtype == np.float64


def test_the_contract_names_what_a_tracker_without_parameters_lacks():
    """A tracker with no parameters (params_class None, as the base class allows): the
    params and bad-input checks pass, and the vanishing check says what it needs instead of
    an AttributeError on params.max_lost."""
    from tracker.base import Tracker
    from tracker.testing import _check_bad_input, _check_params, _check_vanishing

    class Still(Tracker):
        def __init__(self, params=None):
            super().__init__()

        def _init(self, frame):
            pass

        def _add(self, frame, points):
            pass

        def _remove(self, keep):
            pass

        def _step(self, frame):
            return self.points

    _check_params(Still)
    _check_bad_input(Still)
    with pytest.raises(AssertionError, match="give the params max_lost and lost_ratio"):
        _check_vanishing(Still)


@pytest.fixture(scope="module")
def crowd():
    from synth_data.sequence import synthetic_crowd

    return synthetic_crowd(
        150, 20, seed=3, template_px=10, size=(320, 240), contrast=0.2, noise_sigma=10, speed=2.6
    )


class _Still(NCCTracker):
    """A tracker that never moves: each target stays where it was born."""

    def _step(self, frame):
        return self.points.copy()


def test_every_floor_but_mean_shifts_is_above_a_tracker_that_never_moves(crowd):
    """A floor at or below what standing still scores cannot tell a tracker from none.
    Mean-shift's is (``cv2.meanShift``'s up-left bias on this crowd's flat back-projection,
    ``tracker.baselines.meanshift``): it is the one exception, and is kept as measured."""
    (ids, pts), births = crowd.births()
    gt_ids, gt_pts = crowd.gt_points()
    res = _Still().track(crowd.frames(), ids, pts, crowd.template_size, births=births)
    still = accuracy_curve(gt_ids, gt_pts, res.ids, res.positions, strict=True)
    assert 10.0 < still[5] < 30.0 and 30.0 < still[15] < 50.0  # the crowd moves: 16 / 40
    for name in KEEPS_IDS:
        if name != "meanshift":
            assert FLOOR[name]["acc@5"] > still[5] + 50, (name, still[5])
            assert FLOOR[name]["acc@15"] > still[15] + 40, (name, still[15])


@pytest.mark.parametrize("name", KEEPS_IDS)
def test_plant_and_recover_accuracy_floor(name, crowd):
    factory = registry.get(name).create
    (ids, pts), births = crowd.births()
    gt_ids, gt_pts = crowd.gt_points()
    res = factory().track(crowd.frames(), ids, pts, crowd.template_size, births=births)
    curve = accuracy_curve(gt_ids, gt_pts, res.ids, res.positions, strict=True)
    assert np.isfinite(res.positions[np.isfinite(res.positions)]).all()
    assert curve[5] >= FLOOR[name]["acc@5"], (name, curve[5])
    assert curve[15] >= FLOOR[name]["acc@15"], (name, curve[15])


def test_ncc_match_centre_stays_inside_the_image():
    """NCC tracker keeps a match centre inside the image even if the best match is beyond."""
    f0 = np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    f0[:, 63] = f0[:, 62]  # with the replicated border, the shifted patch matches exactly at x = 64
    f1 = np.ascontiguousarray(np.roll(f0, 1, axis=1))
    tr = NCCTracker()
    tr.init(f0, np.array([1]), np.array([[63.0, 32.0]]), 8)
    ids, pts = tr.step(f1)
    assert ids.tolist() == [1]
    assert 0 <= pts[0, 0] <= 63


@pytest.mark.parametrize("blank", ["template", "frames"])
def test_ncc_stays_where_every_window_scores_alike(blank):
    """A template cut from a flat frame (OpenCV scores it 1 everywhere) or frames gone blank
    (every window 0): the tied target stays where it is. It had taken the first window, the
    search's top-left corner, and walked up-left by the radius every frame (4 px at 8 px)."""
    from tracker.testing import make_scene

    sc = make_scene([[40, 40], [60, 50]], [[0, 0], [0, 0]], n_frames=4)
    flat = np.full_like(sc.frames[0], 128)
    first, rest = (flat, sc.frames[1:]) if blank == "template" else (sc.frames[0], [flat] * 3)
    tr = NCCTracker()
    tr.init(first, sc.ids, sc.points[0], 8)
    for f in rest:
        ids, pts = tr.step(f)
        np.testing.assert_array_equal(pts, sc.points[0, : len(ids)])


@pytest.mark.parametrize(
    ("births", "message"),
    [
        ({"3": ([5], [[30.0, 30.0]])}, "births: frame '3' is not a frame index"),
        ({-1: ([5], [[30.0, 30.0]])}, "births: frame -1 is not a frame index"),
        ({9: ([5], [[30.0, 30.0]])}, "births: frame 9 is beyond the sequence's 6 frames"),
        ({3: [5]}, "births at frame 3: expected (ids, points)"),
        ({3: ([], [[30.0, 30.0]])}, "births at frame 3: 1 points but no ids"),
        ([5], "births must be a mapping frame -> (ids, points) or a callable, got list"),
    ],
)
def test_births_the_tracker_would_drop_are_refused_before_tracking(births, message):
    """A births key as text, negative or past the last frame, or a malformed value: each had
    been dropped in silence (or failed deep inside with a TypeError)."""
    import re

    from tracker.testing import make_scene

    sc = make_scene([[20, 20], [60, 40]], [[1, 0], [0, 1]], n_frames=6)
    tr = NCCTracker()
    with pytest.raises(ValueError, match=re.escape(message)):
        tr.track(sc.frames, sc.ids, sc.points[0], sc.template_size, births=births, n_frames=6)
    with pytest.raises(ValueError, match=re.escape("births at frames [9] are beyond the")):
        tr.track(sc.frames, sc.ids, sc.points[0], sc.template_size, births={9: ([5], [[1, 1]])})


@pytest.mark.parametrize(
    ("births", "message"),
    [(([7], [[5000.0, 5.0]]), "starts outside the"), (([1], [[30.0, 30.0]]), "already used")],
)
def test_step_refuses_bad_births_before_it_moves_anything(births, message):
    """A birth outside the image or with a used id is refused before the frame is tracked:
    the refusal had come after the targets had stepped into the frame, so a caller that
    retried the frame with mended births tracked it twice."""
    from tracker.testing import make_scene

    sc = make_scene([[20, 20], [60, 40]], [[1, 0], [0, 1]], n_frames=3)
    tr = NCCTracker()
    tr.init(sc.frames[0], sc.ids, sc.points[0], sc.template_size)
    before = tr.points.copy()
    with pytest.raises(ValueError, match=message):
        tr.step(sc.frames[1], (np.array(births[0]), np.array(births[1])))
    assert tr.frame_index == 0
    np.testing.assert_array_equal(tr.points, before)


def test_run_tracker_refuses_a_start_without_its_births_mapping():
    from tracker.runner import run_tracker
    from tracker.testing import make_scene

    sc = make_scene([[20, 20]], [[1, 0]], n_frames=4)

    class Source:
        length, template_size = 4, sc.template_size

        def frames(self):
            return iter(sc.frames)

        def births(self):
            return (sc.ids, sc.points[0]), {}

    with pytest.raises(ValueError, match="start must be"):
        run_tracker("ncc", Source(), metrics="none", start=((sc.ids, sc.points[0]), None))
    res = run_tracker("ncc", Source(), metrics="none", start=((sc.ids, sc.points[0]), {}))
    assert res.result.positions.shape == (4, 1, 2)
    assert res.fps == res.result.fps > 0
    one = run_tracker("ncc", Source(), metrics="none", frames=1)  # nothing tracked: no rate
    assert one.fps == one.result.fps == 0.0


def test_a_tracker_gets_its_own_copy_of_the_callers_points():
    """as_points hands the tracker a copy: one that moves its points in place had moved the
    caller's initial points and births (20.0 -> 20.25, seen by a contributor)."""
    from tracker.base import as_points

    pts = np.array([[20.0, 30.0]])
    _, got = as_points([1], pts)
    got += 0.25
    assert pts.tolist() == [[20.0, 30.0]]


def test_set_params_check_catches_a_value_copied_at_init():
    """A tracker that copies search_factor at init and ignores set_params is caught (the
    field moves the tracks on the check's scenes); a field that moves nothing is reported as
    unexercised, not as checked."""
    from tracker.baselines.ncc import NCCTracker
    from tracker.testing import check_set_params

    class Frozen(NCCTracker):
        def _init(self, frame):
            self._frozen = self.params.search_factor
            super()._init(frame)

        def _set_radius(self):
            from tracker.candidates import grid_offsets, search_radius

            factor = getattr(self, "_frozen", self.params.search_factor)
            self.radius = search_radius(self.template_size, factor)
            self.model.radius = self.radius
            self.model.window = self.template_size + 2 * self.radius
            self._offsets = grid_offsets(self.radius)

    with pytest.raises(AssertionError, match="search_factor=.* given by set_params after init"):
        check_set_params(lambda p: Frozen(p))
    checked = check_set_params(lambda p: NCCTracker(p))
    assert "search_factor" in checked and check_set_params.unexercised == ["cmc_method"]
