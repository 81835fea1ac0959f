"""Environments for tuning dense-crowd trackers and for driving crowds (SPEC §8).

Importing this package registers the Gymnasium ids (string entry points: nothing heavy is
imported until ``gymnasium.make``):

* ``crowdsim/TrackerTuning-v0`` -- :class:`envs.tracker_tuning.TrackerTuningEnv`: the real
  BQP tracker runs inside; an action sets its term weights and appearance-update threshold
  for the next K frames; the reward is the tracking accuracy over them;
* ``crowdsim/TrackerTuningBandit-v0`` -- the one-step variant for black-box tuners.

Module map:

* :mod:`envs.param_space` -- Box[-1, 1]^d <-> tracker parameters (env, Optuna, Ray Tune);
* :mod:`envs.episodes` -- seeded scenario distribution -> in-memory sequences, or a suite;
* :mod:`envs.tracker_tuning` -- the two Gymnasium environments;
* :mod:`envs.crowd_v0` -- the PettingZoo crowd (``env``, ``parallel_env``, ``raw_env``);
* :mod:`envs.tuners` -- Optuna / Ray Tune / stable-baselines3 drivers.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

_ENVS = {
    "crowdsim/TrackerTuning-v0": "envs.tracker_tuning:TrackerTuningEnv",
    "crowdsim/TrackerTuningBandit-v0": "envs.tracker_tuning:TrackerTuningBanditEnv",
}
for _id, _entry_point in _ENVS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry_point)
