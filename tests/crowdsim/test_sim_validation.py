"""Validation against real crowds (small cases) and bad-input handling of the simulator API."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdsim.params import SocialForceParams
from crowdsim.scenarios import SCENARIOS, make_scenario, weidmann_speed
from crowdsim.simulation import Simulation
from crowdsim.validation import fundamental_diagram, lane_order_parameter, max_overlap


def test_weidmann_reference_values():
    assert float(weidmann_speed(1.0)) == pytest.approx(1.058, abs=1e-3)
    assert float(weidmann_speed(5.4)) == pytest.approx(0.0, abs=1e-12)
    assert float(weidmann_speed(0.1)) == pytest.approx(1.34, abs=1e-3)


@pytest.mark.slow
def test_fundamental_diagram_small_case_within_20_percent_of_weidmann():
    """Periodic corridor at 1 and 3 /m², measured with PedPy, follows Weidmann within ±20 %."""
    points = fundamental_diagram(
        [1.0, 3.0], length=14.0, width=4.0, warmup_s=10.0, measure_s=10.0, seed=0
    )
    for p in points:
        assert p.density == pytest.approx(p.target_density, rel=0.1)
        assert 0.8 <= p.ratio <= 1.2, (p.target_density, p.speed, p.weidmann)
        assert p.max_overlap <= 0.2


@pytest.mark.parametrize("measure_s", [0.2, 0.01])
def test_fundamental_diagram_refuses_a_measurement_without_speeds(measure_s):
    """PedPy's speeds span 5 frames: 5 frames gave a NaN speed, 0 a pandas error."""
    with pytest.raises(
        ValueError, match=rf"measure_s must cover at least 6 steps .* {measure_s:g} s"
    ):
        fundamental_diagram([1.0], length=8.0, width=3.0, warmup_s=0.0, measure_s=measure_s)


def test_station_refuses_a_density_its_hall_cannot_hold():
    """1,000 people at 1.5 /m² had started with about 920 in silence; 1 /m² fits them all."""
    with pytest.raises(
        ValueError, match=r"station.density 1.5 /m² is too high for n_agents 1000: only 9\d\d "
    ):
        make_scenario("station", n_agents=1000, density=1.5).build(np.random.default_rng(0))
    agents = make_scenario("station", n_agents=1000, density=1.0).build(np.random.default_rng(0))
    assert len(agents.agents) == 1000


def test_pure_hm95_is_faster_than_weidmann_at_high_density():
    """Without the headway rule dense crowds stay far too fast: the rule is what calibrates."""
    (p,) = fundamental_diagram(
        [3.0],
        length=14.0,
        width=4.0,
        warmup_s=6.0,
        measure_s=4.0,
        params=SocialForceParams(headway_time=0.0),
    )
    assert p.ratio > 1.5


def test_lane_order_parameter_exact_cases():
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    lanes = np.array([1, 1, 1, -1, -1, -1])
    assert lane_order_parameter(pos, lanes) == pytest.approx(1.0)
    alternating = np.array([1, -1, 1, -1, 1, -1])
    # Per row: the middle agent sees two opposite walkers (phi = 1), each end one of each (0).
    assert lane_order_parameter(pos, alternating) == pytest.approx(1 / 3)


def test_max_overlap_exact():
    pos = np.array([[0.0, 0.0], [0.36, 0.0], [5.0, 5.0]])
    radius = np.array([0.2, 0.2, 0.2])
    assert max_overlap(pos, radius) == pytest.approx(0.04 / 0.2)
    # Across a periodic seam.
    pos = np.array([[0.1, 1.0], [9.74, 1.0]])
    assert max_overlap(pos, radius[:2], period=10.0) == pytest.approx(0.04 / 0.2)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"n_agents": 0}, "n_agents"),
        ({"n_agents": -5}, "n_agents"),
        ({"n_agents": 1_000_001}, "n_agents"),
        ({"n_agents": 2.5}, "n_agents"),
        ({"n_agents": 5.0}, "n_agents"),
        ({"density": 6.5}, "density"),
        ({"density": 0.0}, "density"),
        ({"density": math.nan}, "density"),
        ({"prominent_fraction": math.nan}, "prominent_fraction"),
        ({"radius": (0.3, 0.2)}, "radius"),
    ],
)
def test_bad_scenario_parameters_name_field_and_value(kwargs, field):
    for name in ("marathon", "counterflow"):
        with pytest.raises(ValueError, match=field):
            make_scenario(name, **kwargs)


def test_unknown_scenario_and_parameter():
    with pytest.raises(ValueError, match="unknown scenario 'parade'"):
        make_scenario("parade")
    with pytest.raises(ValueError, match="colour"):
        make_scenario("marathon", colour=3)
    with pytest.raises(ValueError, match="road_width"):
        make_scenario("marathon", road_width=float("nan"))


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": -0.1}, "dt"),
        ({"tau": math.nan}, "tau"),
        ({"V0": -1.0}, "V0"),
        ({"fov_deg": 400.0}, "fov_deg"),
        ({"c": 2.0}, "c"),
        ({"potential": "cubic"}, "potential"),
        ({"sigma": math.inf}, "sigma"),
    ],
)
def test_bad_model_parameters(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SocialForceParams(**kwargs)


def test_every_model_parameter_is_validated():
    from dataclasses import fields

    for f in fields(SocialForceParams):
        bad = "cubic" if f.name == "potential" else math.nan
        with pytest.raises(ValueError, match=f"SocialForceParams.{f.name} must be"):
            SocialForceParams(**{f.name: bad})


def test_simulation_rejects_bad_seed_and_steps():
    sc = make_scenario("crossing", n_agents=4)
    with pytest.raises(ValueError, match="seed"):
        Simulation(sc, seed=-1)
    sim = Simulation(sc, seed=0)
    with pytest.raises(ValueError, match="steps"):
        sim.run(-3)
    with pytest.raises(ValueError, match="pos"):
        sim.set_state(pos=np.zeros((3, 2)))


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_scenarios_span_one_to_many_agents(name):
    for n in (1, 7):
        sim = Simulation(make_scenario(name, n_agents=n), seed=0)
        assert sim.state.n == n
        sim.run(3)


def test_large_crowd_builds_and_steps():
    """10,000 agents build and step (speed itself is measured in `crowdsim bench sim`)."""
    sim = Simulation(make_scenario("commuters", n_agents=10_000, density=2.0), seed=0, record=False)
    sim.run(2)
    assert sim.state.n >= 9_900 and np.isfinite(sim.state.pos).all()


def test_lane_order_parameter_squares_a_mixed_neighbourhood():
    """Lane order squares (n_same - n_opp) / n: a mixed neighbourhood gives 1/9, not 1/3."""
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    sign = np.array([1, 1, 1, -1])
    assert lane_order_parameter(pos, sign) == pytest.approx((3 * (1 / 9) + 1.0) / 4)


def test_lane_order_neighbours_lie_strictly_inside_the_window_and_band():
    """Lane-order neighbours lie strictly inside window (x) and band (y)."""
    assert math.isnan(lane_order_parameter(np.array([[0.0, 0.0], [5.0, 0.0]]), np.array([1, 1])))
    assert math.isnan(lane_order_parameter(np.array([[0.0, 0.0], [5.004, 0.0]]), np.array([1, 1])))
    assert math.isnan(lane_order_parameter(np.array([[0.0, 0.0], [0.0, 0.3]]), np.array([1, 1])))
    assert lane_order_parameter(np.array([[0.0, 0.0], [4.99, 0.29]]), np.array([1, 1])) == 1.0


def test_fundamental_diagram_global_density_is_agents_per_area():
    """FDPoint.global_density is n / (period * width), the corridor's target density."""
    (p,) = fundamental_diagram([1.0], length=10.0, width=4.0, warmup_s=0.2, measure_s=1.0)
    assert p.global_density == pytest.approx(1.0, rel=0.05)
