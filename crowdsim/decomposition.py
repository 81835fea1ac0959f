"""The simulator split across worker processes: domain decomposition over strips.

Two pymunk spaces in two threads do not run in parallel (pymunk holds the GIL while it
steps), so :class:`crowdsim.simulation.Simulation` with ``workers=N > 1`` cuts the world into
``N`` strips and steps each in its own process with its own pymunk space.

Strips
    The world is cut into ``N`` strips along its longer axis (along x for a periodic world),
    at first ``N`` equal ones chosen from the world geometry and ``N`` only
    (:func:`strip_layout`). An agent belongs to the strip that holds its centre; the first
    and last strips extend to infinity (a periodic world wraps instead). Every
    :data:`BALANCE_EVERY` steps the parent counts each strip's agents and, when the fullest
    holds more than :data:`BALANCE_TOLERANCE` above the mean, moves the inner borders to the
    agents' quantiles (every strip at least twice the halo wide), so that each worker has
    about as much work and the barrier does not wait for one crowded strip. The workers
    learn the new borders with the next step; the bodies that a border move brings into a
    window are added like any agent that walks in.

Halo
    Worker ``k`` keeps one pymunk body for every agent within ``halo = cutoff + 0.5 m`` of its
    strip: its own agents and *halo* copies of its neighbours' agents near the borders. Halo
    bodies are ordinary dynamic bodies with the same mass, radius and social force as the
    original, so contacts across a border are resolved with the right masses; their result
    is thrown away, and at the start of every step they are reset to their owner's state.
    Social forces of the owned agents are exact (every neighbour within ``cutoff`` is
    present); only the outer edge of a halo, at least 0.5 m from the owned agents, misses
    some of its own contacts within one step.

Migration
    Ownership follows positions: after a step an agent whose centre crossed a border is
    owned by the neighbour from the next step on. It already has a halo body there (it was
    within the halo), and it stays a halo body on the side it left, so migration changes
    no body, only who writes the agent's state back.

Shared memory and step barrier
    Positions, velocities, route progress and the "present" flag live in one
    ``multiprocessing.shared_memory`` block indexed by agent id, twice: step ``k`` reads
    buffer ``k % 2`` and each worker writes the agents it owns into the other one, so no
    worker ever reads a half-written state. The parent sends "step" to every worker and
    waits for all replies (the barrier), watching the process sentinels: a worker that
    dies ends the run with :class:`WorkerFailed` naming the worker and the step, and every
    worker is stopped and the memory unlinked (also on ``close()``, garbage collection and
    interpreter exit).

Determinism
    Each worker sees exactly the same inputs at every step whatever the timing (the double
    buffer and the barrier), adds and removes bodies in ascending id order, and the force
    kernels sum in a fixed order whatever their thread count: the same scenario, seed and
    ``N`` give bit-identical trajectories. Different ``N`` give different (equally valid)
    trajectories: sums run in another order and border contacts are solved in two spaces.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import traceback
import types
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import connection, shared_memory
from multiprocessing.reduction import ForkingPickler
from time import perf_counter
from typing import Any

import numba
import numpy as np
import pymunk
import pymunk.batch as pb

from crowdsim.forces import BodyRows, WallGrid, contact_space, social_force
from crowdsim.params import SocialForceParams
from crowdsim.world import RouteTable, World

_BODY = pb.BodyFields

HALO_MARGIN = 0.5
"""Metres of halo beyond the interaction cutoff: halo bodies within this distance of the
owned agents have all their contacts and all their social forces."""

START_TIMEOUT_S = 120.0
"""Seconds a worker may take to start (import numba and pymunk, build its space)."""

STRIP_STAGES: tuple[str, ...] = ("window", "social_force", "contacts", "write_back")
"""The parts of a worker's step that :meth:`StripEngine.timing` reports: finding its
agents, routes and bodies (``window``), the social force, pymunk's contact sub-steps, and
writing its agents back to the shared state."""

HASH_CELL = 2.0
"""Cell size (m) of the spatial hash that is each worker's pymunk broad phase."""

BALANCE_EVERY = 25
"""Steps between two checks of the strips' balance (see :class:`StripEngine`)."""

BALANCE_TOLERANCE = 0.05
"""The strips are re-cut when the fullest holds more than this share above the mean."""

STOP_GRACE_S = 2.0
"""Seconds a worker gets to exit after "stop" before it is terminated, then killed."""

STATIC_FIELDS = ("radius", "desired_speed", "route", "group", "stop_start", "stop_end")
"""Per-agent attributes that never change during a run: sent once to every worker."""

_TEST_DIE_AT: tuple[int, int] | None = None
"""Test hook: ``(worker, step)`` makes that worker kill itself (SIGKILL) at that step (-2:
before it reads its start-up data)."""


class WorkerFailed(RuntimeError):
    """A worker process died or raised; ``worker`` and ``step`` say which and when.

    The message is one line: ``worker 1 (pid 4242) died at step 17 (killed by SIGKILL)``.
    """

    def __init__(self, worker: int, step: int, message: str) -> None:
        super().__init__(message)
        self.worker = worker
        self.step = step


# ------------------------------------------------------------------------------ strips


@dataclass(frozen=True)
class StripLayout:
    """How the world is cut: ``n`` strips along ``axis`` between the ``edges``.

    Attributes
    ----------
    axis : int
        0 = strips side by side along x, 1 = along y.
    edges : tuple of float
        ``n + 1`` ascending coordinates (m): strip ``k`` holds ``[edges[k], edges[k + 1])``.
        The first and last are the world's extent along ``axis`` (``0`` and ``period`` in a
        periodic world); in a non-periodic world the end strips reach to infinity.
    period : float
        Periodic length of the x axis (0 = none); then ``axis = 0``.
    halo : float
        Halo width, m.
    """

    axis: int
    edges: tuple[float, ...]
    period: float
    halo: float

    @classmethod
    def equal(
        cls, axis: int, lo: float, width: float, n: int, period: float, halo: float
    ) -> StripLayout:
        """``n`` strips of ``width`` m from ``lo``."""
        return cls(axis, tuple(float(lo + k * width) for k in range(n + 1)), period, halo)

    @property
    def n(self) -> int:
        """Number of strips (= workers)."""
        return len(self.edges) - 1

    def owner(self, coord: np.ndarray) -> np.ndarray:
        """Strip ``(m,)`` int64 of the coordinates ``coord`` ``(m,)`` along ``axis`` (m)."""
        inner = np.asarray(self.edges[1:-1])
        return np.searchsorted(inner, coord, side="right").astype(np.int64)

    def window(self, k: int) -> tuple[float, float]:
        """``(lo, hi)`` of the bodies worker ``k`` keeps: its strip plus the halo (an end
        strip of a non-periodic world reaches to infinity)."""
        lo = self.edges[k] - self.halo
        hi = self.edges[k + 1] + self.halo
        if self.period <= 0:
            lo = -np.inf if k == 0 else lo
            hi = np.inf if k == self.n - 1 else hi
        return lo, hi

    def centre(self, k: int) -> float:
        """Centre of strip ``k`` along ``axis`` (m)."""
        return 0.5 * (self.edges[k] + self.edges[k + 1])

    def local(self, k: int, coord: np.ndarray) -> np.ndarray:
        """Coordinates ``(m,)`` in worker ``k``'s unwrapped frame: in a periodic world the
        image nearest to the strip's centre (the worker's space has no seam)."""
        if self.period <= 0:
            return coord
        return _unwrap_all(np.asarray(coord, np.float64), self.centre(k), self.period)

    def balanced(self, coord: np.ndarray) -> StripLayout:
        """The layout whose inner edges split the agents at ``coord`` ``(m,)`` (along
        ``axis``) into ``n`` equal counts, each strip kept at least ``2 * halo`` wide (the
        halo must come from the immediate neighbours only); the outer edges stay. A pure
        function of ``coord``'s values, so a run stays deterministic."""
        n, e = self.n, np.array(self.edges)
        if n < 2 or len(coord) == 0:
            return self
        inner = np.quantile(coord, np.arange(1, n) / n)
        e[1:-1] = np.clip(inner, e[0], e[-1])
        wmin = 2 * self.halo
        for k in range(1, n):  # forward, then backward: feasible as the span >= n * wmin
            e[k] = max(e[k], e[k - 1] + wmin)
        for k in range(n - 1, 0, -1):
            e[k] = min(e[k], e[k + 1] - wmin)
        return StripLayout(self.axis, tuple(float(v) for v in e), self.period, self.halo)


@numba.njit(cache=True, nogil=True, inline="always")
def _unwrap(c: float, centre: float, period: float) -> float:
    """The image of ``c`` nearest to ``centre`` on a periodic axis (``period > 0``)."""
    return centre + ((c - centre + 0.5 * period) % period) - 0.5 * period


@numba.njit(cache=True, nogil=True)
def _unwrap_all(coord: np.ndarray, centre: float, period: float) -> np.ndarray:
    """:func:`_unwrap` of every entry of ``coord`` ``(m,)``."""
    out = np.empty_like(coord)
    for i in range(len(coord)):
        out[i] = _unwrap(coord[i], centre, period)
    return out


@numba.njit(cache=True, nogil=True)
def _gather_rows(
    pos: np.ndarray, vel: np.ndarray, wp: np.ndarray, alive: np.ndarray, ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``ids`` of the shared state's ``pos, vel (cap, 2)``, ``wp, alive (cap,)``."""
    m = len(ids)
    out_pos = np.empty((m, 2))
    out_vel = np.empty((m, 2))
    out_wp = np.empty(m, np.int64)
    present = np.empty(m, np.bool_)
    for r in range(m):
        i = ids[r]
        out_pos[r, 0] = pos[i, 0]
        out_pos[r, 1] = pos[i, 1]
        out_vel[r, 0] = vel[i, 0]
        out_vel[r, 1] = vel[i, 1]
        out_wp[r] = wp[i]
        present[r] = alive[i] != 0
    return out_pos, out_vel, out_wp, present


@numba.njit(cache=True, nogil=True)
def _pack_bodies(
    pos: np.ndarray,
    vel: np.ndarray,
    local: np.ndarray,
    axis: int,
    rows: np.ndarray,
    out: np.ndarray,
) -> None:
    """Fill pymunk's body rows ``out (m, 4)`` (x, y, vx, vy) with the window's agents ``pos,
    vel (m, 2)``, the coordinate along ``axis`` replaced by the strip frame's ``local (m,)``,
    agent ``q`` at row ``rows[q]``: the fancy-indexed copies and scatters this replaces took
    3 ms a step at 50k agents (numpy's mixed indexing of ``(n, 2)`` rows)."""
    for q in range(len(rows)):
        r = rows[q]
        out[r, 0] = pos[q, 0]
        out[r, 1] = pos[q, 1]
        out[r, axis] = local[q]
        out[r, 2] = vel[q, 0]
        out[r, 3] = vel[q, 1]


@numba.njit(cache=True, nogil=True)
def _scatter_scaled(acc: np.ndarray, scale: float, rows: np.ndarray, out: np.ndarray) -> None:
    """``out[rows[q]] = acc[q] * scale`` for ``acc (m, 2)``: the forces in pymunk's order."""
    for q in range(len(rows)):
        out[rows[q], 0] = acc[q, 0] * scale
        out[rows[q], 1] = acc[q, 1] * scale


@numba.njit(cache=True, nogil=True)
def _write_back(
    bodies: np.ndarray,
    rows: np.ndarray,
    ids: np.ndarray,
    wp: np.ndarray,
    period: float,
    bounds: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    wp_out: np.ndarray,
    alive: np.ndarray,
) -> bool:
    """Write the owned agents' new state into the shared buffer ``pos, vel (cap, 2), wp_out,
    alive (cap,)``: agent ``ids[q]`` from pymunk's row ``bodies[rows[q]]`` (x, y, vx, vy),
    x wrapped into ``[0, period)`` on a periodic axis, with gate ``wp[q]``; an agent more
    than 1 m outside ``bounds`` (xmin, ymin, xmax, ymax; y only when periodic) has left and
    is not written. Returns False, writing nothing, if any of those rows is not finite.
    (numpy's masks, gathers and scatters of ``(n, 2)`` rows took 8 ms a step at 50k agents.)
    """
    for q in range(len(rows)):
        for c in range(4):
            if not np.isfinite(bodies[rows[q], c]):
                return False
    xmin, ymin, xmax, ymax = bounds[0], bounds[1], bounds[2], bounds[3]
    for q in range(len(rows)):
        r = rows[q]
        x = bodies[r, 0]
        y = bodies[r, 1]
        if period > 0:
            x = x % period
        gone = y < ymin - 1 or y > ymax + 1
        if period <= 0:
            gone = gone or x < xmin - 1 or x > xmax + 1
        if gone:
            continue
        i = ids[q]
        pos[i, 0] = x
        pos[i, 1] = y
        vel[i, 0] = bodies[r, 2]
        vel[i, 1] = bodies[r, 3]
        wp_out[i] = wp[q]
        alive[i] = 1
    return True


@numba.njit(cache=True, nogil=True)
def _sorted_differences(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a \\ b, b \\ a)`` of two ascending arrays of distinct ids, ascending: one merge,
    where two ``np.setdiff1d`` sorted both (1.4 ms of a 100k-agent strip step)."""
    only_a = np.empty(len(a), np.int64)
    only_b = np.empty(len(b), np.int64)
    i = j = na = nb = 0
    while i < len(a) and j < len(b):
        if a[i] < b[j]:
            only_a[na] = a[i]
            na += 1
            i += 1
        elif b[j] < a[i]:
            only_b[nb] = b[j]
            nb += 1
            j += 1
        else:
            i += 1
            j += 1
    while i < len(a):
        only_a[na] = a[i]
        na += 1
        i += 1
    while j < len(b):
        only_b[nb] = b[j]
        nb += 1
        j += 1
    return only_a[:na], only_b[:nb]


@numba.njit(cache=True, nogil=True)
def _window_scan(
    alive: np.ndarray,
    pos: np.ndarray,
    axis: int,
    lo: float,
    hi: float,
    period: float,
    centre: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Ids ``(m,)`` (ascending) of the present agents whose coordinate along ``axis``, in
    the frame of the strip centred at ``centre`` (:meth:`StripLayout.local`), lies in
    ``[lo, hi)``, and those coordinates ``(m,)``."""
    n = len(alive)
    ids = np.empty(n, np.int64)
    local = np.empty(n, np.float64)
    m = 0
    for i in range(n):
        if alive[i] == 0:
            continue
        c = pos[i, axis]
        if period > 0:
            c = _unwrap(c, centre, period)
        if c >= lo and c < hi:
            ids[m] = i
            local[m] = c
            m += 1
    return ids[:m], local[:m]


def strip_layout(world: World, n: int, cutoff: float) -> StripLayout:
    """Cut ``world`` into ``n`` equal strips along its longer axis (x when periodic).

    Raises ``ValueError`` when a strip would be narrower than twice the halo
    (``cutoff + HALO_MARGIN``): the halo must come from the immediate neighbours only.
    """
    halo = float(cutoff) + HALO_MARGIN
    if world.period > 0:
        axis, lo, span = 0, 0.0, float(world.period)
    else:
        xmin, ymin, xmax, ymax = (float(b) for b in world.bounds)
        axis = 0 if xmax - xmin >= ymax - ymin else 1
        lo, span = (xmin, xmax - xmin) if axis == 0 else (ymin, ymax - ymin)
    width = span / n
    if n > 1 and width < 2 * halo:
        raise ValueError(
            f"workers={n}: strips of {width:.2f} m along the world's {'xy'[axis]} axis are "
            f"narrower than twice the halo ({2 * halo:g} m); use fewer workers or workers=1"
        )
    return StripLayout.equal(axis, lo, width, n, float(world.period), halo)


# ------------------------------------------------------------------------------ shared state


class SharedState:
    """Agent state in shared memory, indexed by agent id, double-buffered.

    ``pos, vel`` ``(2, cap, 2)`` float64 (m, m/s), ``wp`` ``(2, cap)`` int64 (current gate),
    ``alive`` ``(2, cap)`` uint8 (1 = present). Buffer ``k % 2`` holds the state before
    step ``k``.
    """

    def __init__(self, cap: int, name: str | None = None) -> None:
        self.cap = int(cap)
        size = self.cap * (2 * 16 + 2 * 16 + 2 * 8 + 2)
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=max(size, 1))
        else:
            self.shm = shared_memory.SharedMemory(name=name)
        buf, c = self.shm.buf, self.cap
        self.pos = np.ndarray((2, c, 2), np.float64, buf, 0)
        self.vel = np.ndarray((2, c, 2), np.float64, buf, 32 * c)
        self.wp = np.ndarray((2, c), np.int64, buf, 64 * c)
        self.alive = np.ndarray((2, c), np.uint8, buf, 80 * c)

    @property
    def name(self) -> str:
        return self.shm.name

    def close(self, unlink: bool = False) -> None:
        """Drop the views and unmap the block (and remove its name when ``unlink``)."""
        del self.pos, self.vel, self.wp, self.alive
        self.shm.close()
        if unlink:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


# ------------------------------------------------------------------------------ parent side


class StripEngine:
    """``n`` worker processes stepping the strips of one simulation (the parent side).

    Parameters
    ----------
    world : World
    routes : RouteTable
    params : SocialForceParams
    n_workers : int
        Number of worker processes (>= 2).
    static : dict of str to ndarray
        :data:`STATIC_FIELDS` of the agents with ids ``0 .. n-1``, each ``(n,)``, by id.
    pos, vel : (n, 2) float64
        Their positions and velocities, by id.
    wp : (n,) int64
        Their current gates, by id.
    alive : (n,) bool
        Which of them are present.
    capacity : int
        Agent ids the shared memory holds before it must grow (it grows by doubling).
    balance_every : int, optional
        Every this many steps (default :data:`BALANCE_EVERY`) the parent counts the agents
        of each strip; when the fullest holds more than :data:`BALANCE_TOLERANCE` above the
        mean, the inner borders move to the agents' quantiles (:meth:`StripLayout.balanced`),
        so that the barrier does not wait for one crowded strip. 0 keeps the equal strips
        of :func:`strip_layout`. The decision and the new borders depend only on the
        agents' state at that step, so a run stays deterministic for a given ``n_workers``
        and seed.

    Attributes
    ----------
    serial : bool
        Step the workers one after another instead of side by side (default False): the
        same trajectories, about ``n`` times slower; :meth:`timing` then gives each strip's
        time alone (``benchmarks/split_profile.py``).
    """

    def __init__(
        self,
        world: World,
        routes: RouteTable,
        params: SocialForceParams,
        n_workers: int,
        static: dict[str, np.ndarray],
        pos: np.ndarray,
        vel: np.ndarray,
        wp: np.ndarray,
        alive: np.ndarray,
        capacity: int,
        balance_every: int | None = None,
    ) -> None:
        import multiprocessing as mp

        self.layout = strip_layout(world, n_workers, params.cutoff)
        self.n_workers = n_workers
        self.balance_every = BALANCE_EVERY if balance_every is None else int(balance_every)
        self.rebalances = 0
        """How many times the strips were re-cut."""
        self.owned = np.zeros(n_workers, np.int64)
        """Agents each worker owned at the start of the last step (as the workers count)."""
        n = len(pos)
        self.n_known = n
        self.shared = SharedState(max(capacity, n, 1))
        self._old_shared: list[SharedState] = []
        self._pending_static: list[dict[str, np.ndarray]] = []
        self.procs: list[Any] = []
        self.conns: list[Any] = []
        self._state = {
            "procs": self.procs,
            "conns": self.conns,
            "shared": [self.shared],
            "senders": [],
        }
        self._finalizer = weakref.finalize(self, _shutdown, self._state)
        sh = self.shared
        sh.alive[:] = 0
        sh.pos[0, :n], sh.vel[0, :n], sh.wp[0, :n], sh.alive[0, :n] = pos, vel, wp, alive
        ctx = mp.get_context("spawn")  # numba's thread pools are not fork-safe
        threads = max(1, (os.cpu_count() or 1) // n_workers)
        # The large start-up data (per-agent arrays, the world, the routes: about 48 bytes an
        # agent) goes over the pipe after start(), from a thread: in start()'s own arguments,
        # a worker that died before reading it all left the parent blocked in start() for
        # good, out of reach of START_TIMEOUT_S. SIGINT stays blocked while the workers
        # start, so they begin with it blocked (they ignore it, then unblock it) and a
        # Ctrl-C sent to the whole group never shows a worker's import traceback. The data is
        # pickled here, once: an object that cannot be pickled fails now, not in a thread.
        bulk = bytes(ForkingPickler.dumps({"world": world, "routes": routes, "static": static}))
        senders = self._state["senders"]
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            for k in range(n_workers):
                parent_end, child_end = ctx.Pipe()
                init = {
                    "index": k,
                    "layout": self.layout,
                    "params": params,
                    "shm": sh.name,
                    "cap": sh.cap,
                    "threads": threads,
                    "parent_pid": os.getpid(),
                    "die_at": _TEST_DIE_AT[1] if _TEST_DIE_AT and _TEST_DIE_AT[0] == k else -1,
                }
                proc = ctx.Process(
                    target=_worker_main, args=(child_end, init), name=f"crowdsim-strip-{k}"
                )
                proc.daemon = True
                with _bare_main():
                    proc.start()
                child_end.close()
                self.procs.append(proc)
                self.conns.append(parent_end)
                send = threading.Thread(target=_send_quietly, args=(parent_end, bulk), daemon=True)
                send.start()
                senders.append(send)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        self._gather(-1, ("ready",), START_TIMEOUT_S)
        for send in senders:
            send.join()
        self.serial = False
        self.reset_timing()

    def reset_timing(self) -> None:
        """Start :meth:`timing`'s sums afresh (e.g. after warm-up steps)."""
        self._busy = np.zeros(self.n_workers)
        self._stages = np.zeros(len(STRIP_STAGES))
        self._critical = 0.0
        self._wall = 0.0
        self._timed_steps = 0

    def timing(self) -> dict[str, Any]:
        """Where the time of the steps since :meth:`reset_timing` went, in ms a step.

        ``busy_ms`` (per worker) is the time each worker spent on its strip (from receiving
        "step" to replying), ``critical_ms`` the slowest worker's time (summed step by step),
        ``step_ms`` the parent's wall time in :meth:`step` (sending, waiting, collecting);
        ``barrier_ms = step_ms - critical_ms`` is then what the barrier itself costs
        (messages and wake-ups). ``stage_ms`` splits the mean worker's strip into
        :data:`STRIP_STAGES`. With :attr:`serial` set, the workers step one after another, so
        ``busy_ms`` is each strip's time alone on the machine (a diagnostic: the same results,
        about ``n`` times slower). ``owned`` is :attr:`owned`, the agents of each strip at
        the last step.
        """
        k = max(self._timed_steps, 1)
        busy = self._busy / k * 1e3
        step_ms, critical_ms = self._wall / k * 1e3, self._critical / k * 1e3
        return {
            "steps": self._timed_steps,
            "serial": self.serial,
            "busy_ms": busy.tolist(),
            "busy_mean_ms": float(busy.mean()),
            "stage_ms": {
                name: float(v) / k * 1e3 for name, v in zip(STRIP_STAGES, self._stages, strict=True)
            },
            "critical_ms": critical_ms,
            "step_ms": step_ms,
            "barrier_ms": step_ms - critical_ms,
            "owned": self.owned.tolist(),
        }

    @property
    def pids(self) -> list[int]:
        """Process ids of the workers, by strip."""
        return [int(p.pid) for p in self.procs]

    def current(self, steps: int) -> int:
        """Index of the buffer that holds the state after ``steps`` steps."""
        return steps & 1

    def add(self, ids: np.ndarray, static: dict[str, np.ndarray]) -> None:
        """Register new agents ``ids`` (the next ids, ascending) with their static fields;
        workers learn them with the next step. Their state is written with :meth:`write`."""
        if len(ids) == 0:
            return
        need = int(ids[-1]) + 1
        if need > self.shared.cap:
            self._grow(max(need, 2 * self.shared.cap))
        self.n_known = need
        self._pending_static.append({k: np.asarray(static[k]) for k in STATIC_FIELDS})

    def _grow(self, cap: int) -> None:
        old = self.shared
        new = SharedState(cap)
        new.alive[:] = 0
        c = old.cap
        new.pos[:, :c], new.vel[:, :c] = old.pos, old.vel
        new.wp[:, :c], new.alive[:, :c] = old.wp, old.alive
        self.shared = new
        self._state["shared"].append(new)
        self._old_shared.append(old)

    def step(self, steps: int, time: float) -> None:
        """Advance every strip by one step (the barrier); ``steps`` steps were taken before.

        Raises :class:`WorkerFailed` (after stopping every worker) if a worker dies or fails.
        """
        static = None
        if self._pending_static:
            static = {
                k: np.concatenate([s[k] for s in self._pending_static]) for k in STATIC_FIELDS
            }
            self._pending_static = []
        shm = (self.shared.name, self.shared.cap) if self._old_shared else None
        t0 = perf_counter()
        layout = self._rebalance(steps)
        self.shared.alive[self.current(steps + 1)] = 0  # workers write who is still there
        msg = ("step", steps, time, self.n_known, static, shm, layout)
        busy = np.zeros(self.n_workers)
        stages = np.zeros(len(STRIP_STAGES))
        everyone = list(range(self.n_workers))
        for group in [[k] for k in everyone] if self.serial else [everyone]:
            for k in group:
                try:
                    self.conns[k].send(msg)
                except OSError:
                    self._fail(k, steps, self._death_note(k, steps))
            for k, reply in self._gather(steps, ("done",), None, only=group).items():
                busy[k] = reply[1]
                stages += reply[2]
                self.owned[k] = reply[3]
        self._wall += perf_counter() - t0
        self._busy += busy
        self._stages += stages / self.n_workers
        self._critical += busy.max()
        self._timed_steps += 1
        for old in self._old_shared:
            self._state["shared"].remove(old)
            old.close(unlink=True)
        self._old_shared = []

    def _rebalance(self, steps: int) -> StripLayout | None:
        """The new layout when the strips are due a check (every :attr:`balance_every`
        steps) and out of balance; ``None`` otherwise (the workers keep theirs)."""
        if self.balance_every <= 0 or steps == 0 or steps % self.balance_every:
            return None
        sh, cur, n = self.shared, self.current(steps), self.n_known
        coord = sh.pos[cur, :n, self.layout.axis][sh.alive[cur, :n] != 0]
        if len(coord) < self.n_workers:
            return None
        counts = np.bincount(self.layout.owner(coord), minlength=self.n_workers)
        if counts.max() <= (1.0 + BALANCE_TOLERANCE) * counts.mean():
            return None
        layout = self.layout.balanced(coord)
        if layout == self.layout:
            return None
        self.layout = layout
        self.rebalances += 1
        return layout

    def gather(
        self, steps: int, ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, gates and the present flag ``(m,)`` bool of the agents
        ``ids`` ``(m,)`` after ``steps`` steps, in one pass over the shared state (the
        parent's serial part of a step: numpy's four gathers took 44 ms at 1M agents)."""
        sh, cur = self.shared, self.current(steps)
        return _gather_rows(sh.pos[cur], sh.vel[cur], sh.wp[cur], sh.alive[cur], ids)

    def _gather(
        self,
        steps: int,
        expect: tuple[str, ...],
        timeout: float | None,
        only: list[int] | None = None,
    ) -> dict[int, tuple]:
        """Wait for one reply from every worker (or the workers ``only``) and return the
        replies by worker; a death or an error raises WorkerFailed."""
        waiting = {k: self.conns[k] for k in (range(self.n_workers) if only is None else only)}
        replies: dict[int, tuple] = {}
        sentinels = {p.sentinel: k for k, p in enumerate(self.procs)}
        while waiting:
            ready = connection.wait([*waiting.values(), *sentinels], timeout=timeout)
            if not ready:
                k = min(waiting)
                self._fail(k, steps, f"worker {k} did not start within {timeout:g} s")
            for obj in ready:
                if obj in sentinels:
                    k = sentinels[obj]
                    if k not in waiting or not waiting[k].poll():  # it is gone
                        self._fail(k, steps, self._death_note(k, steps))
                    continue
                k = next(i for i, c in waiting.items() if c is obj)
                try:
                    reply = obj.recv()
                except (EOFError, OSError):
                    self._fail(k, steps, self._death_note(k, steps))
                if reply[0] == "error":
                    self._fail(k, steps, f"worker {k} failed at step {steps}: {reply[1]}")
                replies[k] = reply
                del waiting[k]
        return replies

    def _death_note(self, k: int, steps: int) -> str:
        proc = self.procs[k]
        proc.join(0.5)
        code = proc.exitcode
        if code is not None and code < 0:
            try:
                how = f"killed by {signal.Signals(-code).name}"
            except ValueError:
                how = f"killed by signal {-code}"
        else:
            how = f"exit code {code}"
        where = "while starting" if steps < 0 else f"at step {steps}"
        return f"worker {k} (pid {proc.pid}) died {where} ({how})"

    def _fail(self, k: int, steps: int, message: str) -> None:
        self.close()
        raise WorkerFailed(k, steps, message)

    def close(self) -> None:
        """Stop every worker and unlink the shared memory (idempotent)."""
        self._finalizer()


@contextmanager
def _bare_main() -> Iterator[None]:
    """Start spawned workers without re-running the caller's ``__main__``.

    A spawned child imports the parent's main script first, which restarts the caller's
    own work in every worker when the script lacks an ``if __name__ == "__main__"`` guard.
    The workers need nothing from it (their target and arguments live in crowdsim), so the
    main module is hidden while the child's start-up data is taken.
    """
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is not None:
            sys.modules["__main__"] = main


def _shutdown(state: dict[str, Any]) -> None:
    """Stop the workers (politely, then terminate, then kill) and unlink the memory.

    A worker whose start-up data is still being sent gets no "stop" on its pipe (it would
    interleave with the data): it is terminated, and its sender thread ends with it before
    the pipe is closed."""
    senders = state.get("senders", [])
    sending = [k < len(senders) and senders[k].is_alive() for k in range(len(state["conns"]))]
    for conn, busy, proc in zip(state["conns"], sending, state["procs"], strict=False):
        if busy:
            proc.terminate()
            continue
        try:
            conn.send(("stop",))
        except (OSError, ValueError):
            pass
    for proc in state["procs"]:
        proc.join(STOP_GRACE_S)
        if proc.is_alive():
            proc.terminate()
            proc.join(STOP_GRACE_S)
        if proc.is_alive():
            proc.kill()
            proc.join()
    for sender in senders:  # their workers are gone: a send fails at once
        sender.join(STOP_GRACE_S)
    for conn in state["conns"]:
        conn.close()
    for sh in state["shared"]:
        sh.close(unlink=True)
    senders.clear()
    state["conns"].clear()
    state["procs"].clear()
    state["shared"].clear()


# ------------------------------------------------------------------------------ worker side


class _Strip:
    """One worker's strip: its pymunk space with the owned and halo bodies."""

    def __init__(self, init: dict[str, Any]) -> None:
        self.k = int(init["index"])
        self.layout: StripLayout = init["layout"]
        self.world: World = init["world"]
        self.routes: RouteTable = init["routes"]
        self.params: SocialForceParams = init["params"]
        self.static = {f: np.asarray(v) for f, v in init["static"].items()}
        self.shared = SharedState(init["cap"], name=init["shm"])
        self.die_at = int(init["die_at"])
        self.wall_grid = WallGrid(self.world.walls, self.params.cutoff)
        self.bounds = np.asarray(self.world.bounds, dtype=np.float64)  # xmin, ymin, xmax, ymax
        self.space = self._make_space()
        self.body_rows = BodyRows(self.space)
        self.agents = np.zeros(0, np.int64)  # ids of the bodies in the space, ascending
        self.body_id = np.zeros(len(self.static["radius"]), np.int64)  # by agent id
        self.shapes: dict[int, tuple[pymunk.Body, pymunk.Circle]] = {}
        self.rows = np.zeros(0, np.int64)  # pymunk row of each body in self.agents
        self.n_rows = 0  # pymunk's rows: the agents' bodies and the static body of the walls
        self.stage_s = np.zeros(len(STRIP_STAGES))  # seconds of the last step, per stage
        self.owned = 0  # agents this strip owned at the start of the last step

    def _make_space(self) -> pymunk.Space:
        walls = self.world.walls
        period = self.layout.period
        if period > 0:  # the worker's frame is unwrapped: walls one period away too
            shifted = [walls.copy() for _ in range(2)]
            for s, sign in zip(shifted, (-1.0, 1.0), strict=True):
                s[:, [0, 2]] += sign * period
            walls = np.vstack([walls, *shifted])
        space = contact_space(self.params, walls)
        # Broad phase: a spatial hash, not pymunk's default bounding-box tree. The tree pads
        # each leaf by 0.1 s of its body's motion and re-inserts the leaf (and re-queries its
        # pairs) once the body leaves it, so a walking crowd rebuilds most of the tree every
        # ~8 sub-steps in bursts of 0.3 s per 50k bodies; the bursts fall on different steps
        # in different strips and the barrier waits for the slowest: 2 strips of the 100k
        # corridor took 87 and 124 ms of pymunk a step (measured per worker), the hash 60-75
        # (2 m cells, 8 bodies a cell at 2 /m^2; 0.5 m and 1 m cells were slower).
        n_est = len(self.static["radius"]) // self.layout.n
        space.use_spatial_hash(HASH_CELL, max(10_000, 2 * n_est))
        return space

    def learn(
        self, n_known: int, static: dict[str, np.ndarray] | None, shm: tuple[str, int] | None
    ) -> None:
        """Take in agents that entered (their static fields) and a grown shared block."""
        if static is not None:
            for f in STATIC_FIELDS:
                self.static[f] = np.concatenate([self.static[f], static[f]])
            self.body_id = np.concatenate([self.body_id, np.zeros(len(static["radius"]), np.int64)])
        if shm is not None and shm[0] != self.shared.name:
            old = self.shared
            self.shared = SharedState(shm[1], name=shm[0])
            old.close()
        assert len(self.static["radius"]) == n_known, "agent tables out of step"

    def step(self, steps: int, time: float) -> None:
        """Step ``steps`` -> ``steps + 1`` of this strip (see the module docstring)."""
        if steps == self.die_at:
            os.kill(os.getpid(), signal.SIGKILL)
        sh, lay, p, k = self.shared, self.layout, self.params, self.k
        rb, wb = steps & 1, (steps + 1) & 1
        n = len(self.body_id)
        lo, hi = lay.window(k)
        # One pass over the shared state (no temporaries of the whole crowd): every worker
        # scans all agents each step, so this is the part of a step that does not shrink
        # with more workers (2.5 ms of a 12 ms strip step at 100k agents / 16 strips with
        # numpy masks and gathers: 1.7 ms of them against 0.46 ms here, measured apart).
        t0 = perf_counter()
        ids, local = _window_scan(
            sh.alive[rb, :n], sh.pos[rb, :n], lay.axis, lo, hi, lay.period, lay.centre(k)
        )
        gpos, vel, wp, _ = _gather_rows(sh.pos[rb], sh.vel[rb], sh.wp[rb], sh.alive[rb], ids)
        # Routes on the global state: owner and halo copies get the same directions, and an
        # agent past its last gate is gone for every worker at once.
        e, wp, done = self.routes.desired(gpos, self.static["route"][ids], wp)
        if done.any():
            keep = ~done
            ids, gpos, local, e, wp = ids[keep], gpos[keep], local[keep], e[keep], wp[keep]
            vel = vel[keep]
        self._sync_bodies(ids, gpos, local, vel)
        own = lay.owner(gpos[:, lay.axis]) == k
        self.owned = int(own.sum())
        if len(ids) == 0:
            return
        # Every row pymunk has, the walls' static body's included: zeros there, its place and
        # velocity. (With one row per agent, pymunk read the static body's row from past the
        # buffer's end: whatever the heap held there set the walls' velocity, so 2-worker runs
        # of one seed differed from the first step depending on the worker's memory, and a few
        # hung in pymunk's spatial hash.)
        bodies_in = np.zeros((self.n_rows, 4))
        _pack_bodies(gpos, vel, local, lay.axis, self.rows, bodies_in)
        self.body_rows.write(_BODY.POSITION | _BODY.VELOCITY, bodies_in)
        t1 = perf_counter()
        st = self.static
        standing = (time >= st["stop_start"][ids]) & (time < st["stop_end"][ids])
        v0 = np.where(standing, 0.0, st["desired_speed"][ids])
        acc = social_force(
            gpos,
            vel,
            st["radius"][ids],
            v0,
            e,
            st["group"][ids],
            self.world.walls,
            p,
            lay.period,
            self.wall_grid,
        )
        forces = np.zeros((self.n_rows, 2))
        _scatter_scaled(acc, p.mass, self.rows, forces)
        t2 = perf_counter()
        sub_dt = p.dt / p.substeps
        for _ in range(p.substeps):
            self.body_rows.write(_BODY.FORCE, forces)  # pymunk clears forces
            self.space.step(sub_dt)
        t3 = perf_counter()
        bodies = self.body_rows.read(_BODY.POSITION | _BODY.VELOCITY)
        if not _write_back(
            bodies,
            self.rows[own],
            ids[own],
            wp[own],
            float(lay.period),
            self.bounds,
            sh.pos[wb],
            sh.vel[wb],
            sh.wp[wb],
            sh.alive[wb],
        ):
            raise FloatingPointError(
                f"non-finite agent state at step {steps}; reduce dt (now {p.dt} s) or the "
                "force strengths (--param)"
            )
        self.stage_s[:] = (t1 - t0, t2 - t1, t3 - t2, perf_counter() - t3)

    def _sync_bodies(
        self, ids: np.ndarray, gpos: np.ndarray, local: np.ndarray, vel: np.ndarray
    ) -> None:
        """Bodies for exactly the agents ``ids`` (ascending): remove those that left the
        window, add those that entered (a handful per step, in id order)."""
        gone, new = _sorted_differences(self.agents, ids)
        for a in gone:  # only the agents that left the window
            self.space.remove(*self.shapes.pop(int(self.body_id[a])))
            self.body_id[a] = 0
        if len(new):
            rows = np.searchsorted(ids, new)
            radius = self.static["radius"]
            axis = self.layout.axis
            p = self.params
            for a, r in zip(new.tolist(), rows.tolist(), strict=True):  # entering agents only
                body = pymunk.Body(p.mass, float("inf"))
                xy = [float(gpos[r, 0]), float(gpos[r, 1])]
                xy[axis] = float(local[r])
                body.position = (xy[0], xy[1])
                body.velocity = (float(vel[r, 0]), float(vel[r, 1]))
                shape = pymunk.Circle(body, float(radius[a]))
                shape.friction = p.friction
                shape.elasticity = 0.0
                self.space.add(body, shape)
                self.shapes[body.id] = (body, shape)
                self.body_id[a] = body.id
        if len(gone) or len(new):
            self.agents = ids
            self.n_rows, (self.rows,) = self.body_rows.rows_of(self.body_id[ids])

    def close(self) -> None:
        self.shared.close()


def _send_quietly(conn: Any, data: bytes) -> None:
    """Send the pickled ``data`` on ``conn`` (a worker's start-up data, from a thread); a
    worker that died or was stopped meanwhile is named by :meth:`StripEngine._gather`."""
    try:
        conn.send_bytes(data)
    except (OSError, ValueError, TypeError):  # TypeError: the pipe was closed under it
        pass


def _worker_main(conn: Any, init: dict[str, Any]) -> None:
    """Entry point of a worker process: take the start-up data (:class:`StripEngine`), build
    the strip, then serve "step" messages."""
    from crowdsim.jobs import die_with_parent

    die_with_parent(int(init["parent_pid"]))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked since the start
    strip = None
    try:
        if init["die_at"] == -2:  # test hook: die before the start-up data is read
            os.kill(os.getpid(), signal.SIGKILL)
        init = {**init, **pickle.loads(conn.recv_bytes())}
        import numba

        numba.set_num_threads(int(init["threads"]))
        strip = _Strip(init)
        conn.send(("ready",))
        while True:
            msg = conn.recv()
            if msg[0] != "step":
                break
            _, steps, time, n_known, static, shm, layout = msg
            if layout is not None:  # the strips were re-cut (StripEngine._rebalance)
                strip.layout = layout
            t0 = perf_counter()
            strip.stage_s[:] = 0.0
            try:
                strip.learn(n_known, static, shm)
                strip.step(steps, time)
            except Exception as exc:  # reported to the parent as one line
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
                continue
            conn.send(("done", perf_counter() - t0, strip.stage_s, strip.owned))
    except (EOFError, OSError, KeyboardInterrupt):
        pass
    except Exception as exc:  # failed to start
        try:
            conn.send(("error", f"{type(exc).__name__}: {exc} [{traceback.format_exc(-1)}]"))
        except OSError:
            pass
    finally:
        if strip is not None:
            strip.close()
        conn.close()
