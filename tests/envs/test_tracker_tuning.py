"""TrackerTuning-v0 and its bandit variant: conformance, determinism, reward, clipping."""

from __future__ import annotations

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest

from envs.episodes import ScenarioDistribution, ScenarioEpisodes, tiny_scenarios
from envs.param_space import ParamSpace
from envs.tracker_tuning import (
    BANDIT_ENV_ID,
    ENV_ID,
    OBS_FIELDS,
    PolicyControlled,
    TrackerTuningBanditEnv,
    TrackerTuningEnv,
    make_tuned_tracker,
)

TINY = tiny_scenarios()
"""A sequence of a few people, 12 small frames: each env step takes milliseconds."""


def test_one_registration_table_registers_each_id_once():
    import importlib

    import gymnasium as gym

    import envs

    assert set(envs.ENVS) == {ENV_ID, BANDIT_ENV_ID}
    for env_id, entry in envs.ENVS.items():
        assert gym.registry[env_id].entry_point == entry
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns when an id is registered twice
        importlib.reload(envs)
    assert [i for i in gym.registry if i.startswith("crowdsim/")] == list(envs.ENVS)


def tiny_env(cls=TrackerTuningEnv, **kw):
    return cls(scenarios=dict(TINY), k_frames=5, **kw)


@pytest.mark.parametrize("env_id", [ENV_ID, BANDIT_ENV_ID])
def test_gymnasium_check_env_with_render(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, scenarios=dict(TINY), k_frames=5, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a checker warning is a failure here
        check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("tracker, dim", [("pnmc", 4), ("ncc", 2)])
def test_any_tunable_tracker_makes_a_checked_env(tracker, dim):
    """gymnasium.make(..., tracker=NAME) for the trackers beside BQP: the official checker, its
    own action space, and set_params reaching the tracker."""
    from gymnasium.utils.env_checker import check_env

    env = gym.make(ENV_ID, scenarios=dict(TINY), k_frames=5, tracker=tracker)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    assert env.action_space.shape == (dim,)
    env.reset(seed=3)
    obs, r, *_, info = env.step(np.ones(dim, np.float32))
    space = env.unwrapped.space
    assert env.unwrapped._trk.params == space.to_params(np.ones(dim))
    assert obs[len(OBS_FIELDS) :].tolist() == [1.0] * dim and 0 <= r <= 1
    assert obs[10] == 0 and obs[11] == 0  # no solver and no groups to report
    # the crowd walks: speed and flow come from the tracker's own motion (Tracker.motion;
    # PNMC's velocities, NCC's last displacements), which had read 0 beside BQP's
    assert obs[3] > 0.01 and obs[4] > 0 and obs[5] > 0
    trk = env.unwrapped._trk
    assert trk.motion().shape == trk.points.shape
    env.close()


@pytest.mark.parametrize("cls", [TrackerTuningEnv, TrackerTuningBanditEnv])
def test_sb3_check_env(cls):
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(tiny_env(cls), warn=True)


def test_episode_runs_the_sequence_in_k_frame_steps():
    env = tiny_env()
    obs, info = env.reset(seed=3)
    assert obs.shape == (len(OBS_FIELDS) + 5,) and obs.dtype == np.float32
    assert info["frame"] == 0 and info["params"] == {
        "zeta": 0.3,
        "eta": 0.2,
        "w_sp": 0.3,
        "w_g": 1.0,
        "update_threshold": 0.6,
    }
    frames, done, rewards = [], False, []
    while not done:
        obs, r, done, trunc, info = env.step(np.zeros(5, np.float32))
        assert type(r) is float and 0.0 <= r <= 1.0 and not trunc
        assert r == pytest.approx(info["accuracy"] / 100.0)
        frames.append(info["frames"])
        rewards.append(r)
    assert frames == [5, 5, 1]  # 12 frames: frame 0 initialises, 11 are tracked
    assert info["frame"] == 11 and obs[12] == 1.0  # progress
    assert env.observation_space.contains(obs)


def test_reward_matches_point_errors_of_the_tracked_frames():
    """The step reward is the fraction of gt points within T px over exactly its frames."""
    from tracker.metrics import point_errors

    env = tiny_env(threshold_px=1.0)
    env.reset(seed=5)
    _, r1, *_ = env.step(np.zeros(5))
    ep = env._ep
    err = point_errors(ep.gt_ids, ep.gt_points[1:6], ep.gt_ids, ep.tracks[1:6])
    v = err[~np.isnan(err)]
    assert r1 == pytest.approx(float((v <= 1.0).mean()))
    assert 0.0 < r1 < 1.0  # 1 px is strict enough that not every point is exact


def test_sequence_reward_equals_runner_accuracy():
    """The bandit step tracks exactly like a plain run of the BQP tracker with the paper
    defaults, and its reward is that run's accuracy at 5 px over frames 1..T-1."""
    from tracker.metrics import accuracy_curve
    from tracker.runner import run_tracker

    env = tiny_env(TrackerTuningBanditEnv)
    env.reset(options={"episode": 2})
    _, r, done, _, info = env.step(np.zeros(5))
    assert done
    seq = env.episodes.episode(2)
    run = run_tracker("bqp", seq, metrics="none")
    gt_ids, gt = seq.gt_points()
    col = {int(i): c for c, i in enumerate(gt_ids)}
    ref = np.full_like(env._ep.tracks, np.nan)
    for j, i in enumerate(run.result.ids):
        ref[:, col[int(i)]] = run.result.positions[:, j]
    np.testing.assert_array_equal(env._ep.tracks, ref)
    acc = accuracy_curve(gt_ids, gt[1:], run.result.ids, run.result.positions[1:], [5])[0]
    assert r == pytest.approx(acc / 100) and info["accuracy"] == pytest.approx(acc)


def test_same_seed_same_episode_and_rewards():
    def roll(seed):
        env = tiny_env()
        obs, _ = env.reset(seed=seed)
        out = [obs]
        rng = np.random.default_rng(0)
        done = False
        while not done:
            obs, r, done, _, _ = env.step(rng.uniform(-1, 1, 5))
            out.append(obs)
            out.append(np.float32(r))
        return out

    a, b = roll(11), roll(11)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_actions_reach_the_tracker_and_are_clipped_and_counted():
    env = tiny_env()
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([2.0, -3.0, 0.5, 0.0, 1.0]))
    p = env._trk.params
    assert (p.zeta, p.eta, p.w_sp, p.w_g, p.update_threshold) == pytest.approx(
        (1.5, 0.0, 0.9, 1.0, 1.0)
    )
    assert env._trk.appearance.update_threshold == 1.0  # set_params reached the model
    assert info["clipped"] == 2 and info["clipped_total"] == 2
    _, _, _, _, info = env.step(np.array([5.0, 0, 0, 0, 0]))
    assert info["clipped"] == 1 and info["clipped_total"] == 3
    obs, *_ = env.step(np.zeros(5))
    np.testing.assert_array_equal(obs[len(OBS_FIELDS) :], np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="5 real numbers"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="must be finite"):
        env.step(np.full(5, np.nan))


def test_parameters_change_the_tracking():
    """Switching every term off (action -1 on the weights) changes the tracks."""
    env = tiny_env(TrackerTuningBanditEnv, threshold_px=1.0)
    env.reset(options={"episode": 1})
    env.step(np.zeros(5))
    a = env._ep.tracks.copy()
    env.reset(options={"episode": 1})
    env.step(np.array([-1.0, -1.0, -1.0, -1.0, 1.0]))
    assert not np.array_equal(a, env._ep.tracks, equal_nan=True)


def test_bandit_is_one_step():
    env = tiny_env(TrackerTuningBanditEnv)
    env.reset(seed=0)
    _, _, done, _, info = env.step(np.zeros(5))
    assert done and info["frames"] == 11 and info["frame"] == 11
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(5))


def test_extended_space_has_eight_actions():
    env = tiny_env(extended=True)
    assert env.action_space.shape == (8,)
    env.reset(seed=0)
    env.step(np.array([0, 0, 0, 0, 0, 1.0, -1.0, 1.0]))
    p = env._trk.params
    assert (p.search_factor, p.motion_sigma, p.kcf_learning_rate) == (3.0, 0.2, 0.3)


def test_render_is_the_rgb_overlay():
    env = tiny_env(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(5))
    img = env.render()
    seq = env._ep.seq
    assert img.shape == (seq.height, seq.width, 3) and img.dtype == np.uint8
    # ground truth is drawn in green: RGB (0, 255, 0) pixels exist
    assert ((img[..., 0] == 0) & (img[..., 1] == 255) & (img[..., 2] == 0)).any()


def test_bad_arguments():
    with pytest.raises(ValueError, match="k_frames"):
        TrackerTuningEnv(scenarios=dict(TINY), k_frames=0)
    with pytest.raises(ValueError, match="unknown scenario 'parade'"):
        TrackerTuningEnv(scenarios="parade")
    with pytest.raises(ValueError, match="unknown suite 'nope'"):
        TrackerTuningEnv(suite="nope")
    with pytest.raises(ValueError, match="unknown tracker"):
        TrackerTuningEnv(scenarios=dict(TINY), tracker="kalman")
    with pytest.raises(ValueError, match="bytetrack: no row of tunables"):
        TrackerTuningEnv(scenarios=dict(TINY), tracker="bytetrack")
    env = tiny_env()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(5))
    with pytest.raises(ValueError, match="unknown option.s. episdoe; valid: episode"):
        env.reset(options={"episdoe": 1})  # it had drawn a random episode in silence
    _, info = env.reset(seed=0)
    scen = info["sequence"].rsplit("-", 1)  # what was drawn: its scenario and scene seed
    assert scen[0] in TINY["scenarios"] and scen[1].isdigit()


def test_make_and_async_vector_env():
    """make and make_vec(async) with 2 tiny envs. The 'spawn' context: this test process has
    already run numba's GNU-OpenMP parallel kernels, after which a forked child may not."""
    env = gym.make(ENV_ID, scenarios=dict(TINY), k_frames=5)
    assert isinstance(env.unwrapped, TrackerTuningEnv)
    env.close()
    vec = gym.make_vec(
        ENV_ID,
        num_envs=2,
        vectorization_mode="async",
        vector_kwargs={"context": "spawn"},
        scenarios=dict(TINY),
        k_frames=5,
    )
    try:
        obs, _ = vec.reset(seed=[1, 2])
        assert obs.shape == (2, len(OBS_FIELDS) + 5)
        obs, r, term, trunc, _ = vec.step(np.zeros((2, 5), np.float32))
        assert r.shape == (2,) and ((r >= 0) & (r <= 1)).all()
    finally:
        vec.close()


def test_async_vector_env_default_context_in_a_fresh_process():
    """What a user types: import envs, make_vec(..., vectorization_mode="async")."""
    import subprocess
    import sys

    code = (
        "import gymnasium as gym, numpy as np\n"
        "import envs\n"
        "from envs.tracker_tuning import ENV_ID\n"
        f"vec = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode='async', "
        f"scenarios={dict(TINY)!r}, k_frames=5)\n"
        "obs, _ = vec.reset(seed=0)\n"
        "_, r, *_ = vec.step(np.zeros((2, 5), np.float32))\n"
        "vec.close()\n"
        "print(obs.shape, r.shape)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "(2, 18) (2,)"


@pytest.mark.parametrize("tracker", ["bqp", "pnmc"])
def test_policy_controlled_tracking_follows_the_env(tracker):
    """A policy run through PolicyControlled makes the same tracks as the env stepping it and
    sees the env's first observation, for BQP and for PNMC."""

    class Constant:
        def __init__(self, a):
            self.a = np.asarray(a, np.float32)
            self.seen = []

        def predict(self, obs, deterministic=True):
            self.seen.append(np.asarray(obs).copy())
            return self.a, None

    from tracker.runner import run_tracker

    a = [0.8, -0.5, 0.2, -1.0, 0.4][: ParamSpace(tracker=tracker).dim]
    env = tiny_env(tracker=tracker)
    obs0, _ = env.reset(options={"episode": 4})
    done = False
    while not done:
        _, _, done, _, _ = env.step(a)
    space = ParamSpace(tracker=tracker)
    pol = Constant(a)
    seq = env.episodes.episode(4)
    trk = make_tuned_tracker(tracker, space.to_params(space.default_action))
    run = run_tracker(trk, PolicyControlled(seq, trk, pol, space, k_frames=5), metrics="accuracy")
    assert len(pol.seen) == 3
    np.testing.assert_array_equal(pol.seen[0], obs0)
    gt_ids, _ = seq.gt_points()
    col = {int(i): c for c, i in enumerate(gt_ids)}
    for j, i in enumerate(run.result.ids):
        np.testing.assert_array_equal(run.result.positions[:, j], env._ep.tracks[:, col[int(i)]])
    assert "acc@5" in run.report


def test_episodes_from_a_fixed_stream_are_disjoint_by_seed():
    d = ScenarioDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in TINY.items()})
    train, held = ScenarioEpisodes(d, seed=0), ScenarioEpisodes(d, seed=1)
    assert train.spec(0) == ScenarioEpisodes(d, seed=0).spec(0)
    seeds_a = {train.spec(i).seed for i in range(20)}
    seeds_b = {held.spec(i).seed for i in range(20)}
    assert not seeds_a & seeds_b


def test_suite_episodes_from_a_folder_and_a_builtin_suite(tmp_path):
    from envs.episodes import SuiteEpisodes
    from synth_data.generate import generate
    from synth_data.suites import suite_specs

    d = ScenarioDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in TINY.items()})
    spec = d.sample_spec(np.random.default_rng(3), name="tiny1")
    generate([spec], tmp_path / "suite", workers=1, progress=False)
    env = TrackerTuningEnv(suite=str(tmp_path / "suite"), frames=8, k_frames=5)
    _, info = env.reset(seed=0)
    assert info["sequence"] == "tiny1" and info["length"] == 8
    _, r, done, _, info = env.step(np.zeros(5))
    _, r, done, _, info = env.step(np.zeros(5))
    assert done and info["frames"] == 2 and 0.0 <= r <= 1.0
    with pytest.raises(ValueError, match="no sequence 'tiny2'"):
        SuiteEpisodes(tmp_path / "suite", only=["tiny2"])
    # a damaged frame is named before any work (checksums.json of crowdsim generate)
    frame = tmp_path / "suite" / "tiny1" / "img1" / "000003.jpg"
    frame.write_bytes(frame.read_bytes()[:-200])
    with pytest.raises(ValueError, match=f"{frame}: damaged"):
        SuiteEpisodes(tmp_path / "suite")
    with pytest.raises(ValueError, match="000003.jpg: damaged"):
        TrackerTuningEnv(suite=str(tmp_path / "suite"), k_frames=5)
    (tmp_path / "suite" / "tiny1" / "checksums.json").unlink()  # as a real MOT folder
    with pytest.raises(ValueError, match=f"{frame}: not a complete image"):
        SuiteEpisodes(tmp_path / "suite")
    held = SuiteEpisodes("ucf9", only=["seq8"], frames=3, reseed=5)
    (orig,) = suite_specs("ucf9", ["seq8"])
    assert held.spec(0).seed == orig.seed + 5 and held.spec(0).frames == 3


# ---------------------------------------------------------------------------- no ground truth
class _GtEdited:
    """``seq`` with the same frames and births (what the tracker is given) and its ground
    truth (what only the reward may read) shifted by ``shift`` px, or all NaN after frame 0
    (``shift=None``: people removed from the scoring, ids kept)."""

    def __init__(self, seq, shift):
        self._seq = seq
        self._shift = shift
        for k in ("name", "frame_rate", "width", "height", "length", "template_size"):
            setattr(self, k, getattr(seq, k))

    def frames(self):
        return self._seq.frames()

    def births(self):
        return self._seq.births()

    def gt_points(self):
        ids, pts = self._seq.gt_points()
        pts = pts.copy()
        if self._shift is None:
            pts[1:] = np.nan
        else:
            pts += np.asarray(self._shift, np.float64)
        return ids, pts


class _Edited(ScenarioEpisodes):
    def __init__(self, shift):
        super().__init__(ScenarioDistribution.from_dict(TINY), seed=0)
        self.shift = shift

    def _build(self, index):
        seq = super()._build(index)
        return seq if self.shift == "none" else _GtEdited(seq, self.shift)


ACTIONS = np.array(
    [[0.8, -0.5, 0.2, -1.0, 0.4], [-0.9, 0.7, 1.0, 0.3, -0.6], [0.1, 0.1, -0.4, 1.0, 0.9]]
)
"""A different action on each of the three steps of a 12-frame episode with K = 5."""


def _roll(episodes, episode=4):
    env = TrackerTuningEnv(episodes=episodes, k_frames=5, threshold_px=1.0)
    obs, _ = env.reset(options={"episode": episode})
    seen, rewards, done, k = [obs], [], False, 0
    while not done:
        obs, r, done, _, _ = env.step(ACTIONS[k])
        seen.append(obs)
        rewards.append(r)
        k += 1
    return seen, rewards, env


def test_observation_never_depends_on_the_ground_truth_at_any_step():
    """Shifting the ground truth by (7, -3) px or removing it leaves every observation
    unchanged -- the reset's and each step's -- while the rewards do change (the edit is
    real): nothing of the ground truth leaks into what a policy sees."""
    base, r_base, _ = _roll(_Edited("none"))
    for shift in ((7.0, -3.0), None):
        seen, rewards, _ = _roll(_Edited(shift))
        assert len(seen) == len(base) == 4
        for k, (a, b) in enumerate(zip(base, seen, strict=True)):
            np.testing.assert_array_equal(a, b, err_msg=f"observation {k} (0: reset)")
        assert rewards != r_base  # the reward does read the ground truth
    assert any(r > 0 for r in r_base)


def test_policy_driven_tracker_sees_exactly_the_envs_observations():
    """PolicyControlled (``crowdsim track --policy``) shows the policy the same observation
    the env returns before each step -- every step, on a source whose ground truth is gone --
    and the policy's actions produce the env's tracks."""
    from tracker.runner import run_tracker

    env_obs, _, env = _roll(_Edited("none"))

    class Scripted:
        def __init__(self):
            self.seen = []

        def predict(self, obs, deterministic=True):
            self.seen.append(np.asarray(obs).copy())
            return ACTIONS[len(self.seen) - 1], None

    pol = Scripted()
    space = ParamSpace()
    seq = _GtEdited(env.episodes.episode(4), None)
    trk = make_tuned_tracker("bqp", space.to_params(space.default_action))
    run = run_tracker(trk, PolicyControlled(seq, trk, pol, space, k_frames=5), metrics="none")
    assert len(pol.seen) == 3
    for k, (a, b) in enumerate(zip(env_obs[:3], pol.seen, strict=True)):
        np.testing.assert_array_equal(a, b, err_msg=f"observation before step {k}")
    gt_ids, _ = seq.gt_points()
    col = {int(i): c for c, i in enumerate(gt_ids)}
    for j, i in enumerate(run.result.ids):
        np.testing.assert_array_equal(run.result.positions[:, j], env._ep.tracks[:, col[int(i)]])


def test_each_step_reward_covers_exactly_its_k_frames():
    """Every step's reward is the fraction, over that step's frames only (1-5, 6-10, 11), of
    the ground-truth points whose tracked point of the same id lies within T px -- computed
    here by hand from an independent run of the same actions (a cumulative reward would match
    the first step only)."""
    from tracker.runner import run_tracker

    _, rewards, env = _roll(_Edited("none"))
    space = ParamSpace()
    seq = env.episodes.episode(4)

    class Scripted:
        n = 0

        def predict(self, obs, deterministic=True):
            self.n += 1
            return ACTIONS[self.n - 1], None

    trk = make_tuned_tracker("bqp", space.to_params(space.default_action))
    run = run_tracker(trk, PolicyControlled(seq, trk, Scripted(), space, 5), metrics="none")
    gt_ids, gt = seq.gt_points()
    tracked = dict(zip(run.result.ids.tolist(), range(len(run.result.ids)), strict=True))
    expected = []
    for frames in (range(1, 6), range(6, 11), range(11, 12)):
        hits = total = 0
        for t in frames:
            for c, pid in enumerate(gt_ids.tolist()):
                g = gt[t, c]
                if np.isnan(g).any():
                    continue  # not in the frame: not scored
                total += 1
                j = tracked.get(pid)
                p = run.result.positions[t, j] if j is not None else np.full(2, np.nan)
                hits += bool(np.hypot(*(p - g)) <= 1.0)  # a lost person (NaN) is a miss
        expected.append(hits / total if total else 0.0)
    assert rewards == pytest.approx(expected, abs=1e-12)
    assert len(set(np.round(expected, 6))) == 3  # the steps differ: a mix-up would show


def test_distribution_files_are_bounded_and_a_single_name_is_one_family(tmp_path):
    """``frames: 1e9`` (simulated until killed) and friends are refused with the spec
    files' limits, naming the file; ``scenarios = "marathon"`` is the family marathon."""
    from crowdsim.scenarios import MAX_AGENTS
    from synth_data.spec import MAX_FRAMES, MAX_WARMUP_STEPS

    f = tmp_path / "d.toml"
    f.write_text('scenarios = "marathon"\nframes = 12\n')
    d = ScenarioDistribution.from_arg(str(f))
    assert d.scenarios == ("marathon",) and d.frames == 12
    for field, value, limit in (
        ("frames", MAX_FRAMES + 1, MAX_FRAMES),
        ("warmup_steps", MAX_WARMUP_STEPS + 1, MAX_WARMUP_STEPS),
        ("agents", [1, MAX_AGENTS + 1], MAX_AGENTS),
    ):
        j = tmp_path / f"{field}.json"
        j.write_text(json.dumps({field: value}))
        with pytest.raises(ValueError, match=rf"{j}: ScenarioDistribution.{field} must be") as e:
            ScenarioDistribution.from_arg(str(j))
        assert f", {limit}]" in str(e.value)
        edge = {field: limit if field != "agents" else [1, limit]}
        ScenarioDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in edge.items()})
    (tmp_path / "b.json").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ValueError, match="b.json: not a JSON distribution file"):
        ScenarioDistribution.from_arg(str(tmp_path / "b.json"))


def test_a_point_exactly_the_threshold_away_counts_as_tracked():
    """The reward's acc@T counts errors ``<= T`` (the papers' "within T pixels")."""
    env = TrackerTuningEnv(scenarios=dict(TINY), k_frames=5, threshold_px=1.0)
    env.reset(seed=5)
    ep = env._ep
    ep.tracks[1:6] = ep.gt_points[1:6] + np.array([1.0, 0.0])  # every point 1 px off
    acc, n = env._score(1, 5)
    assert acc == 1.0 and n == np.isfinite(ep.gt_points[1:6, :, 0]).sum() > 0
    ep.tracks[1:6] = ep.gt_points[1:6] + np.array([1.0 + 1e-9, 0.0])
    assert env._score(1, 5) == (0.0, n)


def test_a_drawn_episode_with_nobody_in_view_is_drawn_again():
    """Two families of 6-8 people in 160 x 120 px: about half of the draws frame nobody.
    Every reset still starts an episode with someone to score (as held-out scoring skips
    such draws), and the tuner's training episodes are the first ones that show someone."""
    from envs.episodes import ScenarioDistribution, make_episodes
    from envs.tuners import Objective, Scorer

    scenes = {**TINY, "scenarios": ["counterflow", "crossing"], "frames": 10}
    env = TrackerTuningEnv(scenarios=scenes)
    src = make_episodes(scenarios=ScenarioDistribution.from_dict(scenes))
    empty = [i for i in range(12) if len(src.episode(i).gt_points()[0]) == 0]
    assert empty  # the distribution does frame nobody at times
    for seed in range(12):
        _, info = env.reset(seed=seed)
        assert info["targets"] > 0
    with pytest.raises(ValueError, match="has no ground truth"):  # asked for by index: said
        env.reset(options={"episode": empty[0]})
    scorer = Scorer(Objective(scenarios=src.dist, train_episodes=3, frames=10))
    assert empty[0] not in scorer.indices and len(scorer.indices) == 3
