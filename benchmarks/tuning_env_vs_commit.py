"""TrackerTuning-v0 now (episode cache) against the env of a past commit, in turn.

Issue 15 asked for 3x the env steps/s of the day it was filed. This script times, round by
round, the env of ``--commit`` (a ``git archive`` copy, which renders its episode at every
reset) and today's env reading its episodes from an episode cache, with one protocol for
both: 4 episodes of 100 frames at 100 people, K = 25 frames a step, default action, resets
counted (whole-episode env steps/s, as ``crowdsim bench envs`` counts them). The machine's
speed drifts, so the two run in turn and every round's ratio is printed::

    python benchmarks/tuning_env_vs_commit.py --commit 773958a~1 --rounds 3

Each side runs in its own process (numba threads 1) and times its second pass over the
episodes; one untimed run of each comes first (compiling, filling the cache). Prints a
table and one JSON object.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The protocol of crowdsim.bench.envs._run_episodes, spelled out: the old commit's copy has
# no such helper, and both sides must run the same code to be compared.
CHILD = r"""
import json, sys, time
import numba
import numpy as np
numba.set_num_threads(1)
from crowdsim.bench.envs import _tuning_kwargs
from envs.tracker_tuning import TrackerTuningEnv

cache = sys.argv[1]
kwargs = _tuning_kwargs(100, 100, 25)
if cache:
    env = TrackerTuningEnv(**kwargs, pool=4, episode_cache=cache)
    env.episodes.fill(progress=False)
else:
    env = TrackerTuningEnv(**kwargs)
action = np.zeros(env.action_space.shape, np.float32)


def episodes():
    steps, targets = 0, []
    t0 = time.perf_counter()
    for i in range(4):
        env.reset(seed=i, **({"options": {"episode": i}} if cache else {}))
        done = False
        while not done:
            _, _, done, _, info = env.step(action)
            steps += 1
            targets.append(info["targets"])
    wall = time.perf_counter() - t0
    return {"steps": steps, "steps_per_s": steps / wall, "targets": float(np.mean(targets))}


episodes()  # warm: numba loads its compiled kernels on first call
print(json.dumps(episodes()))
"""


class _ChildFailed(Exception):
    """A timing process that exited with an error (the message is its last stderr line)."""


def _rate(pythonpath: Path, cache: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, cache],
        cwd=tempfile.gettempdir(),  # not the checkout: its packages would shadow the copy
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["no message"])[-1]
        raise _ChildFailed(f"the env of {pythonpath} failed (exit {out.returncode}): {last}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _rounds(old: Path, cache: str, rounds: int) -> list[dict]:
    """``rounds`` rounds of the old env then today's cached one, after one untimed run of
    each (filling the episode cache, compiling both copies into numba's cache)."""
    _rate(ROOT, cache)
    _rate(old, "")
    rows = []
    for r in range(rounds):
        before = _rate(old, "")
        now = _rate(ROOT, cache)
        rows.append(
            {
                "round": r,
                "commit_steps_per_s": before["steps_per_s"],
                "commit_targets": before["targets"],
                "cached_steps_per_s": now["steps_per_s"],
                "cached_targets": now["targets"],
                "ratio": now["steps_per_s"] / before["steps_per_s"],
            }
        )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--commit", default="773958a~1", help="the env to compare with (773958a~1)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, got {args.rounds}")
    with tempfile.TemporaryDirectory(prefix="crowdsim-env-ab-") as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", args.commit], capture_output=True, check=False
        )
        if archive.returncode != 0:
            print(f"--commit {args.commit!r}: {archive.stderr.decode().strip()}", file=sys.stderr)
            return 2
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(old, filter="data")
        try:
            rows = _rounds(old, str(Path(tmp) / "episodes"), args.rounds)
        except _ChildFailed as e:
            print(f"--commit {args.commit!r}: {e}", file=sys.stderr)
            return 2
    print(f"{'round':>5} {args.commit + ' steps/s':>20} {'cached steps/s':>15} {'ratio':>6}")
    for row in rows:
        print(
            f"{row['round']:>5} {row['commit_steps_per_s']:>20.2f} "
            f"{row['cached_steps_per_s']:>15.2f} {row['ratio']:>5.2f}x"
        )
    print(json.dumps({"benchmark": "tuning_env_vs_commit", "commit": args.commit, "rounds": rows}))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("tuning_env_vs_commit.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
