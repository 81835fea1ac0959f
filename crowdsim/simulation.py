"""The crowd simulation: social forces (numba) + contacts (pymunk).

One step:

1. routes give each agent its desired direction ``e_i``; agents past their last gate leave;
2. sources add agents (Poisson, only where they do not overlap anybody);
3. agents under control (the hook below) get ``v0_i e_i`` replaced by a given velocity;
4. :func:`crowdsim.forces.social_force` computes every agent's acceleration at once;
5. the forces go to pymunk with ``pymunk.batch.set_space_bodies`` and pymunk integrates the
   step in :attr:`SocialForceParams.substeps` sub-steps with the forces held fixed, resolving
   body contacts (one circle per agent, walls as static segments);
6. positions and velocities come back with ``pymunk.batch.get_space_bodies``.

Control and life cycle (what an environment that drives some agents needs, after JuPedSim):
``step(desired_velocity, controlled)`` drives chosen agents for one step,
:meth:`Simulation.set_desired` / :meth:`Simulation.clear_desired` hold a desired velocity
over steps; :meth:`Simulation.add_agents`, :meth:`Simulation.remove_agents`,
:meth:`Simulation.agents_in_range` and :meth:`Simulation.index_of` work on stable agent ids
(never reused; :attr:`CrowdState.ids` stays sorted).

No Python loop runs over the agents in a step (only over the few that enter or leave).
Everything random comes from the seed: the same scenario, parameters and seed give
bit-identical trajectories however the steps are split across :meth:`Simulation.run` calls.

``Simulation(..., workers=N)`` with ``N > 1`` steps the world in ``N`` worker processes, one
strip each (:mod:`crowdsim.decomposition`); ``workers=1`` (the default) is the one-process
path above, unchanged. Not available with ``workers > 1``: the control hook
(``step(desired_velocity, controlled)`` and :meth:`Simulation.set_desired`); group terms
near a strip border see only the members within the strip's halo. Sources, sinks, periodic
worlds, :meth:`Simulation.add_agents`, :meth:`Simulation.remove_agents` and
:meth:`Simulation.set_state` work. Call :meth:`Simulation.close` (or use ``with``) to stop
the workers early; they also stop when the simulation is garbage-collected or at exit.

>>> from crowdsim.scenarios import make_scenario
>>> sim = Simulation(make_scenario("counterflow", n_agents=20, inflow=False), seed=1)
>>> traj = sim.run(5)
>>> traj.positions.shape
(6, 20, 2)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pymunk
import pymunk.batch as pb

from crowdsim.checks import require_number, whole_numbers
from crowdsim.forces import BodyRows, WallGrid, contact_space, social_force
from crowdsim.params import SocialForceParams
from crowdsim.scenarios import MAX_SPEED, Scenario
from crowdsim.trajectories import Trajectories, TrajectoryRecorder
from crowdsim.world import WALKERS, AgentBatch, RouteTable, first_wall_overlap

MAX_RADIUS = 1.0
"""Largest body radius :meth:`Simulation.add_agents` takes, m (a wheelchair or a pram with
its pusher; the scenarios draw 0.1-0.4 m)."""

if TYPE_CHECKING:
    from crowdsim.decomposition import StripEngine

_BODY = pb.BodyFields


@dataclass
class CrowdState:
    """The present agents as a struct of arrays (SPEC §2), in simulation order.

    Only agents currently in the scene are stored (``active`` is therefore all True; agents
    that left are dropped, agents that enter are appended).

    pos, vel : (n, 2) float64, m and m/s; radius, desired_speed : (n,) m and m/s;
    route, waypoint : (n,) int64; group : (n,) int64, -1 = none; ids : (n,) int64, stable,
    never reused; prominent : (n,) bool; anomaly : (n,) int8; stop_start, stop_end : (n,) s.
    """

    pos: np.ndarray
    vel: np.ndarray
    radius: np.ndarray
    desired_speed: np.ndarray
    route: np.ndarray
    waypoint: np.ndarray
    group: np.ndarray
    ids: np.ndarray
    prominent: np.ndarray
    anomaly: np.ndarray
    stop_start: np.ndarray
    stop_end: np.ndarray

    @property
    def n(self) -> int:
        return len(self.ids)

    @property
    def active(self) -> np.ndarray:
        return np.ones(self.n, dtype=bool)

    def keep(self, mask: np.ndarray) -> None:
        """Keep the rows where ``mask`` ``(n,)`` is True."""
        for name in (*AgentBatch.FIELDS, "ids"):
            setattr(self, name, getattr(self, name)[mask])

    def append(self, batch: AgentBatch, ids: np.ndarray) -> None:
        """Append the agents of ``batch`` with their new ``ids`` ``(len(batch),)``."""
        for name in AgentBatch.FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(batch, name)]))
        self.ids = np.concatenate([self.ids, ids])

    @classmethod
    def empty(cls) -> CrowdState:
        z2, zf, zi = np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)
        return cls(
            z2,
            z2.copy(),
            zf,
            zf.copy(),
            zi,
            zi.copy(),
            zi.copy(),
            zi.copy(),
            np.zeros(0, bool),
            np.zeros(0, np.int8),
            zf.copy(),
            zf.copy(),
        )


class Simulation:
    """A seeded crowd simulation of one scenario.

    Parameters
    ----------
    scenario : Scenario
        What to simulate (see :mod:`crowdsim.scenarios`).
    seed : int
        Seed of every random draw (placement, speeds, arrivals).
    params : SocialForceParams, optional
        Model parameters; defaults to :class:`SocialForceParams`' own: Helbing & Molnár's
        (1995) potentials and strengths, with the departures the README's model table
        measures (``c`` 0.6, ``step_time`` 0.4 s, the self-stopping headway).
    record : bool
        Keep positions of every step for :attr:`trajectories` (turn off for pure speed runs).
    workers : int
        Processes that step the world, ``1 .. os.cpu_count()`` (keyword-only). 1 runs in
        this process; more split the world into strips (:mod:`crowdsim.decomposition`):
        results are deterministic for a given ``workers`` and seed, but differ from those
        of another worker count.

    Attributes
    ----------
    state : CrowdState
        The present agents.
    time : float
        Simulated seconds since the start.
    steps : int
        Steps taken so far.
    """

    def __init__(
        self,
        scenario: Scenario,
        seed: int = 0,
        params: SocialForceParams | None = None,
        record: bool = True,
        *,
        workers: int = 1,
    ) -> None:
        cpus = os.cpu_count() or 1
        if (
            isinstance(workers, bool)
            or not isinstance(workers, (int, np.integer))
            or not 1 <= workers <= cpus
        ):
            raise ValueError(
                f"workers must be an integer in [1, {cpus}] (os.cpu_count()), got {workers!r}"
            )
        self.workers = int(workers)
        self._engine: Any = None
        if not isinstance(scenario, Scenario):
            raise ValueError(f"scenario must be a Scenario, got {type(scenario).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.scenario = scenario
        self.seed = int(seed)
        if params is not None and not isinstance(params, SocialForceParams):
            raise ValueError(f"params must be a SocialForceParams, got {type(params).__name__}")
        self.params = params if params is not None else SocialForceParams()
        build_seq, spawn_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._spawn_rng = np.random.default_rng(spawn_seq)
        setup = scenario.build(np.random.default_rng(build_seq))
        self.world = setup.world
        try:
            self._wall_grid = WallGrid(self.world.walls, self.params.cutoff)
        except ValueError as exc:  # a world too large for memory: name the scenario
            raise ValueError(f"{scenario.name}: {exc}") from None
        self.routes = RouteTable(setup.routes)
        self.sources = setup.sources
        self.info = setup.info
        self.time = 0.0
        self.steps = 0
        self.state = CrowdState.empty()
        self._attrs: dict[str, list[np.ndarray]] = {
            k: [] for k in ("group", "prominent", "anomaly", "radius", "desired_speed")
        }
        self._n_total = 0
        # pymunk body id -> (body, shape); body ids of the agents in state order. Periodic
        # worlds give every agent a kinematic ghost one period away, so that pymunk resolves
        # contacts across the seam x = 0 = period as well.
        self._shapes: dict[int, tuple[pymunk.Body, pymunk.Circle]] = {}
        self._body_ids = np.zeros(0, np.int64)
        self._ghost_ids = np.zeros(0, np.int64)
        self._row_of_ghost = np.zeros(0, np.int64)
        self._space = self._make_space()
        self._rows = BodyRows(self._space)
        self._order_dirty = True
        self._row_of_agent = np.zeros(0, np.int64)
        self._n_rows = 0
        self._recorder = TrajectoryRecorder() if record else None
        # Desired velocities held by set_desired: ids (m,) sorted and velocities (m, 2).
        self._held_ids = np.zeros(0, np.int64)
        self._held_vel = np.zeros((0, 2))
        if self.world.period > 0:  # a scenario may place people past the seam: the state
            setup.agents.pos[:, 0] %= self.world.period  # lives on [0, period) from frame 0
        self._add_agents(setup.agents)
        self._refresh_desired()
        if self.workers > 1:
            self._start_engine()
        else:
            self._sync_order()
        self._record()

    # ------------------------------------------------------------------ public API
    def step(
        self, desired_velocity: np.ndarray | None = None, controlled: np.ndarray | None = None
    ) -> None:
        """Advance the simulation by one time step ``params.dt``.

        Parameters
        ----------
        desired_velocity : (m, 2) float, m/s, optional
            Desired velocities ``u`` of the ``controlled`` agents for this step only (the
            control hook). In the driving term ``(v0_i e_i - v_i) / tau`` [HM95 Eq. 2] the
            agent's ``v0_i e_i`` becomes ``u_i``: its desired speed is ``|u_i|`` and its
            desired direction ``u_i / |u_i|`` (zero for ``u_i = 0``), which also set its
            field of view, headway and speed cap (``1.3 max(|u_i|, 0.5 m/s)``), as if the
            agent had chosen that goal. Everybody else follows the social force as before
            (they see the controlled agents as usual). Overrides :meth:`set_desired` for
            those agents.
        controlled : (m,) int ids or (n,) bool mask over :attr:`state`, optional
            Which agents ``desired_velocity`` drives (ids must be present). ``None`` with a
            ``desired_velocity`` means every present agent, in :attr:`state` order.
        """
        if self._engine is not None:
            self._step_split(desired_velocity, controlled)
            return
        command = self._command(desired_velocity, controlled)
        p = self.params
        self._refresh_desired()
        self._spawn()
        if self._order_dirty:
            self._sync_order()
        e, v0 = self._controlled_desired(*self._desired_cache, command)
        st = self.state
        if self.world.period > 0 and st.n:
            self._place_ghosts()
        if st.n:
            acc = social_force(
                st.pos,
                st.vel,
                st.radius,
                v0,
                e,
                st.group,
                self.world.walls,
                p,
                self.world.period,
                self._wall_grid,
            )
            forces = np.zeros((self._n_rows, 2))
            forces[self._row_of_agent] = acc * p.mass
        # Social forces stay fixed over the step; contacts are resolved in sub-steps so that
        # fast head-on encounters do not sink into each other within one 0.04 s move.
        sub_dt = p.dt / p.substeps
        for _ in range(p.substeps):
            if st.n:
                self._rows.write(_BODY.FORCE, forces)  # pymunk clears forces
            self._space.step(sub_dt)
        self.time = (self.steps + 1) * p.dt
        self.steps += 1
        if st.n:
            self._read_back()
            self._wrap_and_cull()
        self._record()

    # ------------------------------------------------------------------ control hook
    def set_desired(self, ids: np.ndarray, velocity: np.ndarray) -> None:
        """Hold the desired velocity of agents ``ids`` ``(m,)`` at ``velocity`` ``(m, 2)``
        or ``(2,)`` m/s from the next step on, until :meth:`clear_desired` (or until they
        leave); see :meth:`step` for what a desired velocity replaces."""
        if self._engine is not None:
            raise ValueError(_unsupported("set_desired"))
        ids = self._present_ids(ids, "set_desired")
        vel = _desired_velocities(velocity, ids, "set_desired.velocity")
        ids, first = np.unique(ids[::-1], return_index=True)  # the last entry of an id wins
        vel = vel[::-1][first]
        keep = ~np.isin(self._held_ids, ids)
        held_ids = np.concatenate([self._held_ids[keep], ids])
        order = np.argsort(held_ids, kind="stable")
        self._held_ids = held_ids[order]
        self._held_vel = np.concatenate([self._held_vel[keep], vel])[order]

    def clear_desired(self, ids: np.ndarray | None = None) -> None:
        """Let agents ``ids`` ``(m,)`` (all held ones when ``None``) follow the social force
        again."""
        if ids is None:
            keep = np.zeros(len(self._held_ids), dtype=bool)
        else:
            keep = ~np.isin(self._held_ids, _ids_array(ids, "clear_desired.ids"))
        self._held_ids, self._held_vel = self._held_ids[keep], self._held_vel[keep]

    @property
    def held_desired(self) -> tuple[np.ndarray, np.ndarray]:
        """Agents under :meth:`set_desired`: ``(ids (m,) int64 sorted, velocities (m, 2))``;
        agents that left are dropped at the next step."""
        return self._held_ids.copy(), self._held_vel.copy()

    def route_directions(self) -> np.ndarray:
        """Unit directions ``(n, 2)`` each present agent's route points to now (towards the
        nearest point of its current gate), in :attr:`state` order; no side effect."""
        st = self.state
        return self.routes.desired(st.pos, st.route, st.waypoint)[0]

    # ------------------------------------------------------------------ life cycle
    def add_agents(
        self,
        pos: np.ndarray,
        *,
        radius: np.ndarray | float | None = None,
        desired_speed: np.ndarray | float = WALKERS.mean,
        route: np.ndarray | int = 0,
        group: np.ndarray | int = -1,
        vel: np.ndarray | None = None,
        prominent: np.ndarray | bool = False,
    ) -> np.ndarray:
        """Add agents at once (between steps); return their new ids ``(m,)`` int64.

        Ids continue from :attr:`n_total` and are never reused. A body that crosses a wall
        (its centre nearer a wall segment's centre line than its radius) raises
        ``ValueError`` naming the row and the wall: pymunk had pushed it out on either side,
        often outside the walls. A body wholly on the far side of a wall is taken (the world
        has no notion of its walkable area: a station's arrivals walk outside its walls).
        Nothing checks that the new bodies are clear of others (pymunk pushes overlapping
        bodies apart).

        Parameters
        ----------
        pos : (m, 2) float, m
        radius : (m,) or scalar, m; default the middle of the scenario's radius range
        desired_speed : (m,) or scalar, m/s
        route : (m,) or scalar int, index into the scene's routes (starting at its first gate)
        group : (m,) or scalar int, -1 = none
        vel : (m, 2) float, m/s, default zero
        prominent : (m,) or scalar bool, drawn in a distinct colour by the renderer
        """
        pos = np.array(_floats(pos, "add_agents.pos"))
        if pos.ndim != 2 or pos.shape[1] != 2 or not np.isfinite(pos).all():
            raise ValueError(
                f"add_agents.pos must be finite with shape (m, 2), got shape {pos.shape}"
            )
        m = len(pos)
        if radius is None:
            radius = 0.5 * (self.scenario.radius[0] + self.scenario.radius[1])
        radius = _per_agent(radius, m, np.float64, "radius")
        speed = _per_agent(desired_speed, m, np.float64, "desired_speed")
        routes = _per_agent(route, m, np.int64, "route")
        if m and not ((radius > 0).all() and (radius <= MAX_RADIUS).all()):
            raise ValueError(f"add_agents.radius must be in (0, {MAX_RADIUS}] m, got {radius}")
        if m and not ((speed >= 0).all() and (speed <= MAX_SPEED).all()):
            raise ValueError(
                f"add_agents.desired_speed must be in [0, {MAX_SPEED}] m/s, got {speed}"
            )
        self._require_inside(pos, "add_agents.pos")
        self._require_clear_of_walls(pos, radius, "add_agents.pos")
        n_routes = len(self.routes.length)
        if m and not ((routes >= 0).all() and (routes < n_routes).all()):
            raise ValueError(f"add_agents.route must be in [0, {n_routes}), got {routes}")
        batch = AgentBatch(
            pos=pos,
            vel=np.zeros((m, 2))
            if vel is None
            else _desired_velocities(vel, np.arange(m), "add_agents.vel", "row"),
            radius=radius,
            desired_speed=speed,
            route=routes,
            waypoint=np.zeros(m, np.int64),
            group=_per_agent(group, m, np.int64, "group"),
            prominent=_per_agent(prominent, m, bool, "prominent"),
            anomaly=np.zeros(m, np.int8),
            stop_start=np.full(m, np.inf),
            stop_end=np.full(m, np.inf),
        )
        if self.world.period > 0:
            batch.pos[:, 0] %= self.world.period
        batch.waypoint = self.routes.desired(batch.pos, batch.route, batch.waypoint)[1]
        first = self._n_total
        self._add_agents(batch)
        return np.arange(first, self._n_total, dtype=np.int64)

    def _require_inside(self, pos: np.ndarray, name: str) -> None:
        """Refuse positions beyond the world's bounds by more than the 1 m after which a step
        removes an agent (x wraps in a periodic world)."""
        xmin, ymin, xmax, ymax = self.world.bounds
        x = pos[:, 0] % self.world.period if self.world.period > 0 else pos[:, 0]
        out = (x < xmin - 1) | (x > xmax + 1) | (pos[:, 1] < ymin - 1) | (pos[:, 1] > ymax + 1)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise ValueError(
                f"{name}[{i}] = ({pos[i, 0]:g}, {pos[i, 1]:g}) m lies outside the world "
                f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g} m; a step removes agents more "
                "than 1 m beyond it)"
            )

    def _require_clear_of_walls(self, pos: np.ndarray, radius: np.ndarray, name: str) -> None:
        """Refuse a body that crosses a wall (its centre nearer a wall's centre line than its
        radius): pymunk pushes it out on either side, outside the walkable area as often as
        not. A periodic world checks x on ``[0, period)``, where the body will be."""
        at = pos
        if self.world.period > 0:
            at = np.column_stack([pos[:, 0] % self.world.period, pos[:, 1]])
        hit = first_wall_overlap(at, radius, self.world.walls)
        if hit is not None:
            i, j, d = hit
            x0, y0, x1, y1 = self.world.walls[j, :4]
            raise ValueError(
                f"{name}[{i}] = ({pos[i, 0]:g}, {pos[i, 1]:g}) m overlaps the wall from "
                f"({x0:g}, {y0:g}) to ({x1:g}, {y1:g}) m: its centre is {d:.3f} m from it, "
                f"less than its radius {radius[i]:g} m"
            )

    def remove_agents(self, ids: np.ndarray) -> None:
        """Remove the present agents ``ids`` ``(m,)`` at once (between steps: from the next
        step on they are gone, as after JuPedSim's ``mark_agent_for_removal``)."""
        ids = self._present_ids(ids, "remove_agents")
        if len(ids):
            self._remove(np.isin(self.state.ids, ids))

    def index_of(self, ids: np.ndarray, strict: bool = True) -> np.ndarray:
        """Rows ``(m,)`` int64 of agents ``ids`` ``(m,)`` in :attr:`state`.

        Absent ids raise ``ValueError`` (naming them) when ``strict``, else give -1.
        :attr:`state` keeps its ids sorted, so this is a binary search.
        """
        ids = _ids_array(ids, "index_of.ids")
        present = self.state.ids
        rows = np.minimum(np.searchsorted(present, ids), max(len(present) - 1, 0))
        found = (present[rows] == ids) if len(present) else np.zeros(len(ids), dtype=bool)
        if strict and not found.all():
            raise ValueError(f"agent id(s) not present: {ids[~found][:10].tolist()}")
        return np.where(found, rows, -1).astype(np.int64)

    def agents_in_range(self, point: np.ndarray, radius: float) -> np.ndarray:
        """Ids ``(k,)`` int64, sorted, of the present agents whose centre lies within
        ``radius`` metres of ``point`` ``(2,)`` (across the seam of a periodic world).

        One vectorised pass over the agents, O(n): cheaper than building a k-d tree for
        a single query.
        """
        point = _floats(point, "agents_in_range.point")
        if point.shape != (2,) or not np.isfinite(point).all():
            raise ValueError(f"agents_in_range.point must be two finite numbers, got {point}")
        require_number("agents_in_range", "radius", radius, lo=0)
        d = self.state.pos - point
        if self.world.period > 0:
            d[:, 0] -= self.world.period * np.round(d[:, 0] / self.world.period)
        return self.state.ids[np.hypot(d[:, 0], d[:, 1]) <= radius]

    def set_state(self, pos: np.ndarray | None = None, vel: np.ndarray | None = None) -> None:
        """Overwrite positions ``(n, 2)`` m and/or velocities ``(n, 2)`` m/s of the present
        agents (in :attr:`state` order), e.g. to build a hand-made scene.

        Unlike :meth:`add_agents`, nothing checks the walls: a scene may press a body into
        one on purpose.
        """
        n = self.state.n
        given = {}
        for name, value in (("pos", pos), ("vel", vel)):
            if value is None:
                continue
            value = np.array(_floats(value, f"set_state.{name}"))
            if value.shape != (n, 2):
                raise ValueError(f"{name} must have shape ({n}, 2), got {value.shape}")
            if not np.isfinite(value).all():
                raise ValueError(f"{name} must be finite")
            if name == "pos":
                self._require_inside(value, "set_state.pos")
            else:  # a body faster than this leaves the world within a step, unseen
                _desired_velocities(value, self.state.ids, "set_state.vel")
            given[name] = value
        for name, value in given.items():  # both checked before either is set
            setattr(self.state, name, value)
        if self.world.period > 0:
            self.state.pos[:, 0] %= self.world.period
        if self._engine is not None:
            self._engine_write(self.state.ids, self.state.pos, self.state.vel)
            return
        if self._order_dirty:
            self._sync_order()
        rows = self._rows.read(_BODY.POSITION | _BODY.VELOCITY).copy()
        rows[self._row_of_agent, :2] = self.state.pos
        rows[self._row_of_agent, 2:] = self.state.vel
        self._rows.write(_BODY.POSITION | _BODY.VELOCITY, rows)
        self._refresh_desired()

    def run(self, n_steps: int, progress: bool = False) -> Trajectories | None:
        """Take ``n_steps`` steps; return all recorded trajectories (None if not recording)."""
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 0:
            raise ValueError(f"steps must be a non-negative integer, got {n_steps!r}")
        it = range(int(n_steps))
        if progress:
            from crowdsim.progress import progress_bar

            it = progress_bar(it, desc=f"simulating {self.scenario.name}", unit="step")
        for _ in it:
            self.step()
        return self.trajectories if self._recorder is not None else None

    @property
    def engine(self) -> StripEngine | None:
        """The worker processes' :class:`~crowdsim.decomposition.StripEngine` with
        ``workers > 1`` (its ``timing()`` says where a step's time goes), else ``None``."""
        return self._engine

    @property
    def worker_pids(self) -> list[int]:
        """Process ids of the worker processes, by strip (empty with ``workers=1``)."""
        return [] if self._engine is None else self._engine.pids

    @property
    def n_total(self) -> int:
        """Agents that ever existed (ids run from 0 to ``n_total - 1``)."""
        return self._n_total

    @property
    def trajectories(self) -> Trajectories:
        """Every recorded row so far: ``(steps + 1, n_total, 2)`` positions."""
        if self._recorder is None:
            raise ValueError("this simulation was created with record=False")
        attrs = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in self._attrs.items()}
        return self._recorder.finish(self._n_total, self.params.dt, attrs, self.meta())

    def meta(self) -> dict[str, Any]:
        """Scenario, seed, parameters, steps, versions and scenario info (JSON-ready)."""
        from crowdsim import __version__

        return {
            "scenario": self.scenario.to_dict(),
            "seed": self.seed,
            "params": self.params.to_dict(),
            "steps": self.steps,
            "versions": {
                "crowdsim": __version__,
                "pymunk": pymunk.version,
                "numpy": np.__version__,
            },
            "info": _jsonable(self.info),
            # a periodic x axis: Trajectories.velocities takes a step across the seam the
            # short way round (it had read up to 417 m/s there)
            **({"period": float(self.world.period)} if self.world.period > 0 else {}),
            **({"workers": self.workers} if self.workers > 1 else {}),
        }

    # ------------------------------------------------------------------ internals
    def _present_ids(self, ids: np.ndarray, where: str) -> np.ndarray:
        ids = _ids_array(ids, f"{where}.ids")
        self.index_of(ids)  # raises on absent ids
        return ids

    def _command(
        self, desired_velocity: np.ndarray | None, controlled: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The one-step command as ``(ids (m,), velocities (m, 2))``, resolved against the
        agents present before the step (some may leave at its start)."""
        if desired_velocity is None:
            if controlled is not None:
                raise ValueError("step: controlled was given without desired_velocity")
            return None
        st = self.state
        if controlled is None:
            ids = st.ids
        else:
            c = np.asarray(controlled)
            if c.dtype == bool:
                if c.shape != (st.n,):
                    raise ValueError(
                        f"step.controlled as a mask must have shape ({st.n},), got {c.shape}"
                    )
                ids = st.ids[c]
            else:
                ids = self._present_ids(c, "step.controlled")
        vel = _desired_velocities(desired_velocity, ids, "step.desired_velocity")
        if len(ids) > 1 and not (ids[1:] > ids[:-1]).all() and len(np.unique(ids)) != len(ids):
            raise ValueError("step.controlled lists an agent more than once")
        return ids, vel

    def _controlled_desired(
        self, e: np.ndarray, v0: np.ndarray, command: tuple[np.ndarray, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(e, v0)`` with the rows of held and commanded agents set to ``u / |u|, |u|``."""
        if len(self._held_ids):  # forget agents that have left
            live = self.index_of(self._held_ids, strict=False) >= 0
            self._held_ids, self._held_vel = self._held_ids[live], self._held_vel[live]
        ids, vel = self._held_ids, self._held_vel
        if command is not None:
            free = ~np.isin(ids, command[0])
            ids = np.concatenate([ids[free], command[0]])
            vel = np.concatenate([vel[free], command[1]])
        if len(ids) == 0:
            return e, v0
        rows = self.index_of(ids, strict=False)
        live = rows >= 0
        rows, vel = rows[live], vel[live]
        speed = np.hypot(vel[:, 0], vel[:, 1])
        e, v0 = e.copy(), v0.copy()
        e[rows] = np.divide(vel, speed[:, None], out=np.zeros_like(vel), where=speed[:, None] > 0)
        v0[rows] = speed
        return e, v0

    def _make_space(self) -> pymunk.Space:
        # Broad phase: pymunk's default bounding-box tree. Measured on the benchmark corridor
        # it beats the spatial hash (cells of one body diameter, 10 n cells) 3.5x at 10k and
        # 100k agents (0.6 vs 2.1 ms and 19 vs 70 ms a sub-step).
        return contact_space(self.params, self.world.walls)

    def _add_body(self, body: pymunk.Body, x: float, y: float, radius: float) -> int:
        body.position = (x, y)
        shape = pymunk.Circle(body, radius)
        shape.friction = self.params.friction
        shape.elasticity = 0.0
        self._space.add(body, shape)
        self._shapes[body.id] = (body, shape)
        return body.id

    def _add_agents(self, batch: AgentBatch) -> None:
        n = len(batch)
        if n == 0:
            return
        ids = np.arange(self._n_total, self._n_total + n, dtype=np.int64)
        self._n_total += n
        if self.workers == 1:
            self._add_bodies(batch)
        elif self._engine is not None:  # the workers learn them at the next step
            from crowdsim.decomposition import STATIC_FIELDS

            self._engine.add(ids, {f: getattr(batch, f) for f in STATIC_FIELDS})
        self.state.append(batch, ids)
        self._attrs["group"].append(batch.group)
        self._attrs["prominent"].append(batch.prominent)
        self._attrs["anomaly"].append(batch.anomaly)
        self._attrs["radius"].append(batch.radius)
        self._attrs["desired_speed"].append(batch.desired_speed)
        self._order_dirty = True

    def _add_bodies(self, batch: AgentBatch) -> None:
        """One pymunk body per agent of ``batch`` (and a ghost in a periodic world)."""
        n = len(batch)
        body_ids = np.empty(n, np.int64)
        ghost_ids = np.empty(n, np.int64)
        for k in range(n):  # only the entering agents
            x, y, r = float(batch.pos[k, 0]), float(batch.pos[k, 1]), float(batch.radius[k])
            body = pymunk.Body(self.params.mass, float("inf"))
            body.velocity = (float(batch.vel[k, 0]), float(batch.vel[k, 1]))
            body_ids[k] = self._add_body(body, x, y, r)
            if self.world.period > 0:
                ghost = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
                ghost_ids[k] = self._add_body(ghost, x + self.world.period, y, r)
        self._body_ids = np.concatenate([self._body_ids, body_ids])
        if self.world.period > 0:
            self._ghost_ids = np.concatenate([self._ghost_ids, ghost_ids])

    def _remove(self, mask: np.ndarray) -> None:
        """Drop the agents where ``mask`` is True (they left the scene)."""
        if self.workers > 1:
            if self._engine is not None:
                sh = self._engine.shared
                sh.alive[self._engine.current(self.steps), self.state.ids[mask]] = 0
            self.state.keep(~mask)
            return
        gone = [self._body_ids[mask]]
        if self.world.period > 0:
            gone.append(self._ghost_ids[mask])
            self._ghost_ids = self._ghost_ids[~mask]
        for body_id in np.concatenate(gone):  # only the leaving agents
            self._space.remove(*self._shapes.pop(int(body_id)))
        self._body_ids = self._body_ids[~mask]
        self.state.keep(~mask)
        self._order_dirty = True

    def _sync_order(self) -> None:
        """Map pymunk's body iteration order to ours (it changes when bodies are removed)."""
        if self.world.period > 0:
            self._n_rows, (self._row_of_agent, self._row_of_ghost) = self._rows.rows_of(
                self._body_ids, self._ghost_ids
            )
        else:
            self._n_rows, (self._row_of_agent,) = self._rows.rows_of(self._body_ids)
        self._order_dirty = False

    def _read_back(self) -> None:
        rows = self._rows.read(_BODY.POSITION | _BODY.VELOCITY)
        mine = rows[self._row_of_agent]
        self.state.pos = mine[:, :2].copy()
        self.state.vel = mine[:, 2:].copy()
        if not np.isfinite(mine).all():
            raise FloatingPointError(
                f"non-finite agent state at step {self.steps}; reduce dt (now {self.params.dt} "
                "s) or the force strengths (--param)"
            )

    def _wrap_and_cull(self) -> None:
        st = self.state
        period = self.world.period
        if period > 0:
            out = (st.pos[:, 0] < 0) | (st.pos[:, 0] >= period)
            if out.any():
                st.pos[:, 0] %= period
                self.set_state(pos=st.pos)
        xmin, ymin, xmax, ymax = self.world.bounds
        gone = (
            (st.pos[:, 0] < xmin - 1)
            | (st.pos[:, 0] > xmax + 1)
            | (st.pos[:, 1] < ymin - 1)
            | (st.pos[:, 1] > ymax + 1)
        )
        if period > 0:
            gone &= (st.pos[:, 1] < ymin - 1) | (st.pos[:, 1] > ymax + 1)
        if gone.any():
            self._remove(gone)

    def _place_ghosts(self) -> None:
        """Put each ghost one period away from its agent, on the side nearer the seam."""
        rows = self._rows.read(_BODY.POSITION | _BODY.VELOCITY).copy()
        st, period = self.state, self.world.period
        shift = np.where(st.pos[:, 0] < period / 2, period, -period)
        rows[self._row_of_ghost, 0] = st.pos[:, 0] + shift
        rows[self._row_of_ghost, 1] = st.pos[:, 1]
        rows[self._row_of_ghost, 2:] = st.vel
        self._rows.write(_BODY.POSITION | _BODY.VELOCITY, rows)

    def _refresh_desired(self) -> None:
        """Desired directions and speeds; agents past their final gate leave here."""
        st = self.state
        e, wp, done = self.routes.desired(st.pos, st.route, st.waypoint)
        st.waypoint = wp
        if done.any():
            self._remove(done)
            e = e[~done]
        st = self.state
        standing = (self.time >= st.stop_start) & (self.time < st.stop_end)
        v0 = np.where(standing, 0.0, st.desired_speed)
        self._desired_cache = (e, v0)

    def _spawn(self) -> None:
        if not self.sources:
            return
        rng = self._spawn_rng
        new: list[AgentBatch] = []
        for src in self.sources:
            if not (src.start <= self.time < src.stop) or src.rate <= 0:
                continue
            k = int(rng.poisson(src.rate * self.params.dt))
            if k == 0:
                continue
            x0, y0, x1, y1 = src.region
            pos = np.column_stack([rng.uniform(x0, x1, k), rng.uniform(y0, y1, k)])
            radius = rng.uniform(self.scenario.radius[0], self.scenario.radius[1], k)
            ok = self._free(pos, radius, new)
            if not ok.any():
                continue
            pos, radius = pos[ok], radius[ok]
            v0 = src.speeds.sample(rng, len(pos))
            batch = AgentBatch.create(
                pos, radius, v0, src.route, rng, self.scenario.prominent_fraction
            )
            batch.vel = np.asarray(src.heading, float)[None, :] * v0[:, None] * 0.5
            new.append(batch)
        if new:
            batch = AgentBatch.concat(new)
            self._add_agents(batch)
            e_new, wp, _ = self.routes.desired(batch.pos, batch.route, batch.waypoint)
            self.state.waypoint[-len(batch) :] = wp
            e, v0 = self._desired_cache
            self._desired_cache = (np.vstack([e, e_new]), np.concatenate([v0, batch.desired_speed]))

    def _free(self, pos: np.ndarray, radius: np.ndarray, pending: list[AgentBatch]) -> np.ndarray:
        """True where a candidate overlaps nobody (present, pending, or an earlier candidate)."""
        lo, hi = pos.min(axis=0) - 1.0, pos.max(axis=0) + 1.0
        # each group cut to the candidates' box before joining, in x and then the survivors
        # in y: the same rows in the same order as cutting the joined groups, without
        # copying every present agent for each source every step
        others = [(self.state.pos, self.state.radius)] + [(b.pos, b.radius) for b in pending]
        in_x = [(q[:, 0] >= lo[0]) & (q[:, 0] <= hi[0]) for q, _ in others]
        op = np.concatenate([q[m] for (q, _), m in zip(others, in_x, strict=True)])
        orad = np.concatenate([r[m] for (_, r), m in zip(others, in_x, strict=True)])
        in_y = (op[:, 1] >= lo[1]) & (op[:, 1] <= hi[1])
        op, orad = op[in_y], orad[in_y]
        ok = np.ones(len(pos), dtype=bool)
        if len(op):
            d = np.hypot(pos[:, None, 0] - op[None, :, 0], pos[:, None, 1] - op[None, :, 1])
            ok &= np.all(d > radius[:, None] + orad[None, :] + 0.05, axis=1)
        for i in range(1, len(pos)):  # candidates among themselves (a handful per step)
            d = np.hypot(*(pos[:i] - pos[i]).T)
            ok[i] &= bool(np.all((d > radius[:i] + radius[i] + 0.05) | ~ok[:i]))
        return ok

    # ------------------------------------------------------------------ workers > 1
    def _start_engine(self) -> None:
        from crowdsim.decomposition import STATIC_FIELDS, StripEngine

        st, n = self.state, self._n_total
        by_id: dict[str, np.ndarray] = {}
        for f in (*STATIC_FIELDS, "pos", "vel", "waypoint"):
            rows = getattr(st, f)
            by_id[f] = np.zeros((n, *rows.shape[1:]), rows.dtype)
            by_id[f][st.ids] = rows
        alive = np.zeros(n, bool)
        alive[st.ids] = True
        capacity = 2 * n + 1024 if self.sources else n
        self._engine = StripEngine(
            self.world,
            self.routes,
            self.params,
            self.workers,
            {f: by_id[f] for f in STATIC_FIELDS},
            by_id["pos"],
            by_id["vel"],
            by_id["waypoint"],
            alive,
            capacity,
        )
        self._n_pushed = n

    def _engine_write(self, ids: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> None:
        """Overwrite agents' positions and velocities in the state the next step reads."""
        sh, cur = self._engine.shared, self._engine.current(self.steps)
        sh.pos[cur, ids], sh.vel[cur, ids] = pos, vel

    def _step_split(self, desired_velocity: Any, controlled: Any) -> None:
        """One step over the worker processes (see :mod:`crowdsim.decomposition`)."""
        if desired_velocity is not None or controlled is not None:
            raise ValueError(_unsupported("step(desired_velocity, controlled)"))
        if not self._engine.procs:
            raise ValueError("this simulation's workers were stopped (close() or a failure)")
        st = self.state
        if self.sources:  # _spawn extends it
            self._desired_cache = (np.zeros((st.n, 2)), np.zeros(st.n))
        self._spawn()
        eng, st = self._engine, self.state
        if self._n_total > self._n_pushed:  # entered since the last step: rows at the end
            new = st.ids >= self._n_pushed
            ids = st.ids[new]
            cur = eng.current(self.steps)
            self._engine_write(ids, st.pos[new], st.vel[new])
            eng.shared.wp[cur, ids] = st.waypoint[new]
            eng.shared.alive[cur, ids] = 1
            self._n_pushed = self._n_total
        eng.step(self.steps, self.time)
        self.time = (self.steps + 1) * self.params.dt
        self.steps += 1
        pos, vel, wp, present = eng.gather(self.steps, st.ids)
        if not present.all():
            st.keep(present)
            pos, vel, wp = pos[present], vel[present], wp[present]
        st.pos, st.vel, st.waypoint = pos, vel, wp
        self._record()

    def close(self) -> None:
        """Stop the worker processes and free their shared memory (``workers > 1``; a
        no-op otherwise). The simulation cannot step after this."""
        if self._engine is not None:
            self._engine.close()

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _record(self) -> None:
        if self._recorder is not None:
            self._recorder.record(self.state.ids, self.state.pos)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _unsupported(feature: str) -> str:
    return f"{feature} is not supported with workers > 1; use workers=1"


def _ids_array(ids: Any, where: str) -> np.ndarray:
    ids = np.asarray(ids)
    if ids.ndim == 0:
        ids = ids.reshape(1)
    if ids.ndim != 1 or (len(ids) and not np.issubdtype(ids.dtype, np.integer)):
        raise ValueError(f"{where} must be a 1-d array of integer agent ids, got {ids!r}")
    return ids.astype(np.int64)


def _floats(value: Any, where: str) -> np.ndarray:
    """``value`` as a float64 array, or a ``ValueError`` naming ``where`` for text, complex
    numbers or a ragged list (numpy's own error does not name the argument, and it casts a
    complex number to its real part with only a warning)."""
    try:
        raw = np.asarray(value)
        if raw.dtype.kind not in "biufO":
            raise TypeError
        return np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        what = (
            f"{value.dtype} of shape {value.shape}"
            if isinstance(value, np.ndarray)
            else f"{value!r:.80}"
        )
        raise ValueError(f"{where} must be numbers, got {what}") from None


def _velocities(value: Any, m: int, where: str) -> np.ndarray:
    """``(m, 2)`` float64 finite velocities from ``(m, 2)`` or one ``(2,)`` row."""
    v = _floats(value, where)
    if v.shape == (2,):
        v = np.broadcast_to(v, (m, 2))
    if v.shape != (m, 2):
        raise ValueError(f"{where} must have shape ({m}, 2) or (2,), got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError(f"{where} must be finite")
    return np.array(v)


def _desired_velocities(value: Any, ids: np.ndarray, where: str, what: str = "agent") -> np.ndarray:
    """:func:`_velocities` of the agents ``ids`` (for new agents, their rows: ``what`` names
    which), each at most :data:`MAX_SPEED` (a faster command or start would throw the agent
    out of the world within a few steps)."""
    vel = _velocities(value, len(ids), where)
    fast = np.hypot(vel[:, 0], vel[:, 1]) > MAX_SPEED
    if fast.any():
        raise ValueError(
            f"{where} must be at most {MAX_SPEED} m/s, got "
            f"{vel[fast][0].tolist()} for {what} {int(ids[fast][0])}"
        )
    return vel


def _per_agent(value: Any, m: int, dtype: Any, name: str) -> np.ndarray:
    """A scalar or ``(m,)`` value as an ``(m,)`` array of ``dtype``: numbers for a float
    field, whole numbers for an integer one, booleans for a flag (never cast in silence)."""
    v = np.asarray(value)
    if v.ndim == 0:
        v = np.broadcast_to(v, (m,))
    if v.shape != (m,):
        raise ValueError(f"add_agents.{name} must be a scalar or have shape ({m},), got {v.shape}")
    kind = np.dtype(dtype).kind
    if kind == "b":
        ok = v.dtype.kind == "b"
    elif kind in "iu":
        ok = v.dtype.kind == "b" or whole_numbers(v)
    else:
        ok = v.dtype.kind in "biuf"
    if not ok:
        what = {"b": "booleans", "i": "whole numbers", "u": "whole numbers"}.get(kind, "numbers")
        raise ValueError(f"add_agents.{name} must be {what}, got {value!r}")
    return np.array(v, dtype=dtype)
