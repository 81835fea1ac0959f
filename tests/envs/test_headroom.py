"""Headroom: fixed candidates, exact bookkeeping of (a), (b), (c), and a branch that changes
nothing when every candidate is the same."""

from __future__ import annotations

import json

import numpy as np
import pytest

from crowdsim.cli import main
from envs.episodes import tiny_scenarios
from envs.headroom import candidate_actions, measure_headroom, sequence_headroom
from envs.param_space import ParamSpace
from envs.tuners import Objective

TWO = {**tiny_scenarios(), "scenarios": ["counterflow", "crossing"]}


def test_candidates_are_the_defaults_then_seeded_sobol_points():
    space = ParamSpace()
    a = candidate_actions(space, 9, seed=3)
    assert a.shape == (9, 5) and not a[0].any()
    assert (np.abs(a[1:]) <= 1).all() and len({tuple(r) for r in a}) == 9
    np.testing.assert_array_equal(a, candidate_actions(space, 9, seed=3))
    assert not np.array_equal(a, candidate_actions(space, 9, seed=4))
    with pytest.raises(ValueError, match="candidates"):
        candidate_actions(space, 0)


@pytest.mark.parametrize("tracker", ["bqp", "pnmc"])
def test_branching_the_tracker_changes_nothing(tracker):
    """With the defaults as the only candidate, the segment oracle (a state copy per segment)
    scores exactly what one uninterrupted run does."""
    from envs.heldout import heldout_episodes

    objective = Objective(scenarios=dict(tiny_scenarios()), tracker=tracker)
    (_, seq, _), *_ = heldout_episodes(objective, 1)
    space = objective.space()
    r = sequence_headroom(seq, tracker, space, np.zeros((1, space.dim)), k_frames=3)
    assert r["oracle"] == r["static"][0] and r["oracle_choices"] == [0] * 4  # 11 frames / 3


def test_a_b_c_follow_from_the_per_sequence_scores(tmp_path):
    objective = Objective(scenarios=TWO)
    doc = measure_headroom(objective, 2, candidates=5, k_frames=4, progress=False)
    static = np.array([s["static"] for s in doc["sequences"]])
    g = int(np.argmax(static.mean(0)))
    assert doc["global_best"] == doc["candidates"][g]
    assert set(doc["families"]) == {"counterflow", "crossing"}
    for fam, r in doc["families"].items():
        rows = [i for i, s in enumerate(doc["sequences"]) if s["family"] == fam]
        assert r["n"] == 2
        assert r["a_global_static"] == pytest.approx(static[rows, g].mean())
        assert r["b_family_static"] == pytest.approx(static[rows].mean(0).max())
        assert r["b_minus_a"] >= 0 and r["defaults"] == pytest.approx(static[rows, 0].mean())
        oracle = [doc["sequences"][i]["oracle"] for i in rows]
        assert r["c_oracle"] == pytest.approx(np.mean(oracle))
        assert all(0 <= s["oracle"] <= 100 for s in doc["sequences"])


def test_cli_writes_and_refuses_a_foreign_table(tmp_path, capsys):
    spec = tmp_path / "d.json"
    spec.write_text(json.dumps(dict(tiny_scenarios())))
    out = tmp_path / "o"
    argv = ["headroom", "--scenarios", str(spec), "--seeds", "1", "--candidates", "3", "--k",
            "5", "--tracker", "ncc", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    doc = json.loads((out / "headroom.json").read_text())
    assert doc["tracker"] == "ncc" and len(doc["candidates"]) == 3
    assert "| all | 1 |" in (out / "headroom.md").read_text()
    assert main(argv) == 0  # its own files are replaced
    (out / "headroom.json").unlink()
    assert main(argv) == 2  # headroom.md is now a file it cannot prove it wrote
    assert "headroom.md" in capsys.readouterr().err
