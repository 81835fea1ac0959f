"""``benchmarks/edge_births.py``: which tracks count as lost at birth, and where."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

NAN = np.nan


@pytest.fixture
def lost_at_birth(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from edge_births import lost_at_birth

    return lost_at_birth


def test_only_a_track_that_ends_at_birth_while_its_person_stays_counts(lost_at_birth):
    """Four people in a 100x50 frame over 10 frames: id 1 born on the left edge, tracked one
    frame, in view to the end (an edge case, 9 frames lost); id 2 likewise in the middle (not
    the edge); id 3 tracked throughout; id 4's track ends at birth but its person leaves two
    frames later (fewer than --stays)."""
    t = 10
    gt = np.full((t, 4, 2), NAN)
    gt[:, 0] = np.c_[np.linspace(0.4, 20, t), np.full(t, 25.0)]
    gt[:, 1] = [50.0, 25.0]
    gt[:, 2] = [70.0, 10.0]
    gt[5:8, 3] = [30.0, 40.0]
    pos = np.full((t, 4, 2), NAN)
    pos[0, 0] = [0.4, 25.0]
    pos[0, 1] = [50.0, 25.0]
    pos[:, 2] = [70.0, 10.0]
    pos[5, 3] = [30.0, 40.0]
    res = SimpleNamespace(ids=np.array([1, 2, 3, 4]), positions=pos, n_frames=t)
    cases = lost_at_birth(np.array([1, 2, 3, 4]), gt, res, 3, 5, 3.0, (100, 50))
    assert [(c["id"], c["edge"], c["frames_lost"]) for c in cases] == [(1, True, 9), (2, False, 9)]
    assert cases[0]["at"] == [0.4, 25.0] and cases[0]["born"] == cases[0]["ended"] == 0


def test_the_script_names_bad_flags(run_benchmark):
    out = run_benchmark("edge_births.py", "--frames", "1")
    assert out.returncode == 2 and "--frames >= 2" in out.stderr and "Traceback" not in out.stderr
    out = run_benchmark("edge_births.py", "--tracker", "kcf")
    assert out.returncode == 2 and "kcf" in out.stderr and "Traceback" not in out.stderr
