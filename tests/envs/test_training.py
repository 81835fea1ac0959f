"""``crowdsim train`` dies cleanly with its environment processes, and damaged policies are
refused in one line naming the file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from envs.episodes import tiny_scenarios
from envs.training import POLICY_META, load_policy

TINY = tiny_scenarios()


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux ``/proc``)."""
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for its new parent to reap it counts as dead)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


SLOW_STEPS = {**TINY, "agents": [30, 40], "frames": 150, "max_width": 320, "max_height": 240}
"""Episodes whose 100-frame steps take a second or two: a SIGKILL lands mid-step, when an
environment process without a parent-death watch keeps tracking, then prints BrokenPipeError
as it sends the step's result to its dead parent (measured: alive 2.1 s after the kill)."""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_sigkilled_train_leaves_no_environment_process_and_prints_nothing(tmp_path):
    """SIGKILL the parent of ``train --envs 2`` while its two environments track: both (and
    multiprocessing's resource tracker) are gone at once, and nobody prints a word (no
    BrokenPipeError from a worker writing to its dead parent)."""
    pytest.importorskip("stable_baselines3")
    spec = tmp_path / "slow.json"
    spec.write_text(json.dumps(SLOW_STEPS))
    cmd = [
        sys.executable,
        "-c",
        "import sys; from crowdsim.cli import main; sys.exit(main())",
        "train",
        "--algo",
        "ppo",
        "--envs",
        "2",
        "--steps",
        "100000",
        "--k",
        "100",
        "--scenarios",
        str(spec),
        "--no-progress",
        "--out",
        str(tmp_path / "out"),
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        t0 = time.monotonic()
        workers: list[int] = []
        while time.monotonic() - t0 < 120:  # until both environments are built and tracking
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            kids = _children(proc.pid)
            workers = [c for c in kids if _rss_mb(c) > 300]
            if len(workers) == 2:
                break
            time.sleep(0.2)
        assert len(workers) == 2, f"two environment processes expected, got {kids}"
        time.sleep(1.5)  # into a step of tracking
        kids = _children(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline and any(_alive(c) for c in kids):
            time.sleep(0.02)
        assert not [c for c in kids if _alive(c)], "children outlived their SIGKILLed parent"
        out, err = proc.communicate(timeout=30)  # EOF: every holder of the pipes is gone
    finally:
        if proc.poll() is None:
            proc.kill()
    assert err.decode() == "" and out.decode() == ""


# ---------------------------------------------------------------------------- damaged zips
@pytest.fixture(scope="module")
def policy_zip(tmp_path_factory) -> Path:
    pytest.importorskip("stable_baselines3")
    from envs.training import train

    out = tmp_path_factory.mktemp("policy")
    said: list[str] = []
    doc = train(
        "ppo",
        out=out,
        steps=4,
        env_kwargs={"scenarios": dict(TINY), "k_frames": 5},
        progress=False,
        log=said.append,
    )
    # the line names the steps PPO trained (whole rollouts), as the record does
    assert said[-1].startswith(f"ppo: {doc['steps']} steps in ") and doc["steps"] >= 4
    return out / "model.zip"


def _rewrite(src: Path, dst: Path, replace: dict[str, bytes | None]) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            data = replace.get(name, zin.read(name))
            if data is not None:
                zout.writestr(name, data)
    return dst


def _truncated_tensors(src: Path, dst: Path) -> Path:
    """``policy.pth`` cut in half, stored with a matching CRC (the zip itself is sound)."""
    with zipfile.ZipFile(src) as zf:
        pth = zf.read("policy.pth")
    return _rewrite(src, dst, {"policy.pth": pth[: len(pth) // 2]})


@pytest.mark.parametrize(
    "damage, needle",
    [
        (lambda s, d: _rewrite(s, d, {POLICY_META: b"[1, 2]"}), "must be a JSON object, got list"),
        (lambda s, d: _rewrite(s, d, {POLICY_META: b"\xff\xfe\x00"}), "is not valid JSON"),
        (lambda s, d: _rewrite(s, d, {POLICY_META: b"{not json"}), "is not valid JSON"),
        (lambda s, d: _rewrite(s, d, {"policy.pth": None}), "the model (policy.pth) is missing"),
        (lambda s, d: _rewrite(s, d, {"data": None}), "the model (data) is missing"),
        (_truncated_tensors, "a damaged policy: stable-baselines3 cannot load it"),
        (
            lambda s, d: d.write_bytes(s.read_bytes()[: s.stat().st_size // 2]) and d,
            "not a stable-baselines3 model",
        ),
    ],
    ids=["meta-list", "meta-binary", "meta-broken", "no-policy", "no-data", "tensors", "cut"],
)
def test_damaged_policies_are_refused_naming_the_file(policy_zip, tmp_path, damage, needle):
    bad = tmp_path / "bad.zip"
    damage(policy_zip, bad)
    with pytest.raises(ValueError) as info:
        load_policy(bad)
    msg = str(info.value)
    assert msg.startswith(str(bad)) and needle in msg and "\n" not in msg
    load_policy(policy_zip)  # the sound one still loads


def test_the_learning_curve_names_its_reward_threshold(tmp_path, monkeypatch):
    """The y label read "accuracy at T px" whatever the environment's threshold was."""
    import matplotlib.pyplot as plt

    from envs.training import plot_learning_curve

    curve = [{"steps": s, "reward_per_step": 50.0 + s / 10} for s in range(0, 100, 10)]
    seen = {}
    real = plt.Figure.savefig

    def spy(fig, *args, **kwargs):
        seen["ylabel"] = fig.axes[0].get_ylabel()
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(plt.Figure, "savefig", spy)
    path = plot_learning_curve(curve, tmp_path / "lc.png", threshold_px=15.0)
    assert path.stat().st_size > 0
    assert seen["ylabel"] == "mean step reward: accuracy at 15 px (%)"
