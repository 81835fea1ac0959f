"""The simulation control hook and the public agent life cycle."""

from __future__ import annotations

import numpy as np
import pytest

from crowdsim.scenarios import make_scenario
from crowdsim.simulation import Simulation


def single_walker() -> Simulation:
    """One agent in a wide periodic corridor, 15 m from both walls (no force but driving)."""
    sc = make_scenario(
        "counterflow",
        n_agents=1,
        density=0.05,
        width=30.0,
        right_fraction=1.0,
        periodic=True,
        inflow=False,
    )
    sim = Simulation(sc, seed=3)
    sim.set_state(pos=[[sim.world.period / 2, 15.0]])
    return sim


def two_groups() -> Simulation:
    """Two clusters of 3 agents, 15 m apart across a 30 m wide periodic corridor: far beyond
    the interaction cutoff of each other for the whole run."""
    sc = make_scenario(
        "counterflow",
        n_agents=6,
        density=0.02,
        width=30.0,
        right_fraction=1.0,
        periodic=True,
        inflow=False,
    )
    sim = Simulation(sc, seed=5)
    x = sim.world.period / 2
    sim.set_state(
        pos=[[x, 5.0], [x + 0.8, 5.5], [x - 0.7, 4.4], [x, 20.0], [x + 0.8, 20.5], [x - 0.7, 19.4]]
    )
    return sim


@pytest.mark.parametrize("u", [(0.3, -0.8), (-1.7, 0.4), (0.0, 0.0)])
def test_controlled_walker_relaxes_to_commanded_velocity_exactly(u):
    """dv/dt = (u - v)/tau: pymunk's explicit Euler gives v_k = u (1 - (1 - dt/tau)^k)."""
    sim = single_walker()
    p = sim.params
    u = np.array(u)
    for k in range(1, 31):
        sim.step(desired_velocity=u[None, :], controlled=sim.state.ids)
        expected = u * (1.0 - (1.0 - p.dt / p.tau) ** k)
        np.testing.assert_allclose(sim.state.vel[0], expected, rtol=1e-9, atol=1e-12)


def test_held_desired_velocity_persists_until_cleared():
    a, b = single_walker(), single_walker()
    u = np.array([[0.5, 0.9]])
    a.set_desired([0], u)
    for _ in range(10):
        a.step()
        b.step(desired_velocity=u, controlled=np.array([True]))
    np.testing.assert_array_equal(a.state.pos, b.state.pos)
    np.testing.assert_array_equal(a.state.vel, b.state.vel)
    # A one-step command overrides the held one; then the held one applies again.
    a.step(desired_velocity=[[0.0, 0.0]], controlled=[0])
    b.step(desired_velocity=[[0.0, 0.0]])
    a.step()
    b.step(desired_velocity=u)
    np.testing.assert_array_equal(a.state.vel, b.state.vel)
    a.clear_desired()
    assert len(a.held_desired[0]) == 0
    a.step()
    b.step()
    np.testing.assert_array_equal(a.state.vel, b.state.vel)


def test_uncontrolled_agents_unchanged_by_control_elsewhere():
    plain, driven = two_groups(), two_groups()
    far = np.array([3, 4, 5])
    for _ in range(40):
        plain.step()
        driven.step(desired_velocity=[[-0.4, 0.6]], controlled=[0])
    rows = plain.index_of(far)
    np.testing.assert_array_equal(driven.state.pos[rows], plain.state.pos[rows])
    np.testing.assert_array_equal(driven.state.vel[rows], plain.state.vel[rows])
    assert not np.allclose(driven.state.pos[0], plain.state.pos[0])  # the driven one moved


def test_empty_command_is_a_plain_step():
    a, b = two_groups(), two_groups()
    for _ in range(5):
        a.step()
        b.step(desired_velocity=np.zeros((0, 2)), controlled=np.zeros(0, np.int64))
    np.testing.assert_array_equal(a.state.pos, b.state.pos)


def test_control_is_deterministic_however_split():
    sc = make_scenario("counterflow", n_agents=40, inflow=True)
    runs = []
    for split in ((30,), (7, 23)):
        sim = Simulation(sc, seed=11)
        sim.set_desired([0, 1, 2], [[1.0, 0.3], [-0.5, 0.0], [0.0, 1.2]])
        for n in split:
            for _ in range(n):
                ids = sim.state.ids[3:8]
                sim.step(desired_velocity=np.tile([[0.2, -1.0]], (len(ids), 1)), controlled=ids)
        runs.append(sim.trajectories)
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    np.testing.assert_array_equal(runs[0].ids, runs[1].ids)


def test_add_remove_query_round_trip_and_ids_never_reused():
    sc = make_scenario("counterflow", n_agents=10, density=0.5, periodic=True, inflow=False)
    sim = Simulation(sc, seed=2)
    assert sim.n_total == 10
    new = sim.add_agents(
        [[1.0, 1.0], [2.0, 3.0]], radius=0.2, desired_speed=[1.0, 1.5], route=[0, 1]
    )
    np.testing.assert_array_equal(new, [10, 11])
    rows = sim.index_of(new)
    np.testing.assert_array_equal(sim.state.pos[rows], [[1.0, 1.0], [2.0, 3.0]])
    np.testing.assert_array_equal(sim.state.desired_speed[rows], [1.0, 1.5])
    np.testing.assert_array_equal(sim.state.route[rows], [0, 1])
    assert 11 in sim.agents_in_range([2.0, 3.1], 0.2)
    assert 10 not in sim.agents_in_range([2.0, 3.1], 0.2)
    assert 11 in sim.agents_in_range([2.05, 3.0], 0.2)  # the cell of a point off the grid
    # Periodic: a point just across the seam finds the agent at x = 1.
    assert 10 in sim.agents_in_range([sim.world.period - 0.1, 1.0], 1.2)
    sim.step()
    sim.remove_agents([10, 3])
    assert not np.isin([10, 3], sim.state.ids).any()
    np.testing.assert_array_equal(sim.index_of([10, 11], strict=False)[0], -1)
    with pytest.raises(ValueError, match="not present"):
        sim.index_of([10])
    with pytest.raises(ValueError, match="not present"):
        sim.remove_agents([10])
    again = sim.add_agents([[4.0, 2.0]])
    np.testing.assert_array_equal(again, [12])  # 10 is gone for good
    assert np.all(np.diff(sim.state.ids) > 0)
    sim.step()
    traj = sim.trajectories
    assert traj.positions.shape[1] == 13
    assert np.isnan(traj.positions[-1, traj.ids.tolist().index(10)]).all()


def test_a_body_across_a_wall_is_refused_and_nothing_is_added():
    """A body placed across a corridor wall had been pushed out of the corridor by pymunk
    (to y = -1.2 and 7.2) in silence."""
    sc = make_scenario("counterflow", n_agents=5, inflow=False)
    sim = Simulation(sc, seed=0)
    before, n_total = sim.state.pos.copy(), sim.n_total
    for pos, radius in (([3.0, 0.0], 0.2), ([3.0, -0.1], 0.2), ([2.0, 5.5], 0.8)):
        with pytest.raises(ValueError, match=r"add_agents.pos\[1\] = .* overlaps the wall"):
            sim.add_agents([[1.0, 1.0], pos], radius=radius)
    assert sim.n_total == n_total
    np.testing.assert_array_equal(sim.state.pos, before)
    # touching the wall's thickness, or wholly beyond it, is taken
    ids = sim.add_agents([[3.0, 0.21], [4.0, -0.5]], radius=0.2)
    np.testing.assert_array_equal(sim.state.pos[sim.index_of(ids)], [[3.0, 0.21], [4.0, -0.5]])
    # a periodic world checks x where the body will be, on [0, period)
    sim = Simulation(make_scenario("counterflow", n_agents=5, periodic=True), seed=0)
    with pytest.raises(ValueError, match=r"pos\[0\] = .* overlaps the wall from \(-1, 6\)"):
        sim.add_agents([[sim.world.period + 0.5, 5.9]])


def test_first_wall_overlap_matches_brute_force_in_any_chunk():
    from crowdsim.world import first_wall_overlap

    rng = np.random.default_rng(4)
    for _ in range(50):
        m, n = int(rng.integers(1, 12)), int(rng.integers(1, 40))
        walls = np.column_stack([rng.uniform(0, 10, (m, 4)), np.full(m, 0.05)])
        walls[0, 2:4] = walls[0, :2]  # a wall of one point
        pos, radius = rng.uniform(0, 10, (n, 2)), rng.uniform(0.1, 1.0, n)
        a, u = walls[:, :2], walls[:, 2:4] - walls[:, :2]
        want = None
        for i in range(n):
            d = []
            for j in range(m):
                len2 = u[j] @ u[j]
                t = min(1.0, max(0.0, (pos[i] - a[j]) @ u[j] / len2)) if len2 else 0.0
                d.append(float(np.hypot(*(pos[i] - a[j] - t * u[j]))))
            if min(d) < radius[i]:
                want = (i, int(np.argmin(d)), min(d))
                break
        for chunk in (1, 5, 1 << 20):
            got = first_wall_overlap(pos, radius, walls, chunk=chunk)
            assert (got is None) == (want is None)
            if got is not None:
                assert got[:2] == want[:2] and got[2] == pytest.approx(want[2], abs=1e-12)


def test_bad_control_input_is_refused():
    sim = two_groups()
    with pytest.raises(ValueError, match="shape"):
        sim.step(desired_velocity=np.zeros((2, 2)), controlled=[0])
    with pytest.raises(ValueError, match="not present"):
        sim.step(desired_velocity=np.zeros((1, 2)), controlled=[99])
    with pytest.raises(ValueError, match="finite"):
        sim.set_desired([0], [np.nan, 0.0])
    with pytest.raises(ValueError, match=r"set_desired.velocity must be at most .* agent 0"):
        sim.set_desired([0], [500.0, 0.0])  # held unchecked, it threw the agent off the world
    with pytest.raises(ValueError, match="without desired_velocity"):
        sim.step(controlled=[0])
    with pytest.raises(ValueError, match="radius"):
        sim.add_agents([[1.0, 1.0]], radius=-0.1)
    with pytest.raises(ValueError, match="route"):
        sim.add_agents([[1.0, 1.0]], route=7)


@pytest.mark.parametrize("period", [0.0, 9.0, 2.5])
def test_k_nearest_matches_brute_force(period):
    from crowdsim.forces import k_nearest

    rng = np.random.default_rng(int(period * 10))
    pos = rng.uniform(0, [period or 12.0, 6.0], (300, 2))
    pos[5] = pos[4]  # a tie at distance 0
    rows = np.array([0, 4, 5, 17, 299])
    idx, dist, rel = k_nearest(pos, rows, 5, 1.2, period)
    for q, i in enumerate(rows):
        d = pos - pos[i]
        if period:
            d[:, 0] -= period * np.floor(d[:, 0] / period + 0.5)
        r = np.hypot(d[:, 0], d[:, 1])
        r[i] = np.inf
        near = np.lexsort((np.arange(len(pos)), r))[:5]
        near = near[r[near] <= 1.2]
        np.testing.assert_array_equal(idx[q, : len(near)], near)
        assert (idx[q, len(near) :] == -1).all()
        np.testing.assert_allclose(dist[q, : len(near)], r[near], rtol=1e-12)
        np.testing.assert_allclose(rel[q, : len(near)], d[near], atol=1e-12)


def test_nearest_wall_distance_and_direction():
    from crowdsim.forces import WallGrid, nearest_wall

    walls = np.array([[0.0, 0.0, 10.0, 0.0, 0.05], [0.0, 4.0, 10.0, 4.0, 0.05]])
    pts = np.array([[5.0, 1.0], [5.0, 3.5], [5.0, 2.0], [-3.0, 2.0]])
    clearance, direction = nearest_wall(pts, walls, WallGrid(walls, 2.5), 2.5)
    np.testing.assert_allclose(clearance[:3], [0.95, 0.45, 1.95])
    np.testing.assert_allclose(direction[:3], [[0, -1], [0, 1], [0, -1]])
    assert clearance[3] == np.inf and not direction[3].any()


def test_starting_velocities_hold_the_speed_limit():
    """A body started at 1e6 m/s had left the world in one step and been removed unseen."""
    sim = two_groups()
    with pytest.raises(ValueError, match=r"add_agents.vel must be at most .* row 0"):
        sim.add_agents([[1.0, 1.0]], vel=[1e6, 0.0])
    before = sim.state.pos.copy()
    with pytest.raises(ValueError, match=r"set_state.vel must be at most"):
        sim.set_state(pos=before + 0.1, vel=np.full((sim.state.n, 2), 1e6))
    np.testing.assert_array_equal(sim.state.pos, before)  # nothing set when one is refused


def test_a_periodic_world_reads_its_speeds_the_short_way_round():
    """A step across the seam of a periodic corridor had counted as a jump of the whole
    length (up to 417 m/s): the trajectories now carry the period."""
    sim = Simulation(make_scenario("counterflow", n_agents=60, periodic=True, inflow=False), seed=1)
    traj = sim.run(150)
    assert traj.period == sim.world.period > 0
    speed = np.linalg.norm(traj.velocities(), axis=-1)
    assert np.nanmax(speed) < 5.0
    back = traj.__class__(positions=traj.positions, ids=traj.ids, dt=traj.dt, meta={"period": "x"})
    with pytest.raises(ValueError, match="meta.period must be a length >= 0 m, got 'x'"):
        back.velocities()
