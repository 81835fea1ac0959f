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


class _Checked(wrappers.BaseWrapper):
    """An AEC face of the crowd that checks what each call passes, at that call: an action
    of the wrong shape or not finite is refused by the ``step`` that gives it (naming the
    agent), never buffered until the cycle's last agent (``parallel_to_aec`` steps the crowd
    only then, and a bad action left in its buffer would fail every step after); and
    ``observe`` of an unknown agent names it (a ``ValueError``, not a ``KeyError``)."""

    def __init__(self, aec: AECEnv, crowd: CrowdParallelEnv) -> None:
        super().__init__(aec)
        self._crowd = crowd

    def step(self, action: Any) -> None:
        if action is not None:  # None: the agent follows the social force (or is done)
            self._crowd._check_action(self.agent_selection, action)
        super().step(action)

    def observe(self, agent: str) -> Any:
        self._crowd._check_agent(agent)
        inner = self.env
        while not hasattr(inner, "_observations") and hasattr(inner, "env"):
            inner = inner.env  # down to parallel_to_aec, which keeps the last observations
        if agent not in getattr(inner, "_observations", {agent: None}):
            raise ValueError(f"observe: agent {agent!r} has not entered the scene yet")
        return super().observe(agent)


def raw_env(**kwargs: Any) -> AECEnv:
    """The AEC face without the usual wrappers (``parallel_to_aec`` of the parallel env), with
    the crowd's checks at the call that passes a bad value."""
    crowd = parallel_env(**kwargs)
    return _Checked(parallel_to_aec(crowd), crowd)


def env(**kwargs: Any) -> AECEnv:
    """The AEC environment with the usual wrappers: call order enforced, finite
    out-of-bounds actions clipped (with a warning); an action of the wrong shape or not
    finite is refused by name first, never clipped."""
    crowd = parallel_env(**kwargs)
    aec = wrappers.ClipOutOfBoundsWrapper(_Checked(parallel_to_aec(crowd), crowd))
    return wrappers.OrderEnforcingWrapper(_Checked(aec, crowd))
