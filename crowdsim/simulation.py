"""The crowd simulation: social forces (numba) + contacts (pymunk).

One step:

1. routes give each agent its desired direction ``e_i``; agents past their last gate leave;
2. sources add agents (Poisson, only where they do not overlap anybody);
3. :func:`crowdsim.forces.social_force` computes every agent's acceleration at once;
4. the forces go to pymunk with ``pymunk.batch.set_space_bodies`` and pymunk integrates one
   step, resolving body contacts (one circle per agent, walls as static segments);
5. positions and velocities come back with ``pymunk.batch.get_space_bodies``.

No Python loop runs over the agents in a step (only over the few that enter or leave).
Everything random comes from the seed: the same scenario, parameters and seed give
bit-identical trajectories however the steps are split across :meth:`Simulation.run` calls.

>>> from crowdsim.scenarios import make_scenario
>>> sim = Simulation(make_scenario("counterflow", n_agents=20, inflow=False), seed=1)
>>> traj = sim.run(5)
>>> traj.positions.shape
(6, 20, 2)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pymunk
import pymunk.batch as pb

from crowdsim.forces import WallGrid, social_force
from crowdsim.params import SocialForceParams
from crowdsim.scenarios import Scenario
from crowdsim.trajectories import Trajectories, TrajectoryRecorder
from crowdsim.world import AgentBatch, RouteTable

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

    _FROM_BATCH = {"pos": "pos", "vel": "vel", "radius": "radius", "desired_speed": "v0",
                   "route": "route", "waypoint": "wp", "group": "group",
                   "prominent": "prominent", "anomaly": "anomaly", "stop_start": "stop_start",
                   "stop_end": "stop_end"}

    def keep(self, mask: np.ndarray) -> None:
        for name in (*self._FROM_BATCH, "ids"):
            setattr(self, name, getattr(self, name)[mask])

    def append(self, batch: AgentBatch, ids: np.ndarray) -> None:
        for name, src in self._FROM_BATCH.items():
            setattr(self, name, np.concatenate([getattr(self, name), getattr(batch, src)]))
        self.ids = np.concatenate([self.ids, ids])

    @classmethod
    def empty(cls) -> CrowdState:
        z2, zf, zi = np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)
        return cls(z2, z2.copy(), zf, zf.copy(), zi, zi.copy(), zi.copy(), zi.copy(),
                   np.zeros(0, bool), np.zeros(0, np.int8), zf.copy(), zf.copy())


class Simulation:
    """A seeded crowd simulation of one scenario.

    Parameters
    ----------
    scenario : Scenario
        What to simulate (see :mod:`crowdsim.scenarios`).
    seed : int
        Seed of every random draw (placement, speeds, arrivals).
    params : SocialForceParams, optional
        Model parameters; defaults to Helbing & Molnár (1995) values.
    record : bool
        Keep positions of every step for :attr:`trajectories` (turn off for pure speed runs).

    Attributes
    ----------
    state : CrowdState
        The present agents.
    time : float
        Simulated seconds since the start.
    steps : int
        Steps taken so far.
    """

    def __init__(self, scenario: Scenario, seed: int = 0,
                 params: SocialForceParams | None = None, record: bool = True) -> None:
        if not isinstance(scenario, Scenario):
            raise ValueError(f"scenario must be a Scenario, got {type(scenario).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.scenario = scenario
        self.seed = int(seed)
        self.params = params if params is not None else SocialForceParams()
        build_seq, spawn_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._spawn_rng = np.random.default_rng(spawn_seq)
        setup = scenario.build(np.random.default_rng(build_seq))
        self.world = setup.world
        self._wall_grid = WallGrid(self.world.walls, self.params.cutoff)
        self.routes = RouteTable(setup.routes)
        self.sources = setup.sources
        self.info = setup.info
        self.time = 0.0
        self.steps = 0
        self.state = CrowdState.empty()
        self._attrs: dict[str, list[np.ndarray]] = {k: [] for k in
                                                     ("group", "prominent", "anomaly", "radius",
                                                      "desired_speed")}
        self._n_total = 0
        # pymunk body id -> (body, shape); body ids of the agents in state order. Periodic
        # worlds give every agent a kinematic ghost one period away, so that pymunk resolves
        # contacts across the seam x = 0 = period as well.
        self._shapes: dict[int, tuple[pymunk.Body, pymunk.Circle]] = {}
        self._body_ids = np.zeros(0, np.int64)
        self._ghost_ids = np.zeros(0, np.int64)
        self._row_of_ghost = np.zeros(0, np.int64)
        self._space = self._make_space()
        self._order_dirty = True
        self._row_of_agent = np.zeros(0, np.int64)
        self._n_rows = 0
        self._recorder = TrajectoryRecorder() if record else None
        self._add_agents(setup.agents)
        self._refresh_desired()
        self._sync_order()
        self._record()

    # ------------------------------------------------------------------ public API
    def step(self) -> None:
        """Advance the simulation by one time step ``params.dt``."""
        p = self.params
        self._refresh_desired()
        self._spawn()
        if self._order_dirty:
            self._sync_order()
        e, v0 = self._desired_cache
        st = self.state
        if self.world.period > 0 and st.n:
            self._place_ghosts()
        if st.n:
            acc = social_force(st.pos, st.vel, st.radius, v0, e, st.group, self.world.walls, p,
                               self.world.period, self._wall_grid)
            forces = np.zeros((self._n_rows, 2))
            forces[self._row_of_agent] = acc * p.mass
            buf = pb.Buffer()
            buf.set_float_buf(forces.ravel())
        # Social forces stay fixed over the step; contacts are resolved in sub-steps so that
        # fast head-on encounters do not sink into each other within one 0.04 s move.
        sub_dt = p.dt / p.contact_substeps
        for _ in range(int(p.contact_substeps)):
            if st.n:
                pb.set_space_bodies(self._space, _BODY.FORCE, buf)  # pymunk clears forces
            self._space.step(sub_dt)
        self.time = (self.steps + 1) * p.dt
        self.steps += 1
        if st.n:
            self._read_back()
            self._wrap_and_cull()
        self._record()

    def set_state(self, pos: np.ndarray | None = None, vel: np.ndarray | None = None) -> None:
        """Overwrite positions ``(n, 2)`` m and/or velocities ``(n, 2)`` m/s of the present
        agents (in :attr:`state` order), e.g. to build a hand-made scene."""
        n = self.state.n
        for name, value in (("pos", pos), ("vel", vel)):
            if value is None:
                continue
            value = np.array(value, dtype=np.float64)
            if value.shape != (n, 2):
                raise ValueError(f"{name} must have shape ({n}, 2), got {value.shape}")
            if not np.isfinite(value).all():
                raise ValueError(f"{name} must be finite")
            setattr(self.state, name, value)
        if self.world.period > 0:
            self.state.pos[:, 0] %= self.world.period
        if self._order_dirty:
            self._sync_order()
        buf = pb.Buffer()
        pb.get_space_bodies(self._space, _BODY.POSITION | _BODY.VELOCITY, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4).copy()
        rows[self._row_of_agent, :2] = self.state.pos
        rows[self._row_of_agent, 2:] = self.state.vel
        out = pb.Buffer()
        out.set_float_buf(rows.ravel())
        pb.set_space_bodies(self._space, _BODY.POSITION | _BODY.VELOCITY, out)
        self._refresh_desired()

    def run(self, n_steps: int, progress: bool = False) -> Trajectories | None:
        """Take ``n_steps`` steps; return all recorded trajectories (None if not recording)."""
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 0:
            raise ValueError(f"steps must be a non-negative integer, got {n_steps!r}")
        it = range(int(n_steps))
        if progress:
            from tqdm import tqdm

            it = tqdm(it, desc=f"simulating {self.scenario.name}", unit="step", leave=False)
        for _ in it:
            self.step()
        return self.trajectories if self._recorder is not None else None

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
        import pymunk as _pm

        from crowdsim import __version__

        return {"scenario": self.scenario.to_dict(), "seed": self.seed,
                "params": self.params.to_dict(), "steps": self.steps,
                "versions": {"crowdsim": __version__, "pymunk": _pm.version,
                             "numpy": np.__version__},
                "info": _jsonable(self.info)}

    # ------------------------------------------------------------------ internals
    def _make_space(self) -> pymunk.Space:
        p = self.params
        space = pymunk.Space()
        space.iterations = int(p.solver_iterations)
        space.collision_slop = p.contact_slop
        space.collision_bias = p.contact_bias
        space.damping = 1.0
        # Broad phase: pymunk's default bounding-box tree. Measured on the benchmark corridor
        # it beats the spatial hash (cells of one body diameter, 10 n cells) 3.5x at 10k and
        # 100k agents (0.6 vs 2.1 ms and 19 vs 70 ms a sub-step).
        for x0, y0, x1, y1, th in self.world.walls:
            seg = pymunk.Segment(space.static_body, (x0, y0), (x1, y1), th)
            seg.friction = p.friction
            seg.elasticity = 0.0
            space.add(seg)
        return space

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
        self.state.append(batch, ids)
        self._attrs["group"].append(batch.group)
        self._attrs["prominent"].append(batch.prominent)
        self._attrs["anomaly"].append(batch.anomaly)
        self._attrs["radius"].append(batch.radius)
        self._attrs["desired_speed"].append(batch.v0)
        self._order_dirty = True

    def _remove(self, mask: np.ndarray) -> None:
        """Drop the agents where ``mask`` is True (they left the scene)."""
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
        buf = pb.Buffer()
        pb.get_space_bodies(self._space, _BODY.BODY_ID, buf)
        space_ids = np.frombuffer(buf.int_buf(), dtype=np.uintp).astype(np.int64)
        self._n_rows = len(space_ids)
        sorter = np.argsort(space_ids)
        self._row_of_agent = sorter[np.searchsorted(space_ids, self._body_ids, sorter=sorter)]
        if self.world.period > 0:
            self._row_of_ghost = sorter[np.searchsorted(space_ids, self._ghost_ids,
                                                        sorter=sorter)]
        self._order_dirty = False

    def _read_back(self) -> None:
        buf = pb.Buffer()
        pb.get_space_bodies(self._space, _BODY.POSITION | _BODY.VELOCITY, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4)
        mine = rows[self._row_of_agent]
        self.state.pos = mine[:, :2].copy()
        self.state.vel = mine[:, 2:].copy()
        if not np.isfinite(mine).all():
            raise FloatingPointError(f"non-finite agent state at step {self.steps}; "
                                     f"reduce dt (now {self.params.dt} s)")

    def _wrap_and_cull(self) -> None:
        st = self.state
        period = self.world.period
        if period > 0:
            out = (st.pos[:, 0] < 0) | (st.pos[:, 0] >= period)
            if out.any():
                st.pos[:, 0] %= period
                self.set_state(pos=st.pos)
        xmin, ymin, xmax, ymax = self.world.bounds
        gone = ((st.pos[:, 0] < xmin - 1) | (st.pos[:, 0] > xmax + 1)
                | (st.pos[:, 1] < ymin - 1) | (st.pos[:, 1] > ymax + 1))
        if period > 0:
            gone &= (st.pos[:, 1] < ymin - 1) | (st.pos[:, 1] > ymax + 1)
        if gone.any():
            self._remove(gone)

    def _place_ghosts(self) -> None:
        """Put each ghost one period away from its agent, on the side nearer the seam."""
        buf = pb.Buffer()
        pb.get_space_bodies(self._space, _BODY.POSITION | _BODY.VELOCITY, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4).copy()
        st, period = self.state, self.world.period
        shift = np.where(st.pos[:, 0] < period / 2, period, -period)
        rows[self._row_of_ghost, 0] = st.pos[:, 0] + shift
        rows[self._row_of_ghost, 1] = st.pos[:, 1]
        rows[self._row_of_ghost, 2:] = st.vel
        out = pb.Buffer()
        out.set_float_buf(rows.ravel())
        pb.set_space_bodies(self._space, _BODY.POSITION | _BODY.VELOCITY, out)

    def _refresh_desired(self) -> tuple[np.ndarray, np.ndarray]:
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
        return e, v0

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
            batch = AgentBatch.create(pos, radius, v0, src.route, rng,
                                      self.scenario.prominent_fraction)
            batch.vel = np.asarray(src.heading, float)[None, :] * v0[:, None] * 0.5
            new.append(batch)
        if new:
            batch = AgentBatch.concat(new)
            self._add_agents(batch)
            e_new, wp, _ = self.routes.desired(batch.pos, batch.route, batch.wp)
            self.state.waypoint[-len(batch):] = wp
            e, v0 = self._desired_cache
            self._desired_cache = (np.vstack([e, e_new]), np.concatenate([v0, batch.v0]))

    def _free(self, pos: np.ndarray, radius: np.ndarray, pending: list[AgentBatch]) -> np.ndarray:
        """True where a candidate overlaps nobody (present, pending, or an earlier candidate)."""
        others_p = [self.state.pos] + [b.pos for b in pending]
        others_r = [self.state.radius] + [b.radius for b in pending]
        op, orad = np.concatenate(others_p), np.concatenate(others_r)
        lo, hi = pos.min(axis=0) - 1.0, pos.max(axis=0) + 1.0
        near = np.all((op >= lo) & (op <= hi), axis=1)
        op, orad = op[near], orad[near]
        ok = np.ones(len(pos), dtype=bool)
        if len(op):
            d = np.hypot(pos[:, None, 0] - op[None, :, 0], pos[:, None, 1] - op[None, :, 1])
            ok &= np.all(d > radius[:, None] + orad[None, :] + 0.05, axis=1)
        for i in range(1, len(pos)):  # candidates among themselves (a handful per step)
            d = np.hypot(*(pos[:i] - pos[i]).T)
            ok[i] &= bool(np.all((d > radius[:i] + radius[i] + 0.05) | ~ok[:i]))
        return ok

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


def simulate(scenario: Scenario, steps: int, seed: int = 0,
             params: SocialForceParams | None = None, progress: bool = False) -> tuple[
                 Trajectories, float]:
    """Run a scenario for ``steps`` steps; return its trajectories and the wall time (s)."""
    sim = Simulation(scenario, seed=seed, params=params)
    t0 = time.perf_counter()
    traj = sim.run(steps, progress=progress)
    assert traj is not None
    return traj, time.perf_counter() - t0
