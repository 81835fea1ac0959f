"""Scene-aware tuning: the nearest-neighbour choice on hand-built tables, the policy's
schedule, its file (and refusals), and the fit end to end on tiny episodes: it scores what
PolicyControlled then delivers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from crowdsim.cli import main
from envs.episodes import tiny_scenarios
from envs.param_space import ParamSpace
from envs.scene_aware import SceneAwarePolicy, episode_scores, fit_scene_aware, scene_features
from envs.tuners import Objective

F = len(scene_features())


def hand_built(neighbours: int = 1, opening: int = 0) -> SceneAwarePolicy:
    """Two clusters of scenes: feature 0 near 0 prefers candidate 1, near 10 candidate 2."""
    space = ParamSpace()
    actions = np.zeros((3, space.dim))
    actions[1, 0], actions[2, 0] = 0.5, -0.5
    features = np.zeros((6, F))
    features[:, 0] = [0.0, 0.2, 0.4, 10.0, 10.2, 10.4]
    features[:, 1] = 7.0  # constant: no spread, no say
    scores = np.array(
        [
            [45.0, 60.0, 40.0],
            [45.0, 61.0, 40.0],
            [45.0, 62.0, 40.0],
            [45.0, 30.0, 58.0],
            [45.0, 31.0, 59.0],
            [45.0, 32.0, 60.0],
        ]
    )
    return SceneAwarePolicy("bqp", False, 4, actions, features, scores, neighbours, opening)


def test_the_nearest_scenes_choose():
    pol = hand_built(neighbours=3)
    near_a, near_b = np.zeros(F), np.zeros(F)
    near_b[0] = 9.8
    assert pol.choose(near_a) == 1 and pol.choose(near_b) == 2
    # every episode voting: the best single candidate (means 45 / 46 / 49.5 -> 2)
    assert pol.choose(near_a, k=6) == 2
    # ties go to the lower index
    tie = SceneAwarePolicy("bqp", False, 4, pol.actions, pol.features, np.full((6, 3), 5.0), 2)
    assert tie.choose(near_b) == 0
    # leave-one-out: each scene chosen by its own cluster scores the cluster's best
    assert pol.leave_one_out(2) == pytest.approx(np.mean([60, 61, 62, 58, 59, 60]))
    others = [np.delete(pol.scores, i, axis=0).mean(0).argmax() for i in range(6)]
    assert pol.leave_one_out(5) == pytest.approx(
        np.mean([pol.scores[i, j] for i, j in enumerate(others)])
    )


def test_predict_opens_then_keeps_its_choice():
    pol = hand_built(neighbours=3, opening=2)
    obs = np.zeros(F + 1 + pol.space.dim)  # the observation: fields, then the action
    a0, _ = pol.predict(obs)
    np.testing.assert_array_equal(a0, pol.actions[2])
    a1, _ = pol.predict(obs)
    np.testing.assert_array_equal(a1, pol.actions[1])  # near cluster A
    far = obs.copy()
    far[0] = 10.0
    np.testing.assert_array_equal(pol.predict(far)[0], pol.actions[1])  # kept for the sequence
    pol.reset()
    pol.predict(far)
    np.testing.assert_array_equal(pol.predict(far)[0], pol.actions[2])
    assert pol.choices == [1, 2]


def test_file_round_trip_and_refusals(tmp_path):
    pol = hand_built(neighbours=3, opening=1)
    p = tmp_path / "scene_aware.json"
    p.write_text(json.dumps(pol.to_dict()))
    back = SceneAwarePolicy.load(p)
    for name in ("actions", "features", "scores"):
        np.testing.assert_array_equal(getattr(back, name), getattr(pol, name))
    assert (back.neighbours, back.opening, back.k_frames) == (3, 1, 4)
    cases = {
        "foreign.json": ({"params": {"zeta": 1.0}}, "not a scene-aware policy"),
        "version.json": ({**pol.to_dict(), "version": 9}, "version 9"),
        "space.json": ({**pol.to_dict(), "space": "zeta:0:1:2"}, "another parameter space"),
        "nan.json": ({**pol.to_dict(), "scores": [[float("nan")] * 3] * 6}, "scores must be"),
        "short.json": ({**pol.to_dict(), "scores": [[1.0, 2.0]] * 6}, r"scores must be \(6, 3\)"),
        "opening.json": ({**pol.to_dict(), "opening": 7}, "opening must be"),
        "missing.json": ({k: v for k, v in pol.to_dict().items() if k != "neighbours"}, "missing"),
    }
    for name, (doc, message) in cases.items():
        bad = tmp_path / name
        bad.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=message) as exc:
            SceneAwarePolicy.load(bad)
        assert name in str(exc.value)
    (tmp_path / "bin.json").write_bytes(b"\x00\xff")
    with pytest.raises(ValueError, match="bin.json"):
        SceneAwarePolicy.load(tmp_path / "bin.json")


def test_fit_scores_what_the_policy_then_delivers(tmp_path):
    """The fit's score of the candidate the policy picks on a training episode is what
    tracking that episode under the policy (PolicyControlled, as heldout and track do) gives."""
    from envs.training import load_policy, policy_tracker
    from tracker.metrics import point_errors
    from tracker.runner import run_tracker

    two = {**tiny_scenarios(), "scenarios": ["counterflow", "crossing"], "agents": [14, 18]}
    objective = Objective(scenarios=two)
    pol, record = fit_scene_aware(objective, episodes=5, candidates=3, k_frames=4, progress=False)
    # episodes 1-3 show nobody: skipped, never scored
    assert record["episodes"] == 2 and record["skipped_empty"] == 3
    assert set(record["leave_one_out"]) == {"1"}
    assert 0 <= record["opening"] < 3 and record["neighbours"] == 1
    p = tmp_path / "scene_aware.json"
    p.write_text(json.dumps(pol.to_dict()))
    model, meta = load_policy(p)
    seq = objective.episodes().episode(4)
    trk, ctl, what = policy_tracker(seq, model, meta)
    assert "scene-aware" in what
    run = run_tracker(trk, ctl, metrics="accuracy")
    j = model.choices[-1]
    gt_ids, gt = seq.gt_points()
    err = point_errors(gt_ids, gt[1:], run.result.ids, run.result.positions[1:])
    ok = ~np.isnan(err)
    acc = 100.0 * (err[ok] <= objective.threshold_px).sum() / ok.sum()
    assert acc == pytest.approx(pol.scores[1, j], abs=1e-9)
    space = ParamSpace()
    again = episode_scores(seq, "bqp", space, pol.actions, 4, 5.0, opening=pol.opening)
    np.testing.assert_allclose(again["scores"], pol.scores[1])
    np.testing.assert_allclose(again["features"], pol.features[1])


def test_cli_writes_and_refuses(tmp_path, capsys):
    dist = tmp_path / "tiny.json"
    dist.write_text(json.dumps(tiny_scenarios()))
    out = tmp_path / "fit"
    args = ["train", "--algo", "scene", "--scenarios", str(dist), "--k", "4"]
    args += ["--episodes", "3", "--candidates", "2", "--out", str(out), "--no-progress"]
    assert main(args) == 0
    for name in ("scene_fit.json", "scene_aware.json", "static_params.json", "scene_fit.png"):
        assert (out / name).is_file()
    assert main(args) == 0  # a rerun replaces its own files
    (out / "scene_fit.png").write_bytes(b"my picture")
    assert main(args) == 2
    assert "scene_fit.png exists and was not written by crowdsim train --algo scene" in (
        capsys.readouterr().err
    )
    assert (out / "scene_fit.png").read_bytes() == b"my picture"
    bad = ["train", "--algo", "scene", "--scenarios", str(dist), "--episode-cache", str(tmp_path)]
    assert main([*bad, "--out", str(tmp_path / "x")]) == 2
    assert "--episode-cache and --pool are for ppo / sac" in capsys.readouterr().err
    assert main([*args[:-3], "--episodes", "1", "--out", str(tmp_path / "y")]) == 2
    assert "--episodes must be" in capsys.readouterr().err
