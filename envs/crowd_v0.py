"""``crowd_v0``: the PettingZoo crowd environment, version 0 (see :mod:`envs.crowd`).

>>> from envs import crowd_v0
>>> par = crowd_v0.parallel_env(n_agents=8, max_cycles=5)
>>> obs, infos = par.reset(seed=0)
>>> len(par.agents), obs["ped_0"].shape
(8, (37,))
>>> aec = crowd_v0.env(n_agents=8, max_cycles=5)  # AEC, order-enforcing, actions clipped
>>> aec.reset(seed=0)
"""

from __future__ import annotations

from typing import Any

from pettingzoo import AECEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from envs.crowd import CrowdEnvParams, CrowdParallelEnv

__all__ = ["CrowdEnvParams", "env", "parallel_env", "raw_env"]


def parallel_env(**kwargs: Any) -> CrowdParallelEnv:
    """The native parallel environment (arguments: see :class:`CrowdParallelEnv`)."""
    return CrowdParallelEnv(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv:
    """The AEC face without the usual wrappers (``parallel_to_aec`` of the parallel env)."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any) -> AECEnv:
    """The AEC environment with the usual wrappers: out-of-bounds actions clipped (with a
    warning), call order enforced."""
    aec = wrappers.ClipOutOfBoundsWrapper(raw_env(**kwargs))
    return wrappers.OrderEnforcingWrapper(aec)
