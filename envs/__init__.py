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
* :mod:`envs.crowd` -- :class:`CrowdParallelEnv`, the PettingZoo crowd (one agent per
  pedestrian), its array API and the shared-policy recipe;
* :mod:`envs.crowd_v0` -- the versioned face (``env``, ``parallel_env``, ``raw_env``);
* :mod:`envs.tuners` -- Optuna / Ray Tune drivers (static parameters);
* :mod:`envs.training` -- stable-baselines3 training of adaptive policies, loading them;
* :mod:`envs.heldout` -- defaults, tuned parameters and policies on held-out sequences.

The names below are imported lazily (the crowd pulls in pymunk and numba, the tuning
environments the tracker), so ``import envs`` only registers the ids.
"""

from __future__ import annotations

import importlib
from typing import Any

from gymnasium.envs.registration import register, registry

_EXPORTS = {
    "CrowdParallelEnv": "envs.crowd",
    "CrowdEnvParams": "envs.crowd",
    "shared_policy_vec_env": "envs.crowd",
    "train_shared_policy": "envs.crowd",
    "TrackerTuningEnv": "envs.tracker_tuning",
    "TrackerTuningBanditEnv": "envs.tracker_tuning",
    "ParamSpace": "envs.param_space",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'envs' has no attribute {name!r}")


_ENVS = {
    "crowdsim/TrackerTuning-v0": "envs.tracker_tuning:TrackerTuningEnv",
    "crowdsim/TrackerTuningBandit-v0": "envs.tracker_tuning:TrackerTuningBanditEnv",
}
for _id, _entry_point in _ENVS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry_point)
