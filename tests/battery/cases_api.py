"""Bad input to the Python API of the simulator, the trackers, the sequences and the
environments: a clear ``ValueError`` naming the argument and the value, never an internal
exception, a hang or a value cast in silence."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from battery.harness import Env, api_case


def _sim(call):
    """``call(sim)`` on a 10-agent counterflow."""

    def run(w: Path, env: Env) -> object:
        from crowdsim.scenarios import make_scenario
        from crowdsim.simulation import Simulation

        return call(Simulation(make_scenario("counterflow", n_agents=10), seed=0))

    return run


# a body far outside the world had the force kernel's agent grid fill the memory
api_case(
    "api-sim-add-far",
    _sim(lambda s: s.add_agents([[1e5, 1e5]])),
    "add_agents.pos[0] = (100000, 100000) m lies outside the world",
)
api_case(
    "api-sim-set-state-far",
    _sim(lambda s: s.set_state(pos=np.full((s.state.n, 2), 1e6))),
    "set_state.pos[0] = (1e+06, 1e+06) m lies outside the world",
)
# a body placed across a wall was pushed out on either side: people walked outside the
# corridor (y = -1.2 and 7.2) with no error
api_case(
    "api-sim-add-on-wall",
    _sim(lambda s: s.add_agents([[1, 1], [3, -0.1]])),
    "add_agents.pos[1] = (3, -0.1) m overlaps the wall from (-4, 0) to (8, 0) m"
    "&&less than its radius 0.225 m",
)
api_case(
    "api-sim-add-wide-body-on-wall",
    _sim(lambda s: s.add_agents([[2, 5.5]], radius=0.8)),
    "add_agents.pos[0] = (2, 5.5) m overlaps the wall from (-4, 6) to (8, 6) m"
    "&&less than its radius 0.8 m",
)
api_case(
    "api-sim-route-float", _sim(lambda s: s.add_agents([[1, 1]], route=1.5)), "route must be whole"
)
api_case(
    "api-sim-prominent-text",
    _sim(lambda s: s.add_agents([[1, 1]], prominent="x")),
    "add_agents.prominent must be booleans, got 'x'",
)
api_case(
    "api-sim-radius-huge",
    _sim(lambda s: s.add_agents([[1, 1]], radius=1e3)),
    "add_agents.radius must be in (0, 1.0] m",
)
api_case(
    "api-sim-speed-text",
    _sim(lambda s: s.add_agents([[1, 1]], desired_speed="x")),
    "add_agents.desired_speed must be numbers, got 'x'",
)
api_case(
    "api-sim-desired-velocity-huge",
    _sim(lambda s: s.step(desired_velocity=np.full((s.state.n, 2), 1e6))),
    "step.desired_velocity must be at most 10.0 m/s",
)
# numpy's "could not convert string to float" named no argument, and a complex array was
# cast to its real part with only a warning
api_case(
    "api-sim-desired-velocity-text",
    _sim(lambda s: s.step(desired_velocity="ab")),
    "step.desired_velocity must be numbers, got 'ab'",
)
api_case(
    "api-sim-add-pos-complex",
    _sim(lambda s: s.add_agents([[1j, 1]])),
    "add_agents.pos must be numbers, got [[1j, 1]]",
)
api_case(
    "api-sim-set-state-vel-complex",
    _sim(lambda s: s.set_state(vel=np.zeros((s.state.n, 2), complex))),
    "set_state.vel must be numbers, got complex128 of shape (10, 2)",
)


def _sim_params(w: Path, env: Env) -> object:
    from crowdsim.scenarios import make_scenario
    from crowdsim.simulation import Simulation

    return Simulation(make_scenario("counterflow", n_agents=10), params={"tau": 0.4})


api_case("api-sim-params-dict", _sim_params, "params must be a SocialForceParams, got dict")


def _crowd(**kw):
    def call(w: Path, env: Env) -> object:
        from synth_data.sequence import synthetic_crowd

        return synthetic_crowd(**{"n": 3, "n_frames": 3, "size": (100, 100), **kw})

    return call


api_case("api-crowd-template-0", _crowd(template_px=0), "template_px must be an integer in [2")
api_case("api-crowd-n-float", _crowd(n=2.5), "synthetic_crowd.n must be an integer")


def _run_tracker(**kw):
    def call(w: Path, env: Env) -> object:
        from synth_data.sequence import synthetic_crowd
        from tracker.runner import run_tracker

        source = kw.pop("source", None) or synthetic_crowd(3, 3, size=(100, 100))
        return run_tracker("ncc", source, **kw)

    return call


api_case("api-run-source-text", _run_tracker(source="seq"), "source must be a sequence source")
api_case("api-run-frames-float", _run_tracker(frames=2.5), "run_tracker.frames must be an integer")
api_case("api-run-template-0", _run_tracker(template_size=0), "template_size must be an integer")
api_case("api-run-metrics", _run_tracker(metrics="bogus"), "metrics must be 'full'")
api_case("api-run-start-int", _run_tracker(start=5), "start must be ((ids0, points0)")


def _init_template(size: int):
    def call(w: Path, env: Env) -> object:
        from tracker.registry import make_tracker

        frame = np.zeros((96, 128, 3), np.uint8)
        return make_tracker("bqp").init(frame, [1], np.array([[40.0, 40.0]]), size)

    return call


api_case("api-tracker-template-3000", _init_template(3000), "template_size must be an integer in")


def _init_many(n: int, size: int):
    def call(w: Path, env: Env) -> object:
        from tracker.registry import make_tracker

        frame = np.zeros((1080, 1920, 3), np.uint8)
        points = np.column_stack([np.linspace(300, 1600, n), np.full(n, 540.0)])
        return make_tracker("bqp").init(frame, np.arange(n), points, size)

    return call


# the KCF models of 2,000 heads at 256 px (8.4 GB, and a step three times that) were
# allocated without a check: a MemoryError or the OOM killer would have said so mid-work
api_case(
    "api-tracker-kcf-memory",
    _init_many(2000, 256),
    "KCF appearance models of 2000 targets (512 px windows) needs about 27.5 GiB of memory, "
    "more than the 12.0 GiB limit",
)


def _init_ids(ids):
    def call(w: Path, env: Env) -> object:
        from tracker.registry import make_tracker

        frame = np.zeros((96, 128, 3), np.uint8)
        return make_tracker("ncc").init(frame, ids, np.array([[40.0, 40.0], [60.0, 60.0]]), 8)

    return call


api_case("api-tracker-ids-inf", _init_ids([np.inf, 1.0]), "ids must be a 1-D integer array")
api_case("api-tracker-ids-nan", _init_ids([np.nan, 1.0]), "ids must be a 1-D integer array")


def _qp_block_ptr_inf(w: Path, env: Env) -> object:
    import scipy.sparse as sp

    from tracker.bqp.qp import BlockQP

    return BlockQP(np.zeros(2), sp.csc_matrix((2, 2)), np.array([0.0, np.inf]))


api_case("api-qp-block-ptr-inf", _qp_block_ptr_inf, "block_ptr must be integers")


def _evaluate_duplicate(w: Path, env: Env) -> object:
    from tracker.metrics import evaluate

    gp = np.zeros((2, 2, 2))
    return evaluate(np.array([1, 2]), gp, np.array([1, 1]), gp)


api_case("api-evaluate-duplicate-ids", _evaluate_duplicate, "tr_ids: id 1 appears more than once")


def _from_spec(w: Path, env: Env) -> object:
    from synth_data.sequence import InMemorySequence

    return InMemorySequence.from_spec(None)


api_case("api-from-spec-none", _from_spec, "spec must be a SequenceSpec")


def _crowd_env(w: Path, env: Env) -> object:
    from envs import crowd_v0

    return crowd_v0.parallel_env(n_agents=5, controlled_ids=[1.5])


api_case("api-crowd-env-ids-float", _crowd_env, "controlled_ids must be a list of integer")


def _dense_256(w: Path, env: Env) -> object:
    from tracker.registry import make_tracker
    from tracker.testing import make_scene

    sc = make_scene([[40, 40], [60, 40], [50, 55], [30, 60]], [[1, 0]] * 4, n_frames=2)
    return make_tracker("bqp-dense").track(sc.frames, sc.ids, sc.points[0], 256)


# the links' counting pass alone would have run for hours, deaf to SIGTERM inside numba
api_case("api-dense-template-256", _dense_256, "candidate pairs to test, more than 2e+10")


def _step_past_the_end(w: Path, env: Env) -> object:
    import gymnasium as gym

    import envs  # noqa: F401 - registers the ids
    from envs.episodes import tiny_scenarios

    e = gym.make("crowdsim/TrackerTuning-v0", scenarios=tiny_scenarios(), k_frames=11)
    e.reset(seed=0)
    e.step(np.zeros(5))  # frames 1-11 of 12: the episode ends
    return e.step(np.zeros(5))


def _reset_needed() -> tuple[type[BaseException], ...]:
    import gymnasium as gym

    return (gym.error.ResetNeeded,)


# as the bandit: a step past the last frame had returned reward 0 as if it were scored
api_case(
    "api-tuning-step-past-end",
    _step_past_the_end,
    "the episode is over; call reset()",
    raises=_reset_needed(),
)
