"""ParamSpace: [-1, 1]^d <-> BQPParams, shared by the env, Optuna and Ray Tune."""

from __future__ import annotations

import numpy as np
import pytest

from envs.param_space import BASE_TUNABLES, EXTRA_TUNABLES, ParamSpace, Tunable
from tracker.bqp.params import BQPParams


def test_zero_action_is_exactly_the_paper_defaults():
    space = ParamSpace()
    assert space.to_params(np.zeros(5)) == BQPParams()
    ext = ParamSpace(extended=True)
    assert ext.dim == 8 and ext.to_params(np.zeros(8)) == BQPParams()
    np.testing.assert_array_equal(space.to_action(BQPParams()), np.zeros(5))


def test_ends_of_the_box_are_the_documented_ranges():
    space = ParamSpace(extended=True)
    lo, hi = space.to_params(-np.ones(8)), space.to_params(np.ones(8))
    for t in BASE_TUNABLES + EXTRA_TUNABLES:
        assert getattr(lo, t.name) == pytest.approx(t.low)
        assert getattr(hi, t.name) == pytest.approx(t.high)
    assert (lo.zeta, lo.eta, lo.w_sp, lo.w_g) == (0.0, 0.0, 0.0, 0.0)  # terms can switch off


def test_round_trip_and_monotone():
    space = ParamSpace(extended=True)
    rng = np.random.default_rng(0)
    for _ in range(50):
        a = rng.uniform(-1, 1, 8)
        np.testing.assert_allclose(space.to_action(space.to_params(a)), a, atol=1e-12)
    grid = np.linspace(-1, 1, 41)
    for t in space.tunables:
        v = t.value(grid)
        assert (np.diff(v) > 0).all()


def test_clipping_counts_and_refuses_nan_and_wrong_shape():
    space = ParamSpace()
    a, n = space.clip([1.5, -2, 0.3, 1.0, -1.0])
    assert n == 2 and a.tolist() == [1.0, -1.0, 0.3, 1.0, -1.0]
    assert space.to_params([9, 9, 9, 9, 9]) == space.to_params(np.ones(5))
    with pytest.raises(ValueError, match=r"must be finite, got \[nan"):
        space.clip([np.nan, 0, 0, 0, 0])
    with pytest.raises(ValueError, match=r"must be finite, got \[inf"):  # never clipped to 1
        space.clip([np.inf, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="5 real numbers"):
        space.clip(np.zeros(3))
    with pytest.raises(ValueError, match=r"got shape \(1, 5\)"):  # no reshaping
        space.clip(np.zeros((1, 5)))


def test_values_outside_a_range_map_to_its_end():
    space = ParamSpace()
    a = space.to_action(
        {"zeta": 5.0, "eta": -1.0, "w_sp": 0.3, "w_g": 1.0, "update_threshold": 0.6}
    )
    assert a.tolist() == [1.0, -1.0, 0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="lack w_g"):
        space.to_action({"zeta": 1, "eta": 1, "w_sp": 1, "update_threshold": 1})


def test_base_params_keep_their_untuned_fields():
    base = BQPParams(appearance="ncc", fw_variant="away")
    p = ParamSpace(base=base).to_params(np.ones(5))
    assert (p.appearance, p.fw_variant, p.zeta) == ("ncc", "away", 1.5)
    with pytest.raises(ValueError, match="tunable tracker.*got dict"):
        ParamSpace(base={"zeta": 1})
    with pytest.raises(ValueError, match="unknown BQPParams parameter"):
        ParamSpace().params_from_dict({"zeta": 1.0, "gamma": 2})


def test_every_row_of_tunables_names_real_fields_with_the_class_defaults():
    """Action 0 is each tracker's own defaults, both range ends are valid parameters, and
    every tunable registry name builds a space; trackers without a row are refused by name."""
    from dataclasses import fields

    from envs.param_space import TUNABLES, tunable_trackers
    from tracker.registry import TRACKERS, get

    assert set(tunable_trackers()) == {"bqp", "bqp-ncc", "bqp-dense", "pnmc", "ncc"}
    assert set(TUNABLES) == {TRACKERS[n].params for n in tunable_trackers()}
    for name in tunable_trackers():
        for extended in (False, True):
            space = ParamSpace(extended=extended, tracker=name)
            base = get(name).make_params()
            defaults = {f.name: f.default for f in fields(space.params_class)}
            for t in space.tunables:
                assert t.default == defaults[t.name], (name, t.name)
            assert space.to_params(space.default_action) == base
            space.to_params(-np.ones(space.dim))  # the parameter class validates both ends
            space.to_params(np.ones(space.dim))
            np.testing.assert_allclose(space.to_action(space.to_params(np.ones(space.dim))), 1)
    assert ParamSpace(tracker="bqp-ncc").base.appearance == "ncc"
    for name in ("bytetrack", "meanshift"):
        with pytest.raises(ValueError, match=f"{name}: no row of tunables"):
            ParamSpace(tracker=name)


def test_integer_tunables_round_and_reach_their_ends():
    space = ParamSpace(tracker="ncc", extended=True)
    assert space.names == ("update_threshold", "search_factor", "update_every")
    assert space.to_params([0, 0, -1]).update_every == 1
    assert space.to_params([0, 0, 0.52]).update_every == 20  # 10 + 0.52 * 20 = 20.4
    assert isinstance(space.values([0, 0, 0.3])["update_every"], int)
    assert space.signature().startswith("NCCParams;")
    assert not ParamSpace().signature().startswith("BQPParams")  # old studies stay valid


def test_optuna_suggestions_use_the_same_ranges():
    optuna = pytest.importorskip("optuna")
    space = ParamSpace()
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=1))
    seen = []

    def objective(trial):
        values = space.optuna_suggest(trial)
        seen.append(values)
        return -float(np.sum(space.to_action(values) ** 2))

    study.optimize(objective, n_trials=20)
    for v in seen:
        for t in space.tunables:
            assert t.low <= v[t.name] <= t.high
    dists = space.optuna_distributions()
    assert dists["w_g"].low == 0.0 and dists["w_g"].high == 3.0


def test_tunable_validation():
    with pytest.raises(ValueError, match="default"):
        Tunable(name="zeta", low=0.0, default=2.0, high=1.0)
    with pytest.raises(ValueError, match="high"):
        Tunable(name="zeta", low=1.0, default=1.0, high=1.0)


def test_integer_tunables_round_to_nearest():
    space = ParamSpace(extended=True, tracker="pnmc")
    values = space.typed({**dict.fromkeys(space.names, 1.0), "update_every": 10.6})
    assert values["update_every"] == 11


def test_candidate_actions_are_the_defaults_then_sobol_points_over_the_whole_box():
    from scipy.stats import qmc

    from envs.param_space import candidate_actions

    actions = candidate_actions(ParamSpace(), 9, seed=3)
    assert np.array_equal(actions[0], np.zeros(5))
    want = 2.0 * qmc.Sobol(5, scramble=True, seed=3).random(8) - 1.0
    np.testing.assert_array_equal(actions[1:], want)
    assert (actions[1:] < 0).any() and (actions[1:] > 0).any()


def test_the_default_distribution_holds_every_scenario():
    """--scenarios all draws from DEFAULT_SCENARIOS, a fixed order: a new scenario must be
    appended there (the end keeps every earlier draw), or it is left out in silence."""
    from crowdsim.scenarios import SCENARIOS
    from envs.episodes import DEFAULT_SCENARIOS

    missing = sorted(set(SCENARIOS) - set(DEFAULT_SCENARIOS))
    assert not missing, f"append {missing} to envs.episodes.DEFAULT_SCENARIOS"
    assert len(DEFAULT_SCENARIOS) == len(set(DEFAULT_SCENARIOS)) == len(SCENARIOS)
