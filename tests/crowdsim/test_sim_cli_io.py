"""`crowdsim simulate` contract and the trajectory file formats."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from crowdsim.atomic import LEDGER
from crowdsim.cli import main
from crowdsim.trajectories import Trajectories


def test_simulate_writes_npz_contract(tmp_path, capsys):
    out = tmp_path / "m.npz"
    rc = main(
        [
            "simulate",
            "marathon",
            "--agents",
            "30",
            "--steps",
            "12",
            "--seed",
            "3",
            "--out",
            str(out),
            "--plot",
            str(tmp_path / "m.png"),
            "--no-progress",
        ]
    )
    assert rc == 0
    assert (tmp_path / "m.png").stat().st_size > 1000
    table = capsys.readouterr().out
    for key in ("agents", "mean speed", "density", "wall time", "steps/s"):
        assert key in table
    with np.load(out) as data:
        pos = data["positions"]
        assert pos.shape[0] == 13 and pos.shape[2] == 2
        assert data["ids"].shape == (pos.shape[1],)
        for attr in ("group", "prominent", "anomaly", "radius", "desired_speed"):
            assert data[f"attr_{attr}"].shape == (pos.shape[1],)
    again = tmp_path / "again.npz"
    main(
        [
            "simulate",
            "marathon",
            "--agents",
            "30",
            "--steps",
            "12",
            "--seed",
            "3",
            "--out",
            str(again),
            "--no-progress",
        ]
    )
    a, b = Trajectories.load(out), Trajectories.load(again)
    assert np.array_equal(a.positions, b.positions, equal_nan=True)
    # no temporary file left behind: only the ledger of what crowdsim wrote
    assert [p.name for p in tmp_path.glob(".*")] == [LEDGER]


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["simulate", "parade"], "unknown scenario 'parade'"),
        (["simulate", "marathon", "--agents", "-4"], "--agents must be in [1, 1000000], got -4"),
        (["simulate", "marathon", "--agents", "0"], "--agents must be in [1, 1000000], got 0"),
        (["simulate", "marathon", "--density", "7"], "--density must be in (0, 6]"),
        (["simulate", "marathon", "--dt", "0"], "--dt must be in (0, 0.2] seconds, got 0.0"),
        (["simulate", "marathon", "--dt", "nan"], "--dt must be in (0, 0.2] seconds, got nan"),
        (
            ["simulate", "marathon", "--param", "tau=nan"],
            "SocialForceParams.tau must be a finite number > 0, got nan",
        ),
        (["simulate", "marathon", "--set", "road_width=nan"], "road_width must be finite"),
        (["simulate", "marathon", "--set", "bogus=1"], "bogus"),
        (["simulate", "marathon", "--out", "x.csv"], "--out must end in .npz"),
        (["simulate", "marathon", "--plot", "x.jpg"], "--plot must end in .png"),
        (["simulate", "marathon", "--param", "dt=0.02"], "--param dt: use --dt instead"),
        (["simulate", "marathon", "--set", "n_agents=5"], "--set n_agents: use --agents instead"),
        (
            ["simulate", "marathon", "--param", "contact_substeps=2.5"],
            "contact_substeps must be an integer in [1, 10000], got 2.5",
        ),
    ],
)
def test_simulate_bad_input_exit_2_one_line(argv, needle):
    proc = subprocess.run(
        [sys.executable, "-m", "crowdsim.cli", *argv, "--steps", "1", "--no-progress"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in proc.stderr


def test_npz_and_csv_round_trip(tmp_path):
    pos = np.full((3, 2, 2), np.nan)
    pos[0, 0] = [1.0, 2.0]
    pos[1, 0] = [1.5, 2.0]
    pos[1, 1] = [4.0, 4.0]
    pos[2, 1] = [4.5, 4.0]
    traj = Trajectories(pos, np.array([5, 9]), dt=0.04)
    back = Trajectories.load(traj.save(tmp_path / "t.npz"))
    assert np.array_equal(back.positions, pos, equal_nan=True)
    assert back.dt == 0.04 and list(back.ids) == [5, 9]
    csv = Trajectories.from_csv(traj.to_csv(tmp_path / "t.csv"), fps=25.0)
    assert np.allclose(csv.positions, pos, equal_nan=True)
    assert list(csv.ids) == [5, 9]


def test_bad_trajectory_files(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,id,x,y\n0,1,2.0,3.0\n1,1,oops,3.0\n")
    with pytest.raises(ValueError, match=r"bad.csv:3: x 'oops' is not a number"):
        Trajectories.from_csv(bad, fps=25)
    bad.write_text("0,1,2.0\n")
    with pytest.raises(ValueError, match="expected 4 columns"):
        Trajectories.from_csv(bad, fps=25)
    with pytest.raises(ValueError, match="no such trajectory file"):
        Trajectories.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"junk.npz: not a crowdsim trajectories .npz \(not a zip"):
        Trajectories.load(tmp_path / "junk.npz")
    with pytest.raises(ValueError, match="fps"):
        Trajectories.from_csv(bad, fps=0)


def _last_json(text: str) -> dict:
    import json

    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def test_bench_sim_prints_table_and_json(capsys):
    assert main(["bench", "sim", "--sizes", "300", "--peers", "none"]) == 0
    out = capsys.readouterr().out
    assert "sim s/wall s" in out
    report = _last_json(out)
    (ours,) = report["results"]
    assert ours["simulator"] == "crowdsim" and ours["agents"] == 300
    assert ours["steps_per_s"] > 0 and ours["max_overlap"] <= 0.2


def test_bench_sim_scale_run_split_across_workers_sums_their_memory(capsys):
    argv = ["bench", "sim", "--sizes", "200", "--peers", "none", "--scale", "4000"]
    assert main([*argv, "--scale-workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "4000 agents, 2 worker(s)" in out and "with the workers:" in out
    scale = _last_json(out)["scale"]
    assert scale["agents"] == 4000 and scale["workers"] == 2 and scale["steps_per_s"] > 0
    # two spawned interpreters with numpy, numba and pymunk each hold tens of MB
    assert scale["total_peak_rss_mb"] > scale["peak_rss_mb"] + 2 * 20


def test_bench_sim_scale_workers_out_of_range_exit_2():
    cpus = os.cpu_count() or 1
    proc = subprocess.run(
        [sys.executable, "-m", "crowdsim.cli", "bench", "sim", "--scale-workers", str(cpus + 1)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"--scale-workers must be in [1, {cpus}] (os.cpu_count()), got {cpus + 1}" in (
        proc.stderr
    )


def test_bench_fd_writes_plots(tmp_path, capsys):
    argv = [
        "bench",
        "fd",
        "--densities",
        "1",
        "--length",
        "8",
        "--width",
        "3",
        "--warmup",
        "2",
        "--measure",
        "2",
        "--lane-seconds",
        "2",
        "--out",
        str(tmp_path),
    ]
    assert main(argv) == 0
    report = _last_json(capsys.readouterr().out)
    assert report["fundamental_diagram"][0]["target_density"] == 1.0
    assert (tmp_path / "fd.png").stat().st_size > 1000
    assert (tmp_path / "lanes.png").stat().st_size > 1000


def test_bench_bad_flags_are_user_errors():
    proc = subprocess.run(
        [sys.executable, "-m", "crowdsim.cli", "bench", "fd", "--densities", "9"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "--densities must lie in (0, 6]" in proc.stderr


def test_csv_frames_are_shifted_to_start_at_row_zero(tmp_path):
    """A CSV whose first frame is 5 loads with that frame as row 0 and no empty leading rows."""
    path = tmp_path / "late.csv"
    path.write_text("frame,id,x,y\n5,7,1.0,2.0\n6,7,1.5,2.0\n7,3,4.0,4.0\n")
    traj = Trajectories.from_csv(path, fps=25.0)
    assert traj.positions.shape == (3, 2, 2) and traj.ids.tolist() == [3, 7]
    expect = np.full((3, 2, 2), np.nan)
    expect[0, 1] = [1.0, 2.0]
    expect[1, 1] = [1.5, 2.0]
    expect[2, 0] = [4.0, 4.0]
    np.testing.assert_array_equal(traj.positions, expect)
    assert traj.dt == 1 / 25.0


def test_velocities_are_backward_differences_in_metres_per_second():
    """velocities() divides the step by dt and is NaN at entry rows and where absent."""
    pos = np.full((3, 1, 2), np.nan)
    pos[1, 0] = [0.0, 0.0]
    pos[2, 0] = [0.1, -0.2]
    vel = Trajectories(pos, np.array([0]), dt=0.04).velocities()
    assert np.isnan(vel[:2]).all()
    np.testing.assert_allclose(vel[2, 0], [2.5, -5.0])
