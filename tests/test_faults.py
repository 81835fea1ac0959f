"""Faults during a run: signals, a killed process, a full disk (issue 10).

Render part: SIGKILL / SIGINT / SIGTERM during ``crowdsim render`` and a rerun, and a full disk
for ``simulate`` and ``render`` on a small tmpfs (skipped where it cannot be mounted).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from crowdsim.cli import main
from synth_data.mot import verify_sequence
from synth_data.writer import TMP_PREFIX

REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------- render
def _walk_csv(path: Path, frames: int, people: int = 12) -> Path:
    t = np.arange(frames)[:, None]
    i = np.arange(people)[None, :]
    x = (1.0 + 0.05 * t + 0.8 * i).ravel()
    y = (1.0 + 0.5 * (i % 4) + 0 * t).ravel()
    rows = np.column_stack(
        [np.repeat(np.arange(frames), people), np.tile(np.arange(people), frames), x, y]
    )
    with open(path, "w") as fh:
        fh.write("frame,id,x,y\n")
        np.savetxt(fh, rows, fmt=["%d", "%d", "%.3f", "%.3f"], delimiter=",")
    return path


def _start_render(csv: Path, out: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    env = env or dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "crowdsim.cli",
            "render",
            "--trajectories",
            str(csv),
            "--fps",
            "25",
            "--size",
            "640x480",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=REPO,
    )


def _wait_for_frames(
    parent: Path, proc: subprocess.Popen, n: int = 3, timeout: float = 120.0
) -> Path:
    """The render's temporary folder once it holds ``n`` frames (the render is mid-way)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for tmp in parent.glob(f"{TMP_PREFIX}*"):
            if len(list((tmp / "img1").glob("*.jpg"))) >= n:
                return tmp
        if proc.poll() is not None:
            pytest.fail(f"render ended early: {proc.communicate()}")
        time.sleep(0.05)
    proc.kill()
    pytest.fail("render did not start writing frames in time")


@pytest.mark.parametrize(
    "sig, code, word",
    [
        (signal.SIGINT, 130, "interrupted by SIGINT"),
        (signal.SIGTERM, 143, "interrupted by SIGTERM"),
    ],
)
def test_render_signal_removes_its_tmp_folder(tmp_path, sig, code, word, slow_jpeg_env):
    csv = _walk_csv(tmp_path / "walk.csv", frames=2000)
    out = tmp_path / "seq"
    proc = _start_render(csv, out, slow_jpeg_env)
    _wait_for_frames(tmp_path, proc)
    t0 = time.monotonic()
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - t0 < 10, "the render did not stop promptly"
    assert proc.returncode == code, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines[-1] == f"crowdsim render: {word}; removed the unfinished temporary folder of {out}"
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.csv"]


def _catches(pid: int, sig: signal.Signals) -> bool:
    """Whether process ``pid`` has a handler for ``sig`` (Linux: ``SigCgt`` of its status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/<pid>/status")
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_command_without_its_own_handler_ends_with_the_signal_code(tmp_path, sig, code):
    """Every command, not only render and generate, ends a signal with 130 / 143 and one line
    (crowdsim.cli.main turns SIGTERM into crowdsim.jobs.Interrupted while a command runs);
    simulate here, whose output must not appear half-written. Before that, SIGTERM killed it
    without a word (-15) and SIGINT said "interrupted" without the signal's name."""
    out = tmp_path / "walk.npz"
    proc = subprocess.Popen(
        [sys.executable, "-m", "crowdsim.cli", "simulate", "marathon", "--agents", "50"]
        + ["--steps", "100000", "--no-progress", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        cwd=REPO,
    )
    deadline = time.monotonic() + 60
    while not _catches(proc.pid, signal.SIGTERM):  # the command runs under the handler
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"simulate ended or never started: {proc.communicate()}")
        time.sleep(0.02)
    time.sleep(0.3)  # well inside the simulation
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == code, err
    assert err.strip().splitlines() == [f"crowdsim simulate: interrupted by {sig.name}"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_render_sigkill_then_rerun_cleans_up_and_completes(tmp_path, slow_jpeg_env):
    csv = _walk_csv(tmp_path / "walk.csv", frames=2000)
    out = tmp_path / "seq"
    proc = _start_render(csv, out, slow_jpeg_env)
    tmp = _wait_for_frames(tmp_path, proc)
    proc.kill()
    proc.wait(timeout=30)
    assert tmp.is_dir() and not out.exists()  # the leftover of a killed render
    short = _walk_csv(tmp_path / "short.csv", frames=5)
    rerun = _start_render(short, out)
    _, err = rerun.communicate(timeout=120)
    assert rerun.returncode == 0, err
    assert f"removed {tmp}" in err
    assert not tmp.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq", "short.csv", "walk.csv"]
    checks = verify_sequence(out)
    assert checks is not None and len([k for k in checks if k.startswith("img1/")]) == 5


# ---------------------------------------------------------------------------- full disk
@pytest.fixture
def tiny_disk(tmp_path):
    """A 256 KiB tmpfs (root and Linux only), unmounted afterwards."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if not sys.platform.startswith("linux") or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root on Linux")
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _contents(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_full_disk_simulate_and_render(tiny_disk, tmp_path, capsys):
    keep = tiny_disk / "keep.txt"
    keep.write_text("earlier results\n")
    # simulate: 300 agents x 101 steps of float64 positions cannot fit in 256 KiB.
    out = tiny_disk / "crowd.npz"
    rc = main(
        [
            "simulate",
            "marathon",
            "--agents",
            "300",
            "--steps",
            "100",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2
    assert err.strip() == f"crowdsim simulate: error: {out}: no space left on the device"
    assert _contents(tiny_disk) == ["keep.txt"]
    # render: 40 frames of 320x240 JPEG noise do not fit either.
    csv = _walk_csv(tmp_path / "walk.csv", frames=40)
    seq = tiny_disk / "seq"
    rc = main(
        [
            "render",
            "--trajectories",
            str(csv),
            "--fps",
            "25",
            "--size",
            "320x240",
            "--out",
            str(seq),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2
    assert err.strip() == f"crowdsim render: error: {seq}: no space left on the device"
    assert _contents(tiny_disk) == ["keep.txt"]
    assert keep.read_text() == "earlier results\n"


STANDALONE_SCRIPTS = (
    "track_stages",
    "split_balance",
    "split_profile",
    "detect",
    "force_threads",
    "tuning_env_vs_commit",
)


@pytest.mark.parametrize("name", STANDALONE_SCRIPTS)
def test_a_standalone_benchmark_stopped_by_ctrl_c_says_so_in_one_line(name):
    """The six scripts that import nothing of crowdsim's at the top (they also run against
    older code) ended a Ctrl-C in a traceback. The interrupt is raised where each reads its
    arguments, inside ``main()``, so the test never races the script's imports."""
    script = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    code = (
        "import argparse, runpy, sys\n"
        "def stop(*args, **kwargs):\n"
        "    raise KeyboardInterrupt\n"
        "argparse.ArgumentParser.parse_args = stop\n"
        f"sys.argv = [{str(script)!r}]\n"
        f"runpy.run_path({str(script)!r}, run_name='__main__')\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 130, run.stderr
    assert run.stderr.strip().splitlines() == [f"{name}.py: interrupted by SIGINT"]
