"""A PettingZoo crowd environment: every pedestrian of a crowdsim scene is an agent.

The versioned public face is :mod:`envs.crowd_v0` (``env``, ``parallel_env``, ``raw_env``);
this module holds the implementation, :class:`CrowdParallelEnv`, its parameters
:class:`CrowdEnvParams`, and a recipe that trains one shared policy with stable-baselines3
over the array API (:func:`shared_policy_vec_env`, :func:`train_shared_policy`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from crowdsim.checks import checked_seed, require_number, whole_numbers
from crowdsim.forces import WallGrid, k_nearest, nearest_wall
from crowdsim.params import SocialForceParams
from crowdsim.scenarios import MAX_AGENTS, Scenario, make_scenario
from crowdsim.simulation import Simulation

NEIGHBOUR_FEATURES = 5
"""Per neighbour: relative position (2), relative velocity (2), present flag (1)."""
OWN_FEATURES = 7
"""Goal direction (2), own velocity (2), nearest-wall direction (2) and proximity (1)."""
_SEED_BOUND = 2**31 - 1


@dataclass(frozen=True, kw_only=True)
class CrowdEnvParams:
    """Numeric settings of :class:`CrowdParallelEnv` (SI units).

    Attributes
    ----------
    n_agents : int
        Pedestrians the scenario places at the start (when it is given by name).
    max_agents : int or None
        Bound of ``possible_agents``: pedestrians with simulation ids ``0 .. max_agents - 1``
        can be agents; later arrivals walk as background. ``None``: ``n_agents``.
    max_cycles : int
        Steps after which every live agent is truncated.
    k_neighbours : int
        ``k``: neighbours reported in an observation (zero-padded).
    neighbour_radius : float
        Neighbours and walls farther than this (m) are not observed.
    vmax : float
        Bound (m/s) of each action component: the Box is ``[-vmax, vmax]^2``.
    controlled_fraction : float
        Fraction of pedestrians that are agents (id ``i`` is one when
        ``floor((i + 1) f) > floor(i f)``, an even, seed-independent spread); the others
        follow the social force.
    collision_weight : float
        Reward lost per metre of body overlap with neighbours and walls.
    """

    n_agents: int = 40
    max_agents: int | None = None
    max_cycles: int = 500
    k_neighbours: int = 6
    neighbour_radius: float = 3.0
    vmax: float = 2.0
    controlled_fraction: float = 1.0
    collision_weight: float = 10.0

    def __post_init__(self) -> None:
        own = "CrowdEnvParams"
        require_number(own, "n_agents", self.n_agents, lo=1, hi=MAX_AGENTS, integer=True)
        if self.max_agents is not None:
            require_number(own, "max_agents", self.max_agents, lo=1, hi=MAX_AGENTS, integer=True)
        require_number(own, "max_cycles", self.max_cycles, lo=1, integer=True)
        require_number(own, "k_neighbours", self.k_neighbours, lo=0, hi=64, integer=True)
        require_number(own, "neighbour_radius", self.neighbour_radius, lo=0, lo_open=True)
        require_number(own, "vmax", self.vmax, lo=0, lo_open=True)
        require_number(own, "controlled_fraction", self.controlled_fraction, lo=0, hi=1)
        require_number(own, "collision_weight", self.collision_weight, lo=0)

    @property
    def obs_size(self) -> int:
        """``d``: length of one observation."""
        return OWN_FEATURES + NEIGHBOUR_FEATURES * int(self.k_neighbours)


class CrowdParallelEnv(ParallelEnv):
    """Pedestrians of a seeded crowdsim scene choose their preferred velocities.

    ## Description

    A :class:`crowdsim.simulation.Simulation` (social forces + pymunk contacts) runs one
    scenario, by default a ``counterflow`` corridor. Each pedestrian whose simulation id is
    below ``max_agents`` (and selected by ``controlled_fraction`` or ``controlled_ids``) is
    a PettingZoo agent named ``"ped_<id>"``; its action replaces its desired velocity
    ``v0_i e_i`` in the social-force driving term for one step, through the simulation's
    control hook (:meth:`crowdsim.simulation.Simulation.step`). Body contacts, the
    repulsion of neighbours and walls, and everybody who is not an agent (or whose action
    is missing from the dict) follow the social force as usual.

    Two faces share one implementation: the PettingZoo dict API (:meth:`reset`,
    :meth:`step`) and an array API for thousands of agents (:meth:`reset_arrays`,
    :meth:`step_arrays`, :meth:`observe_arrays`, :attr:`agent_ids`), vectorised with no
    per-agent Python.

    ## Action Space

    ``Box(-vmax, vmax, (2,), float32)``: the preferred velocity (m/s, world x and y).
    Actions outside the box are clipped (counted in :attr:`n_clipped`). All agents share
    one Space object.

    ## Observation Space

    ``Box(-inf, inf, (d,), float32)`` with ``d = 7 + 5 k``, world axes, metres and m/s:

    | index | meaning |
    |---|---|
    | 0-1 | goal direction: unit vector the agent's route points to (its current gate) |
    | 2-3 | own velocity |
    | 4-5 | unit direction to the nearest wall within ``neighbour_radius`` (zero if none) |
    | 6 | wall proximity ``1 - clearance / neighbour_radius`` in [0, 1] (0 if none) |
    | 7+5j .. 11+5j | j-th nearest neighbour within ``neighbour_radius`` (nearest first) |

    A neighbour block holds its relative position (2), relative velocity (2) and a 1
    (present); padding blocks are all zero.

    Neighbours include non-agent pedestrians; a periodic corridor is seen across its seam.
    All agents share one Space object.

    ## Rewards

    Per step, a Python float: ``(x_i(t+dt) - x_i(t)) . e_i(t) / dt`` (the speed made good
    along the goal direction, m/s) minus ``collision_weight`` times the agent's overlap
    after the step (m): the sum of ``r_i + r_j - d_ij > 0`` over its reported neighbours
    plus ``r_i - clearance > 0`` to the nearest wall. An agent that leaves the scene gets 0
    on that step.

    ## Starting State

    The scenario's seeded initial crowd (``make_scenario(scenario, n_agents=..., **params)``
    when given by name), from the simulation seed drawn from the reset seed.

    ## Episode End

    An agent terminates when it leaves the scene (past the last gate of its route, or out
    of the world's bounds); new pedestrians that enter from sources join as agents while
    their id is below ``max_agents``. After ``max_cycles`` steps every live agent is
    truncated. The episode is over when no agent is left.

    ## Arguments

    ``CrowdParallelEnv(scenario="counterflow", scenario_params=None, *,
    controlled_ids=None, sim_params=None, render_mode=None, render_size=(640, 360),
    **params)`` where ``params`` are the fields of :class:`CrowdEnvParams` (``n_agents``,
    ``max_agents``, ``max_cycles``, ``k_neighbours``, ``neighbour_radius``, ``vmax``,
    ``controlled_fraction``, ``collision_weight``). ``scenario`` is a scenario name (see
    :data:`crowdsim.scenarios.SCENARIOS`) or a :class:`~crowdsim.scenarios.Scenario`;
    ``controlled_ids`` lists the agent ids explicitly instead of ``controlled_fraction``; at
    least one of them must be in the scene at the start (an episode ends when no agent is
    left, so one without any would be over at once: :meth:`reset` refuses it).
    ``render_mode="rgb_array"`` makes :meth:`render` return the top-down ``(H, W, 3)``
    uint8 RGB frame drawn by :class:`crowdsim.render.SceneRenderer` (agents in the distinct
    "prominent" colours, background walkers in dull ones, walls as dark lines).

    All randomness (the scene, arrivals, rendering) derives from the seed given to
    :meth:`reset`.

    ## Version History

    * v0: initial release.
    """

    metadata = {
        "name": "crowd_v0",
        "render_modes": ["rgb_array"],
        "render_fps": 25,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: str | Scenario = "counterflow",
        scenario_params: Mapping[str, Any] | None = None,
        *,
        controlled_ids: Sequence[int] | None = None,
        sim_params: SocialForceParams | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (640, 360),
        **params: Any,
    ) -> None:
        unknown = sorted(set(params) - set(CrowdEnvParams.__dataclass_fields__))
        if unknown:
            raise ValueError(
                f"CrowdParallelEnv: unknown parameter(s) {', '.join(unknown)}; valid: "
                f"{', '.join(CrowdEnvParams.__dataclass_fields__)}"
            )
        self.params = CrowdEnvParams(**params)
        p = self.params
        if isinstance(scenario, Scenario):
            if scenario_params:
                raise ValueError("scenario_params only apply to a scenario given by name")
            self.scenario = scenario
        else:
            if scenario_params is not None and not isinstance(scenario_params, Mapping):
                raise ValueError(
                    f"scenario_params must be a mapping of the scenario's fields, got "
                    f"{scenario_params!r}"
                )
            self.scenario = make_scenario(
                scenario, **{"n_agents": p.n_agents, **dict(scenario_params or {})}
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        if not (isinstance(render_size, (tuple, list)) and len(render_size) == 2):
            raise ValueError(f"render_size must be (width, height) in px, got {render_size!r}")
        for v in render_size:
            require_number("CrowdParallelEnv", "render_size", v, lo=16, hi=8192, integer=True)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        if sim_params is not None and not isinstance(sim_params, SocialForceParams):
            raise ValueError(
                f"sim_params must be a crowdsim.params.SocialForceParams, got {sim_params!r}"
            )
        self.sim_params = sim_params if sim_params is not None else SocialForceParams()
        max_agents = int(p.max_agents if p.max_agents is not None else self.scenario.n_agents)
        self.max_agents = max_agents
        ids = np.arange(max_agents)
        if controlled_ids is not None:
            raw = np.asarray(controlled_ids).reshape(-1)
            if not whole_numbers(raw):  # never cast 1.5 to agent 1 in silence
                raise ValueError(
                    f"controlled_ids must be a list of integer agent ids, got {controlled_ids!r}"
                )
            chosen = np.unique(raw.astype(np.int64))
            if len(chosen) and (chosen[0] < 0 or chosen[-1] >= max_agents):
                raise ValueError(
                    f"controlled_ids must lie in [0, {max_agents}), got {chosen.tolist()[:10]}"
                )
            is_agent = np.isin(ids, chosen)
        else:
            f = float(p.controlled_fraction)
            is_agent = np.floor((ids + 1) * f) > np.floor(ids * f)
        # Lookup by simulation id; ids >= max_agents are never agents.
        self._is_agent = is_agent
        self.possible_agents = [f"ped_{i}" for i in np.flatnonzero(is_agent)]
        self._agent_set = frozenset(self.possible_agents)
        self._obs_space = spaces.Box(-np.inf, np.inf, (p.obs_size,), np.float32)
        self._act_space = spaces.Box(-p.vmax, p.vmax, (2,), np.float32)
        self._agent_names: list[str] | None = []
        self._live_names: tuple[list[str], frozenset[str]] | None = None
        self.np_random: np.random.Generator | None = None
        self.sim: Simulation | None = None
        self.n_clipped = 0
        self._cycles = 0
        self._ids = np.zeros(0, np.int64)
        self._obs = np.zeros((0, p.obs_size), np.float32)
        self._goal = np.zeros((0, 2))
        self._renderer: Any = None

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> spaces.Box:
        """The one observation Space object shared by all agents."""
        self._check_agent(agent)
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        """The one action Space object shared by all agents."""
        self._check_agent(agent)
        return self._act_space

    def _check_agent(self, agent: str) -> None:
        if not isinstance(agent, str) or agent not in self._agent_set:
            raise ValueError(
                f"unknown agent {agent!r}; agents are named 'ped_<id>' with "
                f"ids below max_agents = {self.max_agents}"
            )

    def _live_set(self) -> frozenset[str]:
        if self._live_names is None or self._live_names[0] is not self.agents:
            self._live_names = (self.agents, frozenset(self.agents))
        return self._live_names[1]

    @staticmethod
    def _check_action(name: str, a: Any) -> None:
        """``ValueError`` naming agent ``name`` unless ``a`` is a finite ``(2,)`` action."""
        try:
            raw = np.asarray(a)
            if raw.dtype.kind not in "iuf":  # never cast "1", 1+2j or True in silence
                raise TypeError
            v = raw.astype(np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action of {name!r} must be 2 numbers (m/s), got {a!r}") from None
        if v.shape != (2,):
            raise ValueError(
                f"action of {name!r} must have shape (2,) (preferred velocity, m/s), "
                f"got shape {v.shape}: {a!r}"
            )
        if not np.isfinite(v).all():
            raise ValueError(f"action of {name!r} must be finite, got {v.tolist()}")

    def _refuse_agent(self, name: Any) -> None:
        """``ValueError`` for an action addressed to ``name``, which is not a live agent."""
        self._check_agent(name)  # a misspelt or impossible name
        raise ValueError(
            f"action for agent {name!r}, which is not live (it has left the scene or has "
            "not entered yet); act only for env.agents"
        )

    @property
    def agents(self) -> list[str]:
        """Names of the live agents, ``"ped_<id>"`` in :attr:`agent_ids` order."""
        if self._agent_names is None:
            self._agent_names = [f"ped_{i}" for i in self._ids.tolist()]
        return self._agent_names

    # ------------------------------------------------------------------ array API
    @property
    def agent_ids(self) -> np.ndarray:
        """Simulation ids ``(n,)`` int64, sorted, of the live agents (the rows of the
        arrays :meth:`observe_arrays` returns and :meth:`step_arrays` takes)."""
        return self._ids.copy()

    def reset_arrays(self, seed: int | None = None) -> np.ndarray:
        """Start an episode; return the observations ``(n, d)`` float32 of :attr:`agent_ids`.

        ``seed`` seeds everything (the first reset without one draws fresh entropy; later
        ones continue the env's generator).
        """
        seed = checked_seed(seed)
        if seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        sim_seed, self._render_seed = (int(v) for v in self.np_random.integers(0, _SEED_BOUND, 2))
        self.sim = Simulation(self.scenario, seed=sim_seed, params=self.sim_params, record=False)
        self._wall_grid = WallGrid(self.sim.world.walls, self.params.neighbour_radius)
        self._cycles = 0
        self.n_clipped = 0
        self._refresh_live()
        if len(self._ids) == 0:
            self.sim = None  # no episode began: step() asks for reset() (it stepped an empty one)
            raise ValueError(
                "reset: no agent is in the scene at the start (the controlled ids "
                f"{self.possible_agents[:5]} have not arrived), so the episode would be over "
                "at once; control pedestrians present at the start"
            )
        return self._obs.copy()

    def observe_arrays(self) -> np.ndarray:
        """Observations ``(n, d)`` float32 of the live agents :attr:`agent_ids`."""
        return self._obs.copy()

    def step_arrays(
        self, actions: np.ndarray, act: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One step for the agents that were live before it (:attr:`agent_ids`, ``n``).

        Parameters
        ----------
        actions : (n, 2) float
            Preferred velocities (m/s), clipped to the action Box.
        act : (n,) bool, optional
            False rows follow the social force this step (their action is ignored).

        Returns
        -------
        obs : (n, d) float32
            Observation after the step (zeros for agents that left).
        rewards : (n,) float64
        terminated : (n,) bool
            The agent left the scene.
        truncated : (n,) bool
            ``max_cycles`` reached (the agent is still in the scene).

        Agents that entered during the step appear in :attr:`agent_ids` afterwards;
        :meth:`observe_arrays` gives the observations of the new live set.
        """
        sim = self._require_sim()
        if self._cycles >= self.params.max_cycles:  # it had stepped on in silence
            raise RuntimeError(
                f"the episode is over (max_cycles={self.params.max_cycles} reached): call reset()"
            )
        if self._cycles > 0 and len(self._ids) == 0:  # as step() does: one end for both faces
            raise RuntimeError("the episode is over (no agent is left): call reset()")
        ids = self._ids
        n = len(ids)
        if np.asarray(actions).dtype.kind not in "iuf":
            raise ValueError(f"actions must be (n, 2) numbers, got {actions!r:.60}")
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (n, 2):
            raise ValueError(f"actions must have shape ({n}, 2), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("actions must be finite")
        vmax = self.params.vmax
        clipped = np.clip(a, -vmax, vmax)
        if act is None:
            mask = np.ones(n, dtype=bool)
        else:
            mask = np.asarray(act)
            if mask.dtype != np.bool_ or mask.shape != (n,):
                raise ValueError(
                    f"act must be a boolean ({n},) mask, got {mask.dtype} of shape {mask.shape}"
                )
        controlled, command = ids[mask], clipped[mask]
        self.n_clipped += int(np.count_nonzero((command != a[mask]).any(axis=1)))
        before = sim.state.pos[sim.index_of(ids)]
        goal = self._goal
        sim.step(desired_velocity=command, controlled=controlled)
        self._cycles += 1
        rows = sim.index_of(ids, strict=False)
        present = rows >= 0
        obs_all, overlap_all, agent_rows = self._observe_agents()
        # Agent rows are a subset of the state rows in order: locate ours by id.
        pos_in = np.searchsorted(sim.state.ids[agent_rows], ids[present])
        obs = np.zeros((n, self.params.obs_size), np.float32)
        obs[present] = obs_all[pos_in]
        moved = sim.state.pos[rows[present]] - before[present]
        period = sim.world.period
        if period > 0:
            moved[:, 0] -= period * np.round(moved[:, 0] / period)
        rewards = np.zeros(n)
        rewards[present] = (
            np.einsum("ij,ij->i", moved, goal[present]) / sim.params.dt
            - self.params.collision_weight * overlap_all[pos_in]
        )
        terminated = ~present
        truncated = present & (self._cycles >= self.params.max_cycles)
        self._refresh_live(obs_all, agent_rows)
        return obs, rewards, terminated, truncated

    # ------------------------------------------------------------------ PettingZoo API
    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset: options must be a dict or None, got {options!r}")
        # it takes no options, and ignores any: PettingZoo's own api_test resets with
        # options={"options": 1} and expects that to work
        obs = self.reset_arrays(seed)
        return dict(zip(self.agents, obs, strict=True)), {a: {} for a in self.agents}

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict]
    ]:
        self._require_sim()
        if not self.agents and self._cycles > 0:
            raise RuntimeError("the episode is over (no agent is left): call reset()")
        names = self.agents
        n = len(names)
        if not isinstance(actions, Mapping):
            raise ValueError(
                f"actions must be a dict of agent name -> (2,) action, got {type(actions).__name__}"
            )
        live = self._live_set()
        if not live.issuperset(actions):
            self._refuse_agent(next(k for k in actions if k not in live))
        rows = [k for k, name in enumerate(names) if actions.get(name) is not None]
        given = [actions[names[k]] for k in rows]
        try:  # one conversion for all (thousands of agents); per agent only to name a culprit
            block = np.asarray(given) if given else np.zeros((0, 2))
        except (TypeError, ValueError):  # ragged
            block = None
        if (
            block is None
            or block.dtype.kind not in "iuf"
            or block.shape != (len(given), 2)
            or not np.isfinite(block).all()
        ):
            for k in rows:
                self._check_action(names[k], actions[names[k]])
        arr = np.zeros((n, 2))
        act = np.zeros(n, dtype=bool)
        if rows:
            arr[rows] = block
            act[rows] = True
        ids_before = self._ids
        obs, rew, term, trunc = self.step_arrays(arr, act)
        out_obs = dict(zip(names, obs, strict=True))
        rewards = dict(zip(names, rew.tolist(), strict=True))
        terminations = dict(zip(names, term.tolist(), strict=True))
        truncations = dict(zip(names, trunc.tolist(), strict=True))
        live = self.agents
        # newcomers, in live order: found by id at once (a loop over every live agent's name
        # was a tenth of this dict layer at 5,000 agents)
        for k in np.flatnonzero(~np.isin(self._ids, ids_before)).tolist():
            out_obs[live[k]] = self._obs[k].copy()
            rewards[live[k]] = 0.0
            terminations[live[k]] = truncations[live[k]] = False
        return out_obs, rewards, terminations, truncations, {a: {} for a in out_obs}

    def render(self) -> np.ndarray | None:
        """The top-down frame ``(H, W, 3)`` uint8 RGB (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            return None
        sim = self._require_sim()
        if self._renderer is None or self._renderer[0] != self._render_seed:
            self._renderer = (self._render_seed, *self._make_renderer())
        _, renderer, appearance_of = self._renderer
        st = sim.state
        cam = renderer.camera
        px = cam.project(st.pos)
        speed = np.hypot(st.vel[:, 0], st.vel[:, 1])
        facing = np.where((speed > 0.15)[:, None], st.vel, sim.route_directions())
        ahead = cam.project(st.pos + 0.1 * facing) - px
        heading = np.arctan2(ahead[:, 1], ahead[:, 0])
        frame = renderer.render(sim.steps, px, heading, appearance_of(st.ids))
        import cv2

        walls = sim.world.walls
        if len(walls):  # the renderer draws people only; walls as dark lines on top
            ends = np.rint(cam.project(walls[:, :4].reshape(-1, 2))).astype(np.int32)
            width = max(1, int(round(2 * float(walls[:, 4].mean()) * cam.px_per_m)))
            cv2.polylines(frame, list(ends.reshape(-1, 2, 2)), False, (40, 40, 40), width)
        return np.ascontiguousarray(frame[..., ::-1])

    def close(self) -> None:
        self._renderer = None

    def state(self) -> np.ndarray:
        """Positions and velocities ``(n_present, 4)`` of every pedestrian in the scene."""
        st = self._require_sim().state
        return np.hstack([st.pos, st.vel]).astype(np.float32)

    # ------------------------------------------------------------------ internals
    def _require_sim(self) -> Simulation:
        if self.sim is None:
            raise RuntimeError("call reset() before step() or render()")
        return self.sim

    def _agent_rows(self) -> np.ndarray:
        ids = self.sim.state.ids
        inside = ids < self.max_agents
        rows = np.flatnonzero(inside)
        return rows[self._is_agent[ids[rows]]]

    def _refresh_live(
        self, obs_all: np.ndarray | None = None, agent_rows: np.ndarray | None = None
    ) -> None:
        """Live agents, their observations and goal directions after a reset or step."""
        if obs_all is None:
            obs_all, _, agent_rows = self._observe_agents()
        if self._cycles >= self.params.max_cycles:
            agent_rows = agent_rows[:0]
            obs_all = obs_all[:0]
        self._ids = self.sim.state.ids[agent_rows]
        self._obs = obs_all
        self._goal = self._route_dir[agent_rows] if len(agent_rows) else np.zeros((0, 2))
        self._agent_names = None  # built on first access: the array API never needs it

    def _observe_agents(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Observations ``(m, d)`` float32 and overlaps ``(m,)`` m of every agent in the
        scene, with their state rows ``(m,)``."""
        sim = self.sim
        p = self.params
        st = sim.state
        rows = self._agent_rows()
        m, k, radius = len(rows), int(p.k_neighbours), float(p.neighbour_radius)
        self._route_dir = sim.route_directions()
        obs = np.zeros((m, p.obs_size), np.float32)
        overlap = np.zeros(m)
        if m == 0:
            return obs, overlap, rows
        pos, vel = st.pos[rows], st.vel[rows]
        obs[:, 0:2] = self._route_dir[rows]
        obs[:, 2:4] = vel
        clearance, wall_dir = nearest_wall(pos, sim.world.walls, self._wall_grid, radius)
        near = np.isfinite(clearance)
        obs[:, 4:6] = wall_dir
        obs[:, 6] = np.where(near, np.clip(1.0 - clearance / radius, 0.0, 1.0), 0.0)
        overlap += np.where(near, np.maximum(st.radius[rows] - clearance, 0.0), 0.0)
        if k == 0 or st.n < 2:
            return obs, overlap, rows
        nbr, dist, rel = k_nearest(st.pos, rows, k, radius, sim.world.period)
        valid = nbr >= 0
        safe = np.where(valid, nbr, rows[:, None])  # padding: the agent itself, zeroed below
        feats = np.empty((m, k, NEIGHBOUR_FEATURES))
        feats[..., 0:2] = rel
        feats[..., 2:4] = st.vel[safe] - vel[:, None, :]
        feats[..., 4] = valid
        feats[~valid] = 0.0
        obs[:, OWN_FEATURES:] = feats.reshape(m, k * NEIGHBOUR_FEATURES)
        gap = st.radius[rows][:, None] + st.radius[safe] - dist
        overlap += np.where(valid, np.maximum(gap, 0.0), 0.0).sum(axis=1)
        return obs, overlap, rows

    def _make_renderer(self) -> tuple[Any, Any]:
        from crowdsim.appearance_model import AppearanceParams
        from crowdsim.camera import Camera
        from crowdsim.render import BODY_WIDTH_M, SceneRenderer, assign_appearance

        sim = self.sim
        cam = Camera.fit(sim.world.bounds, size=self.render_size, margin_m=0.5)
        template = int(np.clip(round(BODY_WIDTH_M * cam.px_per_m), 4, 64))
        look = AppearanceParams(
            template_px=template, prominent_fraction=0.0, illumination_drift=0.0, noise_sigma=1.0
        )
        renderer = SceneRenderer(cam, look, self._render_seed, self.metadata["render_fps"])
        chunk = 1024
        table: list[np.ndarray] = []

        def appearance_of(ids: np.ndarray) -> np.ndarray:
            """Looks by id, drawn per block of 1024 ids (so they do not depend on when an
            id first shows up); agents wear the distinct "prominent" colours."""
            need = int(ids.max()) // chunk + 1 if len(ids) else 0
            while len(table) < need:
                c = len(table)
                block = np.arange(c * chunk, (c + 1) * chunk)
                agent = (block < self.max_agents) & self._is_agent[
                    np.minimum(block, self.max_agents - 1)
                ]
                rng = np.random.default_rng([self._render_seed, c])
                table.append(assign_appearance(agent, chunk, look, rng)[0])
            return np.concatenate(table)[ids] if len(ids) else np.zeros(0, np.int64)

        return renderer, appearance_of


# ------------------------------------------------------------------------------ SB3 recipe


def shared_policy_vec_env(env: CrowdParallelEnv, seed: int | None = None) -> Any:
    """Every possible agent of ``env`` as one slot of a stable-baselines3 ``VecEnv``.

    One policy is shared by all pedestrians: slot ``j`` is ``env.possible_agents[j]``, and a
    step is one :meth:`CrowdParallelEnv.step_arrays` call (no per-agent Python). A slot
    whose pedestrian has left (or not yet arrived) gets zero observations and rewards
    until the episode ends; an agent's own termination or truncation is reported as
    ``done`` with its ``terminal_observation``. When no agent is left the env resets
    (``seed`` first, then its own generator) and every slot is done. ``VecEnv.seed(s)``
    (``PPO(..., seed=s)`` calls it) seeds the next reset with ``s``, as SB3's vector envs
    do. Scenes without inflow (e.g. a periodic corridor) fit this best.
    """
    from crowdsim.optional import require

    VecEnv = require("stable_baselines3.common.vec_env", "rl", "the shared-policy recipe").VecEnv
    if not isinstance(env, CrowdParallelEnv):
        raise ValueError(f"env must be a CrowdParallelEnv, got {type(env).__name__}")

    if not env.possible_agents:
        raise ValueError("shared_policy_vec_env: the env has no possible agents (no slot)")
    slot_ids = np.array([int(a.split("_", 1)[1]) for a in env.possible_agents], np.int64)

    class SharedPolicyVecEnv(VecEnv):
        def __init__(self) -> None:
            super().__init__(len(slot_ids), env._obs_space, env._act_space)
            self._seed = seed
            self._actions = np.zeros((len(slot_ids), 2))

        def _fill(self, obs: np.ndarray) -> np.ndarray:
            out = np.zeros((self.num_envs, env.params.obs_size), np.float32)
            out[np.searchsorted(slot_ids, env.agent_ids)] = obs
            return out

        def reset(self) -> np.ndarray:
            # VecEnv.seed(s) (what PPO(seed=s) calls) seeds the next reset, as SB3's own
            # vector envs do; the slots share one crowd, so the first slot's seed is its seed
            seed = self._seeds[0] if self._seeds[0] is not None else self._seed
            obs = env.reset_arrays(seed)
            self._seed = None
            self._reset_seeds()
            return self._fill(obs)

        def step_async(self, actions: np.ndarray) -> None:
            a = np.asarray(actions, dtype=np.float64)
            if a.shape != (self.num_envs, 2):
                raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {a.shape}")
            self._actions = a

        def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
            slots = np.searchsorted(slot_ids, env.agent_ids)
            obs, rew, term, trunc = env.step_arrays(self._actions[slots])
            rewards = np.zeros(self.num_envs, np.float32)
            rewards[slots] = rew
            dones = np.zeros(self.num_envs, dtype=bool)
            dones[slots] = term | trunc
            infos: list[dict] = [{} for _ in range(self.num_envs)]
            for j, o, tr in zip(
                slots[dones[slots]], obs[dones[slots]], trunc[dones[slots]], strict=True
            ):
                infos[j] = {"terminal_observation": o, "TimeLimit.truncated": bool(tr)}
            if len(env.agent_ids) == 0:  # episode over: every slot restarts
                for j in np.flatnonzero(~dones):
                    infos[j] = {
                        "terminal_observation": np.zeros(env.params.obs_size, np.float32),
                        "TimeLimit.truncated": True,
                    }
                dones[:] = True
                return self.reset(), rewards, dones, infos
            return self._fill(env.observe_arrays()), rewards, dones, infos

        def close(self) -> None:
            env.close()

        def render(self, mode: str | None = None) -> np.ndarray | None:
            return env.render()  # one crowd: one frame, not a mosaic of num_envs copies

        def get_images(self) -> list[np.ndarray | None]:
            return [env.render()] * self.num_envs

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            return [getattr(env, attr_name)] * len(self._indices(indices))

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            setattr(env, attr_name, value)

        def env_method(
            self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any
        ) -> list[Any]:
            return [getattr(env, method_name)(*args, **kwargs)] * len(self._indices(indices))

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False] * len(self._indices(indices))

        def _indices(self, indices: Any) -> list[int]:
            if indices is None:
                return list(range(self.num_envs))
            return [indices] if isinstance(indices, int) else list(indices)

    return SharedPolicyVecEnv()


def train_shared_policy(
    total_timesteps: int = 30_000,
    *,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    ppo_kwargs: Mapping[str, Any] | None = None,
) -> tuple[Any, list[float]]:
    """Train one PPO policy shared by every pedestrian; return it and its reward curve.

    The recipe: a :class:`CrowdParallelEnv` (by default 16 agents in a periodic 4 m
    counterflow corridor, 128-step episodes), every agent one slot of
    :func:`shared_policy_vec_env`, stable-baselines3's PPO with an MLP policy and one
    episode per rollout. The curve is the mean per-step reward of each rollout (m/s made
    good along the goal, less the collision penalty), in order; it rises as the policy
    learns to walk towards its goal.

    >>> model, curve = train_shared_policy(20_000)  # doctest: +SKIP
    >>> curve[0] < curve[-1]  # doctest: +SKIP
    True

    ``total_timesteps`` counts agent steps (slots x env steps). Needs the ``rl`` extra
    (torch, stable-baselines3), imported only here.
    """
    from crowdsim.optional import require

    require_number("train_shared_policy", "total_timesteps", total_timesteps, lo=1, integer=True)
    for name, given in (("env_kwargs", env_kwargs), ("ppo_kwargs", ppo_kwargs)):
        if given is not None and not isinstance(given, Mapping):
            raise ValueError(f"train_shared_policy.{name} must be a mapping, got {given!r}")
    require("torch", "rl", "the shared-policy recipe")
    PPO = require("stable_baselines3", "rl", "the shared-policy recipe").PPO
    from stable_baselines3.common.callbacks import BaseCallback

    kwargs = {
        "scenario": "counterflow",
        "scenario_params": {"periodic": True, "inflow": False, "width": 4.0},
        "n_agents": 16,
        "max_cycles": 128,
        **dict(env_kwargs or {}),
    }
    venv = shared_policy_vec_env(CrowdParallelEnv(**kwargs), seed=seed)
    curve: list[float] = []

    class RewardCurve(BaseCallback):
        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            curve.append(float(np.mean(self.model.rollout_buffer.rewards)))

    # One rollout = one episode, so that each point of the curve covers a whole episode.
    n_steps = int(venv.get_attr("params")[0].max_cycles)
    options = {
        "n_steps": n_steps,
        "batch_size": 256,
        "learning_rate": 1e-3,
        "seed": seed,
        "verbose": 0,
        **dict(ppo_kwargs or {}),
    }
    try:
        model = PPO("MlpPolicy", venv, **options)
    except TypeError as exc:  # a keyword PPO does not take
        raise ValueError(f"train_shared_policy.ppo_kwargs: {exc}") from None
    if not options["verbose"]:
        from stable_baselines3.common.logger import Logger

        model.set_logger(Logger(None, []))  # else SB3 leaves an empty /tmp/SB3-<time> folder
    model.learn(total_timesteps=int(total_timesteps), callback=RewardCurve())
    return model, curve
