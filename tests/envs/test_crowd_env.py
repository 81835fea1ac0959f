"""envs.crowd_v0: PettingZoo conformance, the array API, control, observations, rendering."""

from __future__ import annotations

import importlib.util
import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test, seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from crowdsim.simulation import Simulation
from envs import crowd_v0
from envs.crowd import CrowdParallelEnv

SPARSE = {"density": 0.05, "width": 30.0, "right_fraction": 1.0, "periodic": True, "inflow": False}
"""A wide periodic corridor in which a handful of agents feel no wall and nobody else."""


def sparse_env(n: int, **kwargs) -> CrowdParallelEnv:
    return crowd_v0.parallel_env(n_agents=n, scenario_params=SPARSE, **kwargs)


def test_parallel_api_test():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # pettingzoo reports key mismatches as warnings
        parallel_api_test(crowd_v0.parallel_env(n_agents=10, max_cycles=40), num_cycles=40)


def test_parallel_api_test_with_arrivals_and_background_walkers():
    env = crowd_v0.parallel_env(
        n_agents=10,
        max_agents=30,
        controlled_fraction=0.5,
        max_cycles=200,
        scenario_params={"inflow": True},
    )
    assert len(env.possible_agents) == 15
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(env, num_cycles=200)


def test_seed_tests():
    kw = {"n_agents": 8, "max_cycles": 15}
    seed_test(lambda: parallel_to_aec(crowd_v0.parallel_env(**kw)), num_cycles=15)
    seed_test(lambda: crowd_v0.env(**kw), num_cycles=15)
    parallel_seed_test(lambda: crowd_v0.parallel_env(**kw), num_cycles=15)


def test_same_seed_same_episode_other_seed_another():
    runs = []
    for seed in (4, 4, 5):
        env = crowd_v0.parallel_env(n_agents=12)
        obs = [env.reset_arrays(seed)]
        rng = np.random.default_rng(0)
        for _ in range(5):
            obs.append(env.step_arrays(rng.uniform(-1, 1, (len(env.agent_ids), 2)))[0])
        runs.append(np.stack(obs))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_all_agents_share_one_space_object():
    env = crowd_v0.parallel_env(n_agents=6)
    env.reset(seed=0)
    a, b = env.agents[:2]
    assert env.observation_space(a) is env.observation_space(b)
    assert env.action_space(a) is env.action_space(b)
    assert env.observation_space(a).shape == (7 + 5 * 6,)
    assert env.observation_space(a).dtype == np.float32
    with pytest.raises(ValueError, match="unknown agent"):
        env.action_space("ped_99")


def test_array_api_equals_dict_api():
    kw = {"n_agents": 15, "max_cycles": 30, "scenario_params": {"inflow": True}, "max_agents": 25}
    d_env, a_env = crowd_v0.parallel_env(**kw), crowd_v0.parallel_env(**kw)
    obs, _ = d_env.reset(seed=9)
    a_obs = a_env.reset_arrays(9)
    np.testing.assert_array_equal(np.stack([obs[a] for a in d_env.agents]), a_obs)
    rng = np.random.default_rng(1)
    while d_env.agents:
        names, ids = list(d_env.agents), a_env.agent_ids
        assert names == [f"ped_{i}" for i in ids]
        acts = rng.uniform(-2.5, 2.5, (len(ids), 2))  # some out of the box: clipped alike
        obs, rew, term, trunc, _ = d_env.step(dict(zip(names, acts, strict=True)))
        a_obs, a_rew, a_term, a_trunc = a_env.step_arrays(acts)
        np.testing.assert_array_equal(np.stack([obs[a] for a in names]), a_obs)
        assert [rew[a] for a in names] == a_rew.tolist()
        assert all(isinstance(rew[a], float) for a in rew)
        assert [term[a] for a in names] == a_term.tolist()
        assert [trunc[a] for a in names] == a_trunc.tolist()
        for name, o in zip(a_env.agents, a_env.observe_arrays(), strict=True):
            np.testing.assert_array_equal(obs[name], o)  # newcomers too
    assert a_trunc.all() and not a_env.agent_ids.size
    assert d_env.n_clipped == a_env.n_clipped > 0


def test_controlled_agent_moves_as_commanded_and_is_rewarded_for_progress():
    env = sparse_env(1)
    env.reset(seed=0)
    sim = env.sim
    sim.set_state(pos=[[sim.world.period / 2, 15.0]])
    u = np.array([0.9, -0.6], np.float32)
    dt, tau = sim.params.dt, sim.params.tau
    for k in range(1, 21):
        before = sim.state.pos[0].copy()
        _, rew, term, trunc, _ = env.step({"ped_0": u})
        expected = u.astype(np.float64) * (1.0 - (1.0 - dt / tau) ** k)
        np.testing.assert_allclose(sim.state.vel[0], expected, rtol=1e-9, atol=1e-12)
        progress = (sim.state.pos[0, 0] - before[0]) / dt  # goal direction is +x
        assert rew["ped_0"] == pytest.approx(progress, rel=1e-12)
        assert not term["ped_0"] and not trunc["ped_0"]


def test_agents_without_actions_follow_the_social_force():
    env = crowd_v0.parallel_env(n_agents=30, controlled_fraction=0.4)
    env.reset(seed=2)
    plain = Simulation(env.scenario, seed=env.sim.seed, record=False)
    rng = np.random.default_rng(0)
    for step in range(15):
        if step < 10:  # no policy at all: the plain social-force simulation
            env.step({})
            plain.step()
            np.testing.assert_array_equal(env.sim.state.pos, plain.state.pos)
        else:  # the policy drives its agents only; the others get no command
            ids = env.agent_ids
            env.step_arrays(rng.uniform(-1, 1, (len(ids), 2)))
            assert set(ids.tolist()) < set(env.sim.state.ids.tolist())


def test_observation_of_a_planted_scene():
    env = sparse_env(3, k_neighbours=2, neighbour_radius=3.0)
    env.reset(seed=0)
    sim = env.sim
    period = sim.world.period
    # Agent 0 near the seam sees agent 1 across it (0.5 m away); agent 2 is 12 m off.
    sim.set_state(
        pos=[[0.2, 15.0], [period - 0.3, 15.2], [6.0, 3.0]],
        vel=[[0.5, 0.0], [-0.2, 0.1], [0.0, 0.0]],
    )
    obs, *_ = env.step_arrays(np.zeros((3, 2)))
    pos, vel = sim.state.pos, sim.state.vel
    rel = pos[1] - pos[0]
    rel[0] -= period * np.round(rel[0] / period)
    assert rel[0] == pytest.approx(-0.5, abs=0.05)
    want0 = np.concatenate(
        [[1.0, 0.0], vel[0], [0.0, 0.0, 0.0], rel, vel[1] - vel[0], [1.0], np.zeros(5)]
    ).astype(np.float32)
    np.testing.assert_array_equal(obs[0], want0)
    # Agent 2 is 3 m - its clearance from the wall at y = 0 (within 3 m), alone otherwise.
    assert obs[2, 4:6].tolist() == [0.0, -1.0]
    assert 0 < obs[2, 6] < 1 and not obs[2, 7:].any()


def test_agents_leave_and_terminate_then_truncation_ends_the_rest():
    env = crowd_v0.parallel_env(n_agents=12, max_cycles=1000)
    env.reset(seed=1)
    gone: set[str] = set()
    for _ in range(600):
        _, _, term, trunc, _ = env.step({})  # social force walks everybody to the exits
        gone |= {a for a, t in term.items() if t}
        assert not any(trunc.values())
        assert not gone & set(env.agents)
        if not env.agents:
            break
    assert gone == set(env.possible_agents)
    env = crowd_v0.parallel_env(n_agents=12, max_cycles=3)
    env.reset(seed=1)
    for _ in range(3):
        _, _, term, trunc, _ = env.step({})
    assert all(trunc.values()) and not any(term.values()) and env.agents == []


def test_render_rgb_array():
    env = crowd_v0.parallel_env(n_agents=20, render_mode="rgb_array", render_size=(320, 180))
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (180, 320, 3) and frame.dtype == np.uint8
    assert frame.std() > 5  # people and walls on the ground, not a blank image
    assert crowd_v0.parallel_env(n_agents=4).render() is None


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="k_neighbours"):
        crowd_v0.parallel_env(k_neighbours=-1)
    with pytest.raises(ValueError, match="render_mode"):
        crowd_v0.parallel_env(render_mode="human")
    with pytest.raises(ValueError, match="unknown scenario"):
        crowd_v0.parallel_env(scenario="nowhere")
    with pytest.raises(ValueError, match="controlled_ids"):
        crowd_v0.parallel_env(n_agents=5, controlled_ids=[7])
    env = crowd_v0.parallel_env(n_agents=5)
    env.reset_arrays(0)
    with pytest.raises(ValueError, match="shape"):
        env.step_arrays(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="actions must be .n, 2. numbers, got 'abc'"):
        env.step_arrays("abc")


def test_step_refuses_actions_it_cannot_apply_naming_the_agent():
    """A misspelt or unknown name, an agent that has left, a scalar (once broadcast to both
    components) or a wrong-shaped action: each refused naming the agent, nothing stepped."""
    env = sparse_env(4, max_cycles=50)
    env.reset(seed=0)
    a0, a1 = env.agents[:2]
    before = env.state().copy()
    for actions, needle in (
        ({"pde_0": [0.5, 0.0]}, "unknown agent 'pde_0'"),
        ({a0: [0.5, 0.0], "ped_77": [0.0, 0.0]}, "unknown agent 'ped_77'"),
        (
            {a0: 1.0},
            f"action of {a0!r} must have shape (2,) (preferred velocity, m/s), got shape ()",
        ),
        ({a1: [1.0, 2.0, 3.0]}, f"action of {a1!r} must have shape (2,)"),
        ({a1: [[1.0, 2.0]]}, f"action of {a1!r} must have shape (2,)"),
        ({a1: [np.inf, 0.0]}, f"action of {a1!r} must be finite"),
        ({a1: "fast"}, f"action of {a1!r} must be 2 numbers"),
        ({a1: ["1", "2"]}, f"action of {a1!r} must be 2 numbers"),  # was cast in silence
        ({a1: [1 + 1j, 0]}, f"action of {a1!r} must be 2 numbers"),
    ):
        with pytest.raises(ValueError) as info:
            env.step(actions)
        assert needle in str(info.value)
    np.testing.assert_array_equal(env.state(), before)  # nothing moved
    assert env._cycles == 0
    gone = CrowdParallelEnv(n_agents=4, max_cycles=50, scenario_params=SPARSE)
    gone.reset(seed=0)
    name = gone.agents[0]
    gone._ids = gone._ids[1:]  # as if ped_0 had left the scene
    gone._agent_names = None
    with pytest.raises(ValueError, match=f"action for agent {name!r}, which is not live"):
        gone.step({name: [0.0, 0.0]})
    env.step({a0: [0.5, 0.0]})  # a valid dict still steps; missing agents follow the force


@pytest.mark.skipif(
    importlib.util.find_spec("stable_baselines3") is None
    or importlib.util.find_spec("torch") is None,
    reason="the shared-policy recipe needs the rl extra (torch, stable-baselines3)",
)
def test_shared_policy_recipe_runs():
    from envs.crowd import shared_policy_vec_env, train_shared_policy

    venv = shared_policy_vec_env(sparse_env(4, max_cycles=3), seed=0)
    obs = venv.reset()
    assert obs.shape == (4, 37)
    for _ in range(3):
        obs, rew, done, infos = venv.step(np.zeros((4, 2), np.float32))
    assert done.all() and all(i["TimeLimit.truncated"] for i in infos)
    _, curve = train_shared_policy(
        64,
        env_kwargs={"n_agents": 4, "max_cycles": 16},
        ppo_kwargs={"batch_size": 32, "n_epochs": 1},
    )
    assert len(curve) >= 1 and np.isfinite(curve).all()


def test_shared_policy_vec_env_takes_sb3s_seed():
    """VecEnv.seed(s), which PPO(seed=s) calls, seeds the next reset (it was ignored: two
    trainings with one seed drew two crowds); the seed after it is fresh again."""
    from envs.crowd import shared_policy_vec_env

    def first(seed):
        venv = shared_policy_vec_env(crowd_v0.parallel_env(n_agents=6, max_cycles=3))
        venv.seed(seed)
        return venv, venv.reset()

    (venv, a), (_, b), (_, c) = first(5), first(5), first(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(venv.reset(), a)  # a seed is used once
    seeded = shared_policy_vec_env(crowd_v0.parallel_env(n_agents=6, max_cycles=3), seed=5)
    np.testing.assert_array_equal(seeded.reset(), a)  # the factory's seed is the same seed


def test_a_step_after_the_episode_ended_is_refused():
    """After max_cycles (no agent left) a step asks for reset() instead of stepping on."""
    env = sparse_env(3, max_cycles=2)
    env.reset(seed=0)
    while env.agents:
        env.step({a: np.zeros(2) for a in env.agents})
    with pytest.raises(RuntimeError, match="the episode is over .no agent is left.: call reset"):
        env.step({})
    with pytest.raises(RuntimeError, match=r"episode is over \(max_cycles=2 reached\)"):
        env.step_arrays(np.zeros((0, 2)))
    env.reset(seed=0)
    assert len(env.agents) == 3  # a reset starts the next one


def test_progress_reward_is_unwrapped_across_the_periodic_seam():
    """Crossing a periodic seam is rewarded as true progress, not minus a period."""
    env = crowd_v0.parallel_env(n_agents=1, scenario_params=SPARSE)
    env.reset_arrays(0)
    sim = env.sim
    period = sim.world.period
    sim.set_state(pos=[[period - 0.01, 15.0]], vel=[[1.3, 0.0]])
    _, rew, term, _ = env.step_arrays(np.array([[1.3, 0.0]]))
    assert sim.state.pos[0, 0] < 1.0  # it did wrap
    expected = (sim.state.pos[0, 0] + period - (period - 0.01)) / sim.params.dt
    assert rew[0] == pytest.approx(expected, rel=1e-9) and rew[0] == pytest.approx(1.3, rel=1e-6)
    assert not term[0]


def test_reward_charges_the_overlap_with_a_wall():
    """collision_weight * (r - clearance) is taken off an agent pressed into a wall."""
    env = crowd_v0.parallel_env(n_agents=1, scenario_params=SPARSE, collision_weight=10.0)
    env.reset_arrays(0)
    sim = env.sim
    sim.set_state(pos=[[sim.world.period / 2, 0.1]], vel=[[0.0, 0.0]])
    _, rew, _, _ = env.step_arrays(np.array([[0.0, 0.0]]))
    half = float(sim.world.walls[0, 4])
    overlap = float(sim.state.radius[0]) - (float(sim.state.pos[0, 1]) - half)
    assert overlap > 0.05  # still pressed into the wall after the step
    assert rew[0] == pytest.approx(-10.0 * overlap, rel=1e-9)


@pytest.mark.parametrize("face", ["raw_env", "env"])
def test_the_aec_faces_pass_api_test_and_check_each_call(face):
    """PettingZoo's AEC ``api_test`` on both faces; a bad action is refused by the step that
    gives it (the env stays usable), ``None`` lets an agent follow the social force."""
    from pettingzoo.test import api_test

    make = getattr(crowd_v0, face)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # as the parallel test, but for the ±inf bounds of
        warnings.filterwarnings("ignore", "Agent's m.* observation space value is")  # its obs
        api_test(make(n_agents=4, max_cycles=5), num_cycles=5)
    aec = make(n_agents=4, max_cycles=3)
    aec.reset(seed=0)
    with pytest.raises(ValueError, match="action of 'ped_0' must be finite"):
        aec.step(np.array([np.nan, 0.0], np.float32))
    assert aec.agent_selection == "ped_0"  # not buffered: ped_0 still has its turn
    aec.step(np.array([0.5, 0.0], np.float32))
    aec.step(None)
    with pytest.raises(ValueError, match="unknown agent 'ped_9'"):
        aec.observe("ped_9")
    aec.step(np.zeros(2, np.float32))
    aec.step(np.zeros(2, np.float32))  # the cycle's last agent: the crowd steps
    assert set(aec.agents) == {f"ped_{i}" for i in range(4)} and aec.agent_selection == "ped_0"


def test_a_crowd_whose_agents_are_not_there_yet_is_refused_and_its_faces_agree():
    """Controlled ids that only arrive later: the dict face's episode ended at once while
    step_arrays stepped on; now reset says so. An agent that has not entered is named by the
    AEC face's observe (a bare KeyError before)."""
    env = crowd_v0.parallel_env(n_agents=5, max_agents=30, controlled_ids=[20], max_cycles=50)
    with pytest.raises(ValueError, match="no agent is in the scene at the start"):
        env.reset(seed=0)
    aec = crowd_v0.env(n_agents=4, max_agents=20)
    aec.reset(seed=0)
    with pytest.raises(ValueError, match="observe: agent 'ped_15' has not entered the scene yet"):
        aec.observe("ped_15")


def test_a_refused_reset_leaves_no_episode_to_step():
    """After a reset refused for want of agents, step() and step_arrays() ask for reset()
    (they had stepped the episode that never began and returned empty results)."""
    env = crowd_v0.parallel_env(n_agents=5, max_agents=30, controlled_ids=[20], max_cycles=50)
    with pytest.raises(ValueError, match="no agent is in the scene at the start"):
        env.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step({})
    with pytest.raises(RuntimeError, match=r"call reset\(\)"):
        env.step_arrays(np.zeros((0, 2)))


def test_shared_policy_vec_env_checks_its_actions_and_renders_one_frame():
    from envs.crowd import shared_policy_vec_env

    venv = shared_policy_vec_env(sparse_env(4, max_cycles=3, render_mode="rgb_array"), seed=0)
    venv.reset()
    with pytest.raises(ValueError, match=r"actions must have shape \(4, 2\), got \(2, 4\)"):
        venv.step_async(np.zeros((2, 4)))  # a transposed batch had been reshaped in silence
    frame = venv.render()
    assert frame.ndim == 3 and frame.dtype == np.uint8
    assert len(venv.get_images()) == 4
    with pytest.raises(ValueError, match="has no possible agents"):
        shared_policy_vec_env(CrowdParallelEnv(n_agents=4, controlled_fraction=0.0))


def test_dict_step_adds_each_newcomer_once_after_the_stepped_agents():
    """Agents that enter during a step get a key in every dict, after the stepped agents and
    in live order, with reward 0 and both flags False; nobody else is added."""
    env = crowd_v0.parallel_env(
        n_agents=15, max_cycles=60, scenario_params={"inflow": True}, max_agents=40
    )
    env.reset(seed=9)
    rng = np.random.default_rng(1)
    entered = 0
    while env.agents:
        names = list(env.agents)
        obs, rew, term, trunc, infos = env.step({a: rng.uniform(-1, 1, 2) for a in names})
        fresh = [a for a in env.agents if a not in set(names)]
        entered += len(fresh)
        for d in (obs, rew, term, trunc, infos):
            assert list(d) == names + fresh
        for a in fresh:
            assert rew[a] == 0.0 and term[a] is False and trunc[a] is False
            np.testing.assert_array_equal(obs[a], env.observe_arrays()[env.agents.index(a)])
    assert entered > 0
