"""Property tests (hypothesis) for the simulator: any small scene stays physical."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from crowdsim.scenarios import SCENARIOS, make_scenario
from crowdsim.simulation import Simulation
from crowdsim.validation import max_overlap

scenes = st.fixed_dictionaries(
    {
        "name": st.sampled_from(sorted(SCENARIOS)),
        "n_agents": st.integers(1, 60),
        "density": st.floats(0.2, 4.0),
        "seed": st.integers(0, 2**31 - 1),
    }
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes)
# found by this test on a fresh clone: circulation's shaken packing jammed in a narrow annulus
@example(scene={"name": "circulation", "n_agents": 34, "density": 3.0, "seed": 65537})
def test_any_small_scene_stays_finite_bounded_and_apart(scene):
    sc = make_scenario(scene["name"], n_agents=scene["n_agents"], density=scene["density"])
    sim = Simulation(sc, seed=scene["seed"])
    p = sim.params
    for k in range(40):
        sim.step()
        s = sim.state
        assert np.isfinite(s.pos).all() and np.isfinite(s.vel).all()
        # Speeds stay near the cap; contacts may add a little on top of it.
        speed = np.hypot(s.vel[:, 0], s.vel[:, 1])
        assert (speed <= p.speed_cap * np.maximum(s.desired_speed, 0.5) + 0.5).all()
        if k % 8 == 0:
            assert max_overlap(s.pos, s.radius, sim.world.period) <= 0.2
    ids = sim.trajectories.ids
    assert len(np.unique(ids)) == len(ids) == sim.n_total


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), split=st.integers(1, 14))
def test_split_runs_equal_one_run(seed, split):
    sc = make_scenario("station", n_agents=25, density=0.6)
    a = Simulation(sc, seed=seed)
    a.run(15)
    b = Simulation(sc, seed=seed)
    b.run(split)
    b.run(15 - split)
    assert np.array_equal(a.trajectories.positions, b.trajectories.positions, equal_nan=True)
