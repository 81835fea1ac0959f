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
* :mod:`envs.heldout` -- defaults, tuned parameters and policies on held-out sequences;
* :mod:`envs.outputs` -- result files a command may replace: only those it can prove it wrote.

The names below are imported lazily (the crowd pulls in pymunk and numba, the tuning
environments the tracker), so ``import envs`` only registers the ids.
"""

from __future__ import annotations

from typing import Any

from gymnasium.envs.registration import register, registry

__all__ = [
    "CrowdEnvParams",
    "CrowdParallelEnv",
    "ParamSpace",
    "TrackerTuningBanditEnv",
    "TrackerTuningEnv",
    "shared_policy_vec_env",
    "train_shared_policy",
]

ENVS: dict[str, str] = {
    "crowdsim/TrackerTuning-v0": "envs.tracker_tuning:TrackerTuningEnv",
    "crowdsim/TrackerTuningBandit-v0": "envs.tracker_tuning:TrackerTuningBanditEnv",
}
"""The one registration table: Gymnasium id -> string entry point (imported by ``gym.make``)."""


def __getattr__(name: str) -> Any:
    # Static imports inside the function: lazy, and visible to the import-layer test.
    if name in (
        "CrowdParallelEnv",
        "CrowdEnvParams",
        "shared_policy_vec_env",
        "train_shared_policy",
    ):
        from envs import crowd as module
    elif name in ("TrackerTuningEnv", "TrackerTuningBanditEnv"):
        from envs import tracker_tuning as module
    elif name == "ParamSpace":
        from envs import param_space as module
    else:
        raise AttributeError(f"module 'envs' has no attribute {name!r}")
    return getattr(module, name)


for _id, _entry_point in ENVS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry_point)
