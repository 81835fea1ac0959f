"""The simulator split across worker processes (crowdsim.decomposition, issue 16).

Each test that starts workers pays about 2 s of process start-up (spawn imports numba and
pymunk), so the scenes are small and the tests few.
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import crowdsim.decomposition as dec
from crowdsim.cli import main
from crowdsim.decomposition import StripLayout, WorkerFailed, _write_back, strip_layout
from crowdsim.scenarios import make_scenario
from crowdsim.simulation import Simulation
from crowdsim.validation import corridor_speed, lane_formation, overlap_stats
from crowdsim.world import World, polyline

TWO_CORES = (os.cpu_count() or 1) >= 2
needs_two = pytest.mark.skipif(not TWO_CORES, reason="needs 2 CPU cores for workers=2")

# sha256 of the trajectories below, computed with the simulator *before* workers existed
# (git HEAD 2026-05, crowdsim/simulation.py without the workers keyword): 6fcb4ae8...b42.
# Since 2026-11-27 a periodic world wraps its starting people onto [0, period) (frame 0 had
# recorded some past the seam), so the periodic counterflow's bits moved; the other three
# runs are the same. The digest here is the plain simulator's after that fix.
WORKERS_1_DIGEST = "e0b7e14676049b7886c9d1583101a7199f4dc4f88cdf07630af35f3640613370"


def _digest(**kw) -> str:
    h = hashlib.sha256()
    for name, skw in [
        ("counterflow", dict(n_agents=60)),
        ("counterflow", dict(n_agents=60, periodic=True, inflow=False)),
        ("marathon", dict(n_agents=60)),
        ("groups", dict(n_agents=40)),
    ]:
        tr = Simulation(make_scenario(name, **skw), seed=3, **kw).run(60)
        h.update(np.ascontiguousarray(tr.positions).tobytes())
        h.update(tr.ids.tobytes())
    return h.hexdigest()


def test_workers_1_is_bit_identical_to_the_plain_simulator():
    assert _digest() == WORKERS_1_DIGEST
    assert _digest(workers=1) == WORKERS_1_DIGEST


@pytest.mark.parametrize("bad", [0, -1, 10_000, 1.5, True, "2"])
def test_bad_worker_counts_name_the_value(bad):
    with pytest.raises(ValueError, match=r"workers must be an integer in \[1, \d+\].*got"):
        Simulation(make_scenario("counterflow", n_agents=5), workers=bad)


@pytest.mark.parametrize("bad", ["0", str((os.cpu_count() or 1) + 1)])
def test_cli_workers_out_of_range_exit_2(bad, capsys):
    rc = main(["simulate", "marathon", "--agents", "5", "--steps", "1", "--workers", bad])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert f"--workers must be in [1, {os.cpu_count()}] (os.cpu_count()), got {bad}" in err[0]


def test_strips_follow_the_geometry_only():
    world = World(polyline([(0, 0), (100, 0)]), (-1.0, -1.0, 101.0, 21.0))
    lay = strip_layout(world, 2, cutoff=1.5)
    assert (lay.axis, lay.edges, lay.n, lay.halo) == (0, (-1.0, 50.0, 101.0), 2, 2.0)
    np.testing.assert_array_equal(lay.owner(np.array([-5.0, 49.9, 50.0, 500.0])), [0, 0, 1, 1])
    assert lay.window(0) == (-np.inf, 52.0) and lay.window(1) == (48.0, np.inf)
    tall = World(np.zeros((0, 5)), (0.0, 0.0, 10.0, 40.0))
    assert strip_layout(tall, 2, 1.5).axis == 1
    with pytest.raises(ValueError, match="workers=16: strips of 2.50 m .* use fewer workers"):
        strip_layout(tall, 16, 1.5)


def test_periodic_windows_unwrap_around_the_strip():
    lay = StripLayout.equal(axis=0, lo=0.0, width=10.0, n=2, period=20.0, halo=2.0)
    assert lay.window(0) == (-2.0, 12.0)
    # x = 19 is 1 m left of worker 0's strip across the seam; x = 1 is 1 m right of worker 1's.
    np.testing.assert_allclose(lay.local(0, np.array([19.0, 1.0, 11.0])), [-1.0, 1.0, 11.0])
    np.testing.assert_allclose(lay.local(1, np.array([1.0, 19.0, 9.0])), [21.0, 19.0, 9.0])


def test_balanced_strips_split_the_agents_evenly_and_stay_twice_the_halo_wide():
    lay = StripLayout.equal(axis=0, lo=0.0, width=25.0, n=4, period=0.0, halo=2.0)
    # 40 agents in [0, 10) and 40 in [90, 100): equal strips would give 40, 0, 0, 40
    coord = np.r_[np.arange(40) * 0.25, 90.0 + np.arange(40) * 0.25]
    bal = lay.balanced(coord)
    assert bal.edges[0] == 0.0 and bal.edges[-1] == 100.0  # the outer edges stay
    np.testing.assert_array_equal(np.bincount(bal.owner(coord), minlength=4), [20, 20, 20, 20])
    # np.quantile (linear) at 1/4, 1/2, 3/4: 4.75 + 0.75 * 0.25, 9.75 + (90 - 9.75) / 2, ...
    assert bal.edges[1:4] == (4.9375, 49.875, 94.8125)
    # all agents in 2 m: the inner borders crowd together, each strip 2 * halo = 4 m wide
    packed = lay.balanced(np.linspace(50.0, 52.0, 100))
    assert np.allclose(np.diff(packed.edges)[1:3], 4.0) and min(np.diff(packed.edges)) >= 4.0
    assert lay.balanced(np.zeros(0)) is lay
    assert StripLayout.equal(0, 0.0, 50.0, 1, 0.0, 2.0).balanced(coord).n == 1


def _lanes_corridor(**kw):
    return make_scenario(
        "counterflow",
        n_agents=240,
        density=1.0,
        width=6.0,
        right_fraction=0.5,
        periodic=True,
        inflow=False,
        **kw,
    )


@needs_two
def test_two_workers_are_deterministic_and_close_to_one():
    runs = []
    for _ in range(2):
        with Simulation(_lanes_corridor(), seed=4, workers=2) as sim:
            runs.append(sim.run(50))
    a, b = runs
    np.testing.assert_array_equal(a.positions, b.positions)  # every step, bit for bit
    one = Simulation(_lanes_corridor(), seed=4).run(50)
    # Same start; after one step only floating-point order and border contacts differ.
    np.testing.assert_array_equal(a.positions[0], one.positions[0])
    d = np.abs(a.positions[1] - one.positions[1])
    d[:, 0] = np.minimum(d[:, 0], 40.0 - d[:, 0])  # across the seam of the 40 m period
    assert d.max() < 1e-3
    assert not np.array_equal(a.positions[-1], one.positions[-1])


@needs_two
def test_sources_sinks_and_migration_keep_every_agent_once():
    # A non-periodic corridor with inflow at one end and sinks at the other: agents enter
    # (the shared memory grows), walk across the strip border and leave.
    sc = make_scenario("counterflow", n_agents=80, width=4.0)
    with Simulation(sc, seed=2, workers=2) as sim:
        lay = sim._engine.layout
        start_strip = lay.owner(sim.state.pos[:, lay.axis])
        tr = sim.run(150)
        ids = sim.state.ids
        assert np.all(np.diff(ids) > 0) and sim.n_total > 80  # sorted, new agents came in
        assert np.isfinite(sim.state.pos).all()
        end_strip = lay.owner(sim.state.pos[:, lay.axis])
        moved = start_strip[ids[ids < 80]] != end_strip[ids < 80]
        assert moved.any()  # somebody migrated to the other worker
        mean_ov, max_ov = overlap_stats(sim.state.pos, sim.state.radius)
        assert max_ov < 0.3
    assert tr.positions.shape[1] == sim.n_total


@needs_two
def test_unsupported_features_say_so():
    with Simulation(_lanes_corridor(), seed=0, workers=2) as sim:
        with pytest.raises(ValueError, match="set_desired is not supported with workers > 1"):
            sim.set_desired(sim.state.ids[:2], (1.0, 0.0))
        with pytest.raises(ValueError, match=r"step\(desired_velocity.*workers=1"):
            sim.step(np.zeros((sim.state.n, 2)))
        # remove_agents and set_state are supported
        sim.remove_agents(sim.state.ids[:3])
        sim.set_state(vel=np.zeros((sim.state.n, 2)))
        sim.step()
        assert sim.state.n == 237 and 0 not in sim.state.ids
    with pytest.raises(ValueError, match="workers were stopped"):
        sim.step()


@needs_two
@pytest.mark.parametrize("serial", [False, True])
def test_killed_worker_stops_the_run_and_leaves_nothing(tmp_path, serial):
    sim = Simulation(_lanes_corridor(), seed=0, workers=2)
    sim.engine.serial = serial  # then worker 1 dies while the parent waits for worker 0
    sim.run(3)
    pids = sim._engine.pids
    os.kill(pids[1], 9)
    with pytest.raises(WorkerFailed, match=r"^worker 1 \(pid \d+\) died at step 3 \(killed by"):
        sim.step()
    assert multiprocessing.active_children() == []
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@needs_two
def test_cli_worker_death_one_line_exit_2_no_output(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(dec, "_TEST_DIE_AT", (1, 5))
    out = tmp_path / "t.npz"
    argv = ["simulate", "counterflow", "--agents", "80", "--steps", "20", "--no-progress"]
    rc = main([*argv, "--set", "periodic=true", "--workers", "2", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert "worker 1" in err[0] and "died at step 5" in err[0] and "nothing written" in err[0]
    assert list(tmp_path.iterdir()) == []
    assert multiprocessing.active_children() == []


@needs_two
def test_a_worker_that_dies_before_its_start_up_data_is_named_not_waited_for(monkeypatch):
    """More start-up data than a pipe holds (about 48 bytes an agent, 3,000 agents here):
    a worker that dies before reading it had left the parent blocked in start() for good."""
    import time

    monkeypatch.setattr(dec, "_TEST_DIE_AT", (1, -2))
    t0 = time.monotonic()
    with pytest.raises(WorkerFailed, match=r"^worker 1 \(pid \d+\) died while starting \(killed"):
        Simulation(make_scenario("counterflow", n_agents=3000), seed=0, workers=2)
    assert time.monotonic() - t0 < 60
    assert multiprocessing.active_children() == []


@needs_two
def test_split_changes_no_physics():
    """1 vs 2 workers on a periodic counterflow corridor: the lane order and walking speed
    of the split run stay within the spread between two seeds of the 1-worker run."""
    kw = dict(n_agents=240, density=1.0, width=6.0, seconds=16.0, every_s=2.0)
    one = [lane_formation(seed=s, **kw) for s in (0, 1)]
    two = lane_formation(seed=0, workers=2, **kw)
    late = [np.mean(r["lane_order"][-3:]) for r in (*one, two)]
    noise = max(2 * abs(late[0] - late[1]), 0.05)
    assert abs(late[2] - late[0]) <= noise
    assert late[2] > 2 * np.mean(two["random_mix"])  # lanes did form
    # A fundamental-diagram point: speed within Weidmann's band and the seed spread.
    pts = [corridor_speed(2.0, seed=s, warmup_s=6.0, measure_s=6.0) for s in (0, 1)]
    p2 = corridor_speed(2.0, seed=0, warmup_s=6.0, measure_s=6.0, workers=2)
    assert abs(p2["ratio"] - 1) <= 0.2
    spread = max(2 * abs(pts[0]["speed"] - pts[1]["speed"]), 0.05)
    assert abs(p2["speed"] - pts[0]["speed"]) <= spread
    assert p2["max_overlap"] <= pts[0]["max_overlap"] + 0.05


@needs_two
def test_serial_steps_change_nothing_and_the_timing_adds_up():
    runs, timings = [], []
    for serial in (False, True):
        with Simulation(_lanes_corridor(), seed=4, workers=2) as sim:
            sim.engine.serial = serial
            sim.run(3)
            sim.engine.reset_timing()
            runs.append(sim.run(12))
            timings.append(sim.engine.timing())
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    for t in timings:
        assert t["steps"] == 12 and len(t["busy_ms"]) == 2
        assert min(t["busy_ms"]) > 0
        assert t["critical_ms"] >= max(t["busy_ms"]) - 1e-9  # the mean of each step's slowest
        assert sum(t["stage_ms"].values()) <= t["busy_mean_ms"] + 1e-9
        assert set(t["stage_ms"]) == set(dec.STRIP_STAGES)
    side, alone = timings
    assert side["step_ms"] >= side["critical_ms"]
    assert side["barrier_ms"] == side["step_ms"] - side["critical_ms"]
    assert alone["serial"] and alone["step_ms"] >= sum(alone["busy_ms"])


@needs_two
def test_crowded_strip_is_recut_deterministically_and_keeps_every_agent_once():
    # The bench corridor's crowd fills its first 23 of 35 m and walks on: equal strips hold
    # about 3/4 and 1/4 of the agents, so the parent moves the border to the median.
    from crowdsim.bench.sim import _ours_scenario, corridor_layout

    runs, owned = [], []
    for _ in range(2):
        with Simulation(_ours_scenario(corridor_layout(400)), seed=1, workers=2) as sim:
            eng = sim.engine
            equal = eng.layout
            runs.append(sim.run(2 * dec.BALANCE_EVERY + 1))
            assert eng.rebalances >= 1 and eng.layout != equal
            # as the workers count them at the start of the last step, with their own strips
            owned.append(eng.owned.copy())
            assert owned[-1].sum() == 400
            assert len(np.unique(sim.state.ids)) == sim.state.n == 400  # nobody lost or doubled
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    before = np.bincount(equal.owner(runs[0].positions[0][:, 0]), minlength=2)
    assert before.max() > 1.3 * before.mean()
    assert owned[0].max() <= 1.1 * owned[0].mean()  # re-cut at the last check, 1 step ago
    mean_ov, max_ov = overlap_stats(sim.state.pos, sim.state.radius)
    assert max_ov < 0.3
    # The re-cut moved bodies between spaces, not the physics: the grid leaves 0.2 m between
    # neighbours (no contacts), so every step matches one process up to the order of sums.
    one = Simulation(_ours_scenario(corridor_layout(400)), seed=1).run(2 * dec.BALANCE_EVERY + 1)
    assert np.abs(runs[0].positions - one.positions).max() < 1e-9
    assert (runs[0].positions[-1, :, 0] - runs[0].positions[0, :, 0]).mean() > 0.5  # they walked


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--workers", "1"], "--workers must be in [2, "),
        (["--scenarios", "nowhere"], "--scenarios: unknown 'nowhere'"),
        (["--steps", "0"], "--agents, --warmup and --steps must be >= 1"),
        (["--png", "{mine}"], "--png {mine}: the file exists and crowdsim cannot prove it wrote"),
    ],
)
def test_split_balance_benchmark_names_bad_flags(run_benchmark, tmp_path, args, message):
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"a picture of the user's")
    out = run_benchmark("split_balance.py", *(a.format(mine=mine) for a in args))
    message = message.format(mine=mine)
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr
    assert mine.read_bytes() == b"a picture of the user's"


def _resident_mb(pid: int) -> float:
    with open(f"/proc/{pid}/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


@needs_two
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/<pid>/statm")
def test_workers_do_not_leak_the_pymunk_rows():
    """Each worker read its bodies back through a fresh pymunk.batch.Buffer every step, whose
    C arrays nothing frees (+16 MB a worker here before, +0.2 after); crowdsim.forces.BodyRows
    reuses one."""
    sc = make_scenario("counterflow", n_agents=6000, periodic=True, inflow=False)
    with Simulation(sc, seed=0, workers=2, record=False) as sim:
        sim.run(20)
        before = [_resident_mb(pid) for pid in sim.engine.pids]
        sim.run(150)
        grown = [_resident_mb(pid) - b for pid, b in zip(sim.engine.pids, before, strict=True)]
    assert max(grown) < 6.0, grown


@settings(max_examples=200, deadline=None)
@given(
    st.sets(st.integers(0, 400), max_size=150),
    st.sets(st.integers(0, 400), max_size=150),
)
def test_sorted_differences_are_setdiff1d(a, b):
    """A strip's bodies to remove and to add: one merge gives numpy's two set differences."""
    a = np.array(sorted(a), np.int64)
    b = np.array(sorted(b), np.int64)
    gone, new = dec._sorted_differences(a, b)
    np.testing.assert_array_equal(gone, np.setdiff1d(a, b, assume_unique=True))
    np.testing.assert_array_equal(new, np.setdiff1d(b, a, assume_unique=True))


def test_balanced_strips_crowded_at_the_far_end_are_pushed_back_inside():
    """Agents packed at the top end: strips are pushed back, each 2 * halo wide."""
    lay = StripLayout.equal(axis=0, lo=0.0, width=25.0, n=4, period=0.0, halo=2.0)
    bal = lay.balanced(np.linspace(98.0, 100.0, 100))
    assert bal.edges == (0.0, 88.0, 92.0, 96.0, 100.0)


def test_write_back_keeps_agents_within_one_metre_outside_the_bounds():
    """An agent up to 1 m beyond the y bounds is still written back; one farther out has left."""
    bodies = np.array([[5.0, 10.5, 1.0, 0.0], [5.0, 11.5, 1.0, 0.0], [5.0, -0.5, 0.0, 1.0]])
    rows = np.arange(3, dtype=np.int64)
    ids = np.array([0, 1, 2], np.int64)
    wp = np.array([3, 4, 5], np.int64)
    bounds = np.array([0.0, 0.0, 10.0, 10.0])
    pos = np.zeros((3, 2))
    vel = np.zeros((3, 2))
    wp_out = np.zeros(3, np.int64)
    alive = np.zeros(3, np.uint8)
    assert _write_back(bodies, rows, ids, wp, 0.0, bounds, pos, vel, wp_out, alive)
    np.testing.assert_array_equal(alive, [1, 0, 1])
    np.testing.assert_array_equal(pos, [[5.0, 10.5], [0.0, 0.0], [5.0, -0.5]])
    np.testing.assert_array_equal(wp_out, [3, 0, 5])
