"""Static geometry, routes, sources and agent batches that scenarios hand to the simulator.

Everything here is plain data (struct of arrays, metres and seconds); the physics lives in
:mod:`crowdsim.simulation` and :mod:`crowdsim.forces`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np

# ------------------------------------------------------------------------------ geometry


def polyline(
    points: list[tuple[float, float]] | np.ndarray, thickness: float = 0.05, closed: bool = False
) -> np.ndarray:
    """Wall segments ``(m, 5)`` (``x0, y0, x1, y1, half_thickness``) along a polyline."""
    p = np.asarray(points, dtype=np.float64)
    if closed:
        p = np.vstack([p, p[:1]])
    seg = np.column_stack([p[:-1], p[1:], np.full(len(p) - 1, thickness)])
    return seg


def rectangle(
    xmin: float, ymin: float, xmax: float, ymax: float, thickness: float = 0.05
) -> np.ndarray:
    """Closed rectangular obstacle (or room) as wall segments ``(4, 5)``."""
    return polyline(
        [(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax)], thickness, closed=True
    )


def arc(cx: float, cy: float, r: float, a0: float, a1: float, n: int) -> np.ndarray:
    """``(n + 1, 2)`` points on a circle arc from angle ``a0`` to ``a1`` (radians)."""
    a = np.linspace(a0, a1, n + 1)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def first_wall_overlap(
    pos: np.ndarray, radius: np.ndarray, walls: np.ndarray, chunk: int = 1 << 20
) -> tuple[int, int, float] | None:
    """The first disc that crosses a wall: ``(agent row, wall row, distance m)`` or None.

    A disc of ``radius (n,)`` at ``pos (n, 2)`` crosses a wall ``(m, 5)`` when its centre
    lies less than its radius from the wall's centre line (the segment ``x0, y0, x1, y1``);
    the wall row is the nearest one to that disc. Vectorised over agents x walls, ``chunk``
    point-segment distances at a time.
    """
    n, m = len(pos), len(walls)
    if n == 0 or m == 0:
        return None
    a = walls[:, 0:2]
    u = walls[:, 2:4] - a
    len2 = np.einsum("ij,ij->i", u, u)
    inv = np.divide(1.0, len2, out=np.zeros(m), where=len2 > 0)  # a point wall: t = 0
    step = max(1, chunk // m)
    for lo in range(0, n, step):
        p = pos[lo : lo + step]
        dx = p[:, 0, None] - a[:, 0]
        dy = p[:, 1, None] - a[:, 1]
        t = np.clip((dx * u[:, 0] + dy * u[:, 1]) * inv, 0.0, 1.0)
        d = np.hypot(dx - t * u[:, 0], dy - t * u[:, 1])
        hit = (d < radius[lo : lo + step, None]).any(axis=1)
        if hit.any():
            i = int(np.flatnonzero(hit)[0])
            j = int(np.argmin(d[i]))
            return lo + i, j, float(d[i, j])
    return None


@dataclass(frozen=True)
class World:
    """Static scene.

    Attributes
    ----------
    walls : (m, 5) float64
        Wall segments ``x0, y0, x1, y1, half_thickness`` (m), static pymunk segments.
    bounds : tuple of 4 floats
        ``(xmin, ymin, xmax, ymax)`` (m); agents leaving it (by more than 1 m) are removed.
    period : float
        Length (m) of a periodic x axis on ``[0, period)``, 0 for none. Agents crossing
        ``x = period`` re-enter at ``x = 0`` (and vice versa); forces see periodic images.
    """

    walls: np.ndarray
    bounds: tuple[float, float, float, float]
    period: float = 0.0

    def __post_init__(self) -> None:
        walls = np.asarray(self.walls, dtype=np.float64).reshape(-1, 5)
        object.__setattr__(self, "walls", walls)


@dataclass(frozen=True)
class Route:
    """A sequence of gates an agent walks through.

    The desired direction points to the nearest point of the current gate (a segment; a
    point when both ends coincide), so a crowd spreads over a wide gate instead of
    converging on one point. A gate counts as passed within ``reach`` metres.

    Attributes
    ----------
    gates : (k, 4) float64
        Gate segments ``x0, y0, x1, y1`` in m.
    loop : bool
        Start again at the first gate after the last (circulation); otherwise an agent that
        passes the last gate leaves the scene (the last gate is a sink).
    direction : (2,) float64 or None
        A fixed desired direction instead of gates (periodic corridors).
    reach : float
        Distance (m) at which a gate counts as passed.
    """

    gates: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    loop: bool = False
    direction: tuple[float, float] | None = None
    reach: float = 0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "gates", np.asarray(self.gates, dtype=np.float64).reshape(-1, 4))
        if self.direction is None and len(self.gates) == 0:
            raise ValueError("a route needs gates or a fixed direction")


class RouteTable:
    """All routes of a scene packed into arrays for vectorised lookup.

    ``gates (r, kmax, 4)``, ``length (r,)``, ``loop (r,)``, ``direction (r, 2)`` (zero when the
    route uses gates), ``reach (r,)``.
    """

    def __init__(self, routes: list[Route]) -> None:
        if not routes:
            raise ValueError("a scene needs at least one route")
        kmax = max(1, max(len(r.gates) for r in routes))
        self.gates = np.zeros((len(routes), kmax, 4))
        self.length = np.zeros(len(routes), dtype=np.int64)
        self.loop = np.array([r.loop for r in routes])
        self.direction = np.zeros((len(routes), 2))
        self.reach = np.array([r.reach for r in routes])
        for k, r in enumerate(routes):
            self.gates[k, : len(r.gates)] = r.gates
            self.length[k] = len(r.gates)
            if r.direction is not None:
                d = np.asarray(r.direction, dtype=np.float64)
                self.direction[k] = d / np.linalg.norm(d)

    def desired(
        self, pos: np.ndarray, route: np.ndarray, wp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Desired unit directions, advanced waypoint indices and the "arrived" mask.

        Parameters
        ----------
        pos : (n, 2) positions; route, wp : (n,) route and current gate index.

        Returns
        -------
        e : (n, 2) unit directions; wp : (n,) new gate indices; done : (n,) bool, True for
        agents that passed the last gate of a non-looping route.
        """
        n = len(pos)
        e = np.zeros((n, 2))
        done = np.zeros(n, dtype=bool)
        wp = wp.copy()
        if n:
            _route_kernel(
                pos,
                route,
                wp,
                self.gates,
                self.length,
                self.loop,
                self.direction,
                self.reach,
                e,
                done,
            )
        return e, wp, done


@nb.njit(cache=True)
def _nearest_on_gate(x, y, g):
    ux = g[2] - g[0]
    uy = g[3] - g[1]
    len2 = ux * ux + uy * uy
    t = 0.0
    if len2 > 0.0:
        t = min(1.0, max(0.0, ((x - g[0]) * ux + (y - g[1]) * uy) / len2))
    return g[0] + t * ux, g[1] + t * uy


@nb.njit(cache=True)
def _route_kernel(pos, route, wp, gates, length, loop, direction, reach, e, done):
    """Per agent: advance past reached gates (at most two a step), then aim at the nearest
    point of the current gate; a fixed route direction overrides gates."""
    for i in range(pos.shape[0]):
        r = route[i]
        if direction[r, 0] != 0.0 or direction[r, 1] != 0.0:
            e[i, 0] = direction[r, 0]
            e[i, 1] = direction[r, 1]
            continue
        x = pos[i, 0]
        y = pos[i, 1]
        for _ in range(2):  # gates are metres apart, steps centimetres
            qx, qy = _nearest_on_gate(x, y, gates[r, wp[i]])
            if math.hypot(qx - x, qy - y) >= reach[r]:
                break
            if wp[i] + 1 >= length[r]:
                if loop[r]:
                    wp[i] = 0
                else:
                    done[i] = True
                    break
            else:
                wp[i] += 1
        qx, qy = _nearest_on_gate(x, y, gates[r, wp[i]])
        dist = math.hypot(qx - x, qy - y)
        if dist > 1e-9:
            e[i, 0] = (qx - x) / dist
            e[i, 1] = (qy - y) / dist


# ------------------------------------------------------------------------------ agents


@dataclass
class AgentBatch:
    """Agents to add to a simulation (struct of arrays, ``n`` rows).

    The field names are those of :class:`crowdsim.simulation.CrowdState`, which stores the
    present agents the same way (plus their ids).

    pos, vel : (n, 2) m, m/s; radius, desired_speed : (n,) m, m/s; route, waypoint : (n,) int
    route and starting gate; group : (n,) int, -1 = none (group ids are scene-global);
    prominent : (n,) bool; anomaly : (n,) int8 (see ``ANOMALY_KINDS``);
    stop_start, stop_end : (n,) s, an interval in which the agent wants to stand still
    (``inf`` for never).
    """

    pos: np.ndarray
    vel: np.ndarray
    radius: np.ndarray
    desired_speed: np.ndarray
    route: np.ndarray
    waypoint: np.ndarray
    group: np.ndarray
    prominent: np.ndarray
    anomaly: np.ndarray
    stop_start: np.ndarray
    stop_end: np.ndarray

    FIELDS = (
        "pos",
        "vel",
        "radius",
        "desired_speed",
        "route",
        "waypoint",
        "group",
        "prominent",
        "anomaly",
        "stop_start",
        "stop_end",
    )

    @classmethod
    def create(
        cls,
        pos: np.ndarray,
        radius: np.ndarray,
        desired_speed: np.ndarray,
        route: np.ndarray | int,
        rng: np.random.Generator,
        prominent_fraction: float,
        waypoint: np.ndarray | int = 0,
        group: np.ndarray | None = None,
        anomaly: np.ndarray | None = None,
    ) -> AgentBatch:
        pos = np.asarray(pos, dtype=np.float64).reshape(-1, 2)
        n = len(pos)
        return cls(
            pos=pos,
            vel=np.zeros((n, 2)),
            radius=np.asarray(radius, dtype=np.float64),
            desired_speed=np.asarray(desired_speed, dtype=np.float64),
            route=np.broadcast_to(np.asarray(route, dtype=np.int64), (n,)).copy(),
            waypoint=np.broadcast_to(np.asarray(waypoint, dtype=np.int64), (n,)).copy(),
            group=np.full(n, -1, np.int64) if group is None else np.asarray(group, np.int64),
            prominent=rng.random(n) < prominent_fraction,
            anomaly=np.zeros(n, np.int8) if anomaly is None else np.asarray(anomaly, np.int8),
            stop_start=np.full(n, np.inf),
            stop_end=np.full(n, np.inf),
        )

    def __len__(self) -> int:
        return len(self.pos)

    @classmethod
    def concat(cls, batches: list[AgentBatch]) -> AgentBatch:
        return cls(**{f: np.concatenate([getattr(b, f) for b in batches]) for f in cls.FIELDS})


@dataclass(frozen=True)
class SpeedDistribution:
    """Desired speeds (m/s): normal ``N(mean, std)`` truncated to ``[low, high]``."""

    mean: float = 1.34
    std: float = 0.26
    low: float = 0.5
    high: float = 2.5

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if self.std == 0:
            return np.full(n, self.mean)
        v = rng.normal(self.mean, self.std, n)
        bad = (v < self.low) | (v > self.high)
        while bad.any():  # rejection keeps the truncated normal exact
            v[bad] = rng.normal(self.mean, self.std, int(bad.sum()))
            bad = (v < self.low) | (v > self.high)
        return v


WALKERS = SpeedDistribution()
"""Walkers: N(1.34, 0.26) m/s (SPEC §3), truncated to [0.5, 2.5]."""

RUNNERS = SpeedDistribution(mean=2.9, std=0.5, low=2.5, high=4.5)
"""Recreational runners: 2.5-4.5 m/s, mean about 2.9 m/s."""


@dataclass(frozen=True)
class Source:
    """Agents entering through a rectangle ``region`` at ``rate`` per second (Poisson).

    A new agent is placed at a uniform random point of the region, and only if it does not
    overlap anybody, so a congested entrance limits its own inflow.
    """

    region: tuple[float, float, float, float]
    rate: float
    route: int
    speeds: SpeedDistribution = WALKERS
    heading: tuple[float, float] = (1.0, 0.0)
    start: float = 0.0
    stop: float = np.inf


def expected_arrivals(sources: Sequence[Source], seconds: float) -> float:
    """People the ``sources`` bring on average over the first ``seconds`` of a run, each at
    its ``rate`` while it is open (``start`` .. ``stop``): what a memory estimate counts
    before stepping.

    >>> expected_arrivals([Source((0, 0, 1, 1), 2.0, 0, start=1.0, stop=4.0)], 10.0)
    6.0
    """
    return sum(
        float(src.rate) * max(0.0, min(float(src.stop), seconds) - max(float(src.start), 0.0))
        for src in sources
    )


def hex_positions(
    rng: np.random.Generator,
    n: int,
    x0: float,
    y0: float,
    y1: float,
    density: float,
    r_max: float,
    direction: float = 1.0,
    length: float | None = None,
    ordered: bool = False,
) -> np.ndarray:
    """``n`` non-overlapping positions at ``density`` /m² in the band ``y0 <= y <= y1``.

    The area is that of a hexagonal lattice extending from ``x0`` along ``direction`` (+1 or
    -1) as far as needed, or exactly over ``length`` metres when given. Unless ``ordered``,
    the positions are uniform random points in that area pushed apart until no two are
    closer than ``2 r_max`` (a relaxed random packing, as real crowds are disordered); where
    the density is too high for that (more than 55 % of the floor covered by bodies) the
    jittered lattice itself is returned.
    """
    if n == 0:
        return np.zeros((0, 2))
    a = np.sqrt(2.0 / (np.sqrt(3.0) * density))  # hexagonal spacing at this density
    dy = a * np.sqrt(3.0) / 2.0
    rows = max(1, int(np.floor((y1 - y0 - 2 * r_max) / dy)) + 1)
    cols = int(np.ceil(n / rows))
    if length is not None:
        a = length / cols
    # a band wider than n rows fills one column: only its first n rows are built
    used = min(rows, n)
    ys = y0 + r_max + dy * np.arange(used) + 0.5 * ((y1 - y0 - 2 * r_max) - dy * (rows - 1))
    xs = a * (np.arange(cols) + 0.5)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gx = gx + 0.5 * a * (np.arange(used)[None, :] % 2)
    pts = np.column_stack([gx.ravel(), gy.ravel()])[:n]
    coverage = density * np.pi * r_max**2
    if not ordered and coverage <= 0.55:
        lo = np.array([0.0, y0 + r_max])
        hi = np.array([max(float(pts[:, 0].max()) + 0.5 * a, 2 * r_max), y1 - r_max])
        hi[1] = max(hi[1], lo[1])
        pts = relax_overlaps(rng.uniform(lo, hi, (n, 2)), 2 * r_max + 0.02, lo, hi)
    else:
        jitter = max(0.0, (a - 2 * r_max) / 2 - 1e-3)
        if jitter > 0:
            pts[:, 0] += rng.uniform(-jitter, jitter, n)
    pts[:, 0] = x0 + direction * pts[:, 0]
    return pts


def relax_overlaps(
    pos: np.ndarray, min_dist: float, lo: np.ndarray, hi: np.ndarray, max_iter: int = 300
) -> np.ndarray:
    """Push points apart until no pair is closer than ``min_dist``, staying in ``[lo, hi]``.

    Each sweep moves both points of every close pair apart by half their overlap (plus a
    little), vectorised over the pairs a k-d tree finds; a handful to a few dozen sweeps
    suffice below 55 % coverage.
    """
    from scipy.spatial import cKDTree

    pos = np.clip(pos.astype(np.float64, copy=True), lo, hi)
    for _ in range(max_iter):
        pairs = cKDTree(pos).query_pairs(min_dist, output_type="ndarray")
        if len(pairs) == 0:
            break
        d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
        dist = np.hypot(d[:, 0], d[:, 1])
        dist = np.where(dist < 1e-9, 1e-9, dist)
        push = (0.5 * (min_dist - dist) + 1e-3)[:, None] * d / dist[:, None]
        delta = np.zeros_like(pos)
        np.add.at(delta, pairs[:, 0], push)
        np.add.at(delta, pairs[:, 1], -push)
        pos = np.clip(pos + delta, lo, hi)
    return pos


def lattice_length(n: int, width: float, density: float) -> float:
    """Length (m) of a band of ``width`` that holds ``n`` agents at ``density``."""
    return n / (density * width)
