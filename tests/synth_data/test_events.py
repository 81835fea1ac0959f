"""Scheduled events (crowdsim.events): each kind changes exactly its frames, seeded, and bad
events are named errors; the non-stationary distribution groups episodes by event kind."""

from __future__ import annotations

import numpy as np
import pytest

from crowdsim.camera import Camera
from crowdsim.events import Event, parse_events
from envs.episodes import INFLOW_SCENARIOS, ScenarioDistribution
from synth_data.scene import Scene
from synth_data.spec import spec_from_dict

BASE = {
    "name": "ev",
    "seed": 3,
    "frames": 40,
    "warmup_steps": 25,
    "scenario": {"name": "counterflow", "n_agents": 40},
    "camera": {"max_width": 240, "max_height": 160},
    "appearance": {"template_px": 10},
}
WINDOW = (15, 30)  # frames 15..29


def scene(*events: dict) -> Scene:
    return Scene.from_spec(spec_from_dict({**BASE, "events": list(events)} if events else BASE))


def frames(sc: Scene) -> np.ndarray:
    return np.stack(list(sc.frames())).astype(np.float64)


@pytest.fixture(scope="module")
def plain() -> tuple[Scene, np.ndarray]:
    sc = scene()
    return sc, frames(sc)


def window(kind: str, magnitude: float) -> dict:
    return {
        "kind": kind,
        "start": WINDOW[0],
        "frames": WINDOW[1] - WINDOW[0],
        "magnitude": magnitude,
    }


def inside(f: np.ndarray, f0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The window's frames of ``f`` and ``f0``, after checking every other frame is equal."""
    a, b = WINDOW
    np.testing.assert_array_equal(f[:a], f0[:a])
    np.testing.assert_array_equal(f[b:], f0[b:])
    return f[a:b], f0[a:b]


def test_lighting_dims_exactly_its_frames(plain):
    f, f0 = inside(frames(scene(window("lighting", 0.4))), plain[1])
    ratio = f.mean() / f0.mean()
    assert 0.35 < ratio < 0.5  # the light level times 0.4 (noise and rounding aside)


def test_noise_burst_only_inside(plain):
    f, f0 = inside(frames(scene(window("noise", 30.0))), plain[1])
    assert np.std(f - f0) > 15.0


def test_shake_burst_moves_image_and_truth_together(plain):
    sc0, _ = plain
    sc = scene(window("shake", 6.0))
    ids0, p0 = sc0.gt_points()
    ids, p = sc.gt_points()
    np.testing.assert_array_equal(ids, ids0)
    shift = p - p0  # same crowd, same camera: the truth moves by the burst's offsets only
    a, b = WINDOW
    off = sc.camera.jitter(sc.length)
    assert np.all(off[:a] == 0) and np.all(off[b:] == 0)
    np.testing.assert_allclose(np.nanmean(shift, axis=1), off, atol=1e-9)
    assert np.abs(off[a:b]).max() > 2.0


def test_camera_without_bursts_is_unchanged():
    cam = Camera(px_per_m=10.0, width=64, height=64, jitter_px=3.0, seed=5)
    burst = Event("shake", start=50, frames=10, magnitude=4.0)
    with_burst = Camera(
        px_per_m=10.0, width=64, height=64, jitter_px=3.0, seed=5, shake_events=(burst,)
    )
    np.testing.assert_array_equal(cam.jitter(80)[:50], with_burst.jitter(80)[:50])
    np.testing.assert_array_equal(cam.jitter(80)[60:], with_burst.jitter(80)[60:])
    assert not np.array_equal(cam.jitter(80)[50:60], with_burst.jitter(80)[50:60])
    with pytest.raises(ValueError, match="shake_events must be shake events"):
        Camera(px_per_m=10.0, width=64, height=64, shake_events=(Event("noise", 0),))


def speeds(sc: Scene) -> np.ndarray:
    """Mean head speed (px/frame) of the people in view, per frame step."""
    _, p = sc.gt_points()
    return np.nanmean(np.linalg.norm(np.diff(p, axis=0), axis=2), axis=1)


def test_stop_halts_the_crowd_then_it_walks_on(plain):
    sc0, _ = plain
    stop = {"kind": "stop", "start": 5, "frames": 28, "magnitude": 1.0}  # frames 5..32
    sc = scene(stop)
    s, s0 = speeds(sc), speeds(sc0)
    assert s[20:32].mean() < 0.3 * s0[20:32].mean()  # a halted crowd only shuffles
    assert s[36:].mean() > 2.0 * s[28:32].mean()  # walking again
    np.testing.assert_array_equal(sc.traj.positions, scene(stop).traj.positions)  # seeded
    # the steps before the stop are today's
    np.testing.assert_array_equal(sc.traj.positions[:5], sc0.traj.positions[:5])


def test_surge_brings_more_people(plain):
    sc0, _ = plain
    sc = scene({"kind": "surge", "start": 1, "magnitude": 10.0})
    assert sc.traj.positions.shape[1] > sc0.traj.positions.shape[1]
    crossing = {**BASE, "scenario": {"name": "crossing", "n_agents": 20}}
    # refused when the spec is read, naming it, before any sequence is made
    with pytest.raises(ValueError, match="spec: events: a surge multiplies the inflow, and "
                       "scenario 'crossing' with these parameters has none"):  # fmt: skip
        spec_from_dict({**crossing, "events": [window("surge", 3.0)]}, "spec")


def test_spec_round_trip_and_digest():
    spec = spec_from_dict({**BASE, "events": [window("lighting", 0.5)]})
    assert spec.events == (Event("lighting", 15, 15, 0.5),)
    again = spec_from_dict({k: v for k, v in spec.to_dict().items() if k != "calibration"})
    assert again.events == spec.events and again.digest() == spec.digest()
    plain_spec = spec_from_dict(BASE)
    assert "events" not in plain_spec.to_dict()  # digests of event-free specs are today's
    assert plain_spec.digest() != spec.digest()


def test_a_bursts_seed_does_not_depend_on_events_of_other_kinds():
    """Seeded by its place among the shake bursts: a noise event listed before it changes
    nothing (its sequence's digest, which generate compares, stays the same too)."""
    burst = {"kind": "shake", "start": 2, "frames": 20, "magnitude": 3.0}
    alone = Scene.from_spec(spec_from_dict({**BASE, "events": [burst]})).camera
    spec = spec_from_dict({**BASE, "events": [{"kind": "noise", "start": 25}, burst]})
    np.testing.assert_array_equal(Scene.from_spec(spec).camera.jitter(40), alone.jitter(40))


def test_a_cut_drops_later_events_and_keeps_the_frames_before():
    late = {"kind": "shake", "start": 30, "frames": 5, "magnitude": 3.0}
    early = {"kind": "shake", "start": 2, "frames": 20, "magnitude": 3.0}
    spec = spec_from_dict({**BASE, "events": [late, {"kind": "noise", "start": 25}, early]})
    cut = spec.truncated(20)
    assert [(e.kind, e.start) for e in cut.events] == [("shake", 2)]
    again = spec_from_dict({k: v for k, v in cut.to_dict().items() if k != "calibration"})
    assert again.events == cut.events  # the cut spec loads again (events inside its frames)
    # the early burst is the one the whole sequence has, though the late one went before it
    whole, part = Scene.from_spec(spec).camera, Scene.from_spec(cut).camera
    np.testing.assert_array_equal(part.jitter(20), whole.jitter(40)[:20])
    assert np.abs(part.jitter(20)[2:]).max() > 1.0


@pytest.mark.parametrize(
    ("event", "message"),
    [
        ({"kind": "fog", "start": 1}, r"events\[0\]\.kind must be one of lighting"),
        (
            {"kind": "stop", "start": 1, "magnitude": 1.5},
            r"events\[0\]\.magnitude must be .* in \[0, 1\], got 1.5",
        ),
        ({"kind": "noise", "start": 40}, r"events\[0\]\.start must be below the sequence's 40"),
        ({"kind": "noise", "start": -1}, r"events\[0\]\.start must be"),
        ({"kind": "noise"}, r"missing required field 'events\[0\]\.start'"),
        ({"kind": "noise", "start": 1, "when": 3}, r"unknown field\(s\) events\[0\]\.when"),
        ("noise", r"events\[0\] must be a table"),
    ],
)
def test_bad_events_are_named(event, message):
    with pytest.raises(ValueError, match=message):
        spec_from_dict({**BASE, "events": [event]}, source="s.toml")
    with pytest.raises(ValueError, match="events must be a list of tables"):
        parse_events({"kind": "noise"}, "s.toml")


def test_nonstationary_distribution_groups_by_event_kind():
    dist = ScenarioDistribution.from_arg("nonstationary", frames=40)
    assert dist.families == ("lighting", "noise", "shake", "stop", "surge")
    assert set(dist.scenarios) == set(INFLOW_SCENARIOS)
    rng = np.random.default_rng(0)
    seen = set()
    for i in range(30):
        spec = dist.sample_spec(rng, name=f"e{i}")
        (ev,) = spec.events
        seen.add(dist.family(spec))
        assert dist.family(spec) == ev.kind
        assert 10 <= ev.start <= 20 and 10 <= ev.frames <= 20
    assert seen == set(dist.families)
    # without events the draws are today's
    a = ScenarioDistribution().sample_spec(np.random.default_rng(4))
    assert a.events == () and ScenarioDistribution().family(a) == a.scenario["name"]
    with pytest.raises(ValueError, match="surge needs scenarios with inflow .* groups has none"):
        ScenarioDistribution(scenarios=("groups",), events=("surge",))
    with pytest.raises(ValueError, match="unknown kind 'fog'"):
        ScenarioDistribution(events=("fog",))


def test_inflow_scenarios_are_the_ones_with_inflow():
    from crowdsim.scenarios import SCENARIOS, make_scenario

    for name in SCENARIOS:
        has = bool(make_scenario(name).build(np.random.default_rng(0)).sources)
        assert has == (name in INFLOW_SCENARIOS), name


def test_anomalies_stoppers_stop_in_the_video_after_a_long_warm_up():
    """A scenario's stoppers (``anomalies``, kind ``stop``) stand 3-8 s from 0.5-4 s after
    frame 0: their times counted from the warm-up's start had ended every stop before the
    first frame of a 10 s warm-up, and people labelled stop walked through the video."""
    spec = spec_from_dict(
        {
            **BASE,
            "fps": 10.0,
            "warmup_steps": 100,  # 10 s
            "frames": 120,
            "scenario": {
                "name": "anomalies",
                "n_agents": 120,
                "density": 0.5,
                "anomaly_fraction": 0.3,
                "kinds": ["stop"],
            },
        }
    )
    traj = Scene.from_spec(spec).traj
    speed = np.linalg.norm(np.diff(traj.positions, axis=0), axis=2) * spec.fps
    second = np.lib.stride_tricks.sliding_window_view(speed, 10, axis=0).mean(axis=2)
    slowest = np.nanmin(np.where(np.isnan(second), np.inf, second), axis=0)  # a 1 s window
    stoppers = traj.attributes["anomaly"] == 2
    assert stoppers.sum() >= 10
    assert np.median(slowest[stoppers]) < 0.3  # was 1.15: they never stood
    assert np.median(slowest[~stoppers]) > 0.6
