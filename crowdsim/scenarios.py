"""Parameterised, seeded crowd scenarios (SPEC §3).

Each scenario is a frozen dataclass; ``build(rng)`` returns a :class:`Setup` (geometry,
routes, initial agents, sources). Sizes follow the agent count and the density, so any
scenario runs from 1 to :data:`MAX_AGENTS` (1,000,000) agents::

    >>> sc = make_scenario("counterflow", n_agents=40, density=1.0)
    >>> setup = sc.build(np.random.default_rng(0))
    >>> len(setup.agents)
    40

Scenarios: ``marathon``, ``counterflow``, ``groups``, ``anomalies``, ``crossing``,
``circulation``, ``station``, ``commuters``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from crowdsim.checks import require_memory, require_number
from crowdsim.trajectories import ANOMALY_KINDS
from crowdsim.world import (
    RUNNERS,
    WALKERS,
    AgentBatch,
    Route,
    Source,
    SpeedDistribution,
    World,
    arc,
    hex_positions,
    lattice_length,
    polyline,
    rectangle,
    relax_overlaps,
)

MAX_AGENTS = 1_000_000
"""Largest crowd a scenario, ``crowdsim simulate`` or an environment accepts (issue 16's
scale runs: one million agents split across worker processes)."""
EXIT_DISTANCE = 3.0
"""Metres beyond a station door, or the far kerb of a crossing's queue, at which walkers
leave: sinks sit outside the area a camera frames."""
PILLAR_SIDE = 0.8
"""Side of a station pillar, m."""
MAX_LENGTH_M = 10_000.0
"""Largest width, radius or side a scenario takes, m (a 10 km street; the walls' grid of a
world that size takes about 0.4 GB, and one of 1e9 m would not fit in memory)."""
MAX_SPEED = 10.0
"""Largest mean walking speed a scenario takes, m/s (faster than any runner's average)."""
MAX_DENSITY = 6.0


def weidmann_speed(density: np.ndarray | float, v_free: float = 1.34) -> np.ndarray:
    """Weidmann (1993) fundamental diagram ``v(rho) = v_free (1 - exp(-1.913 (1/rho - 1/5.4)))``.

    >>> round(float(weidmann_speed(1.0)), 3)
    1.058
    """
    rho = np.asarray(density, dtype=np.float64)
    return np.clip(v_free * (1.0 - np.exp(-1.913 * (1.0 / rho - 1.0 / 5.4))), 0.0, None)


@dataclass
class Setup:
    """What a scenario hands to :class:`crowdsim.simulation.Simulation`."""

    world: World
    routes: list[Route]
    agents: AgentBatch
    sources: list[Source]
    info: dict[str, Any]


@dataclass(frozen=True)
class Scenario(ABC):
    """Base of all scenarios.

    Attributes
    ----------
    n_agents : int
        Agents placed at the start (1 to :data:`MAX_AGENTS`, 1,000,000); sources may add more
        later.
    density : float
        Density of the initial crowd, persons/m² (0 < density <= 6).
    prominent_fraction : float
        Fraction of agents with distinct clothing ("prominent", paper 2), in [0, 1].
    radius : tuple of 2 floats
        Range (m) of the body radii, drawn uniformly.
    """

    n_agents: int = 100
    density: float = 1.0
    prominent_fraction: float = 0.05
    radius: tuple[float, float] = (0.2, 0.25)

    name: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for f in fields(self):
            _check_type(self.name, f.name, getattr(self, f.name), f.default)
        if isinstance(self.n_agents, bool) or not isinstance(self.n_agents, (int, np.integer)):
            raise ValueError(f"{self.name}.n_agents must be an integer, got {self.n_agents!r}")
        require_number(self.name, "n_agents", self.n_agents, lo=1, hi=MAX_AGENTS, integer=True)
        require_number(self.name, "density", self.density, lo=0, hi=MAX_DENSITY, lo_open=True)
        self._fraction("prominent_fraction")
        lo, hi = self.radius
        if not 0.1 <= lo <= hi <= 0.4:
            raise ValueError(f"radius must satisfy 0.1 <= low <= high <= 0.4 m, got {self.radius}")
        self.validate()

    def validate(self) -> None:  # noqa: B027 - optional hook
        """Scenario-specific checks (raise ``ValueError`` naming the field and value)."""

    def _sizes(self, *names: str) -> None:
        """Widths, radii and sides: positive and at most :data:`MAX_LENGTH_M`."""
        for name in names:
            value = getattr(self, name)
            require_number(self.name, name, value, lo=0, hi=MAX_LENGTH_M, lo_open=True)

    def _fraction(self, *names: str) -> None:
        for name in names:
            require_number(self.name, name, getattr(self, name), lo=0, hi=1)

    @abstractmethod
    def build(self, rng: np.random.Generator) -> Setup:
        """Geometry, routes, initial agents and sources, drawn from ``rng``."""

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **asdict(self)}

    def _radii(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(self.radius[0], self.radius[1], n)


def _check_type(scenario: str, name: str, value: Any, default: Any) -> None:
    """Values must have the kind of their default: bool, number (finite), string or tuple."""
    where = f"{scenario}.{name}"
    if isinstance(default, bool):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{where} must be true or false, got {value!r}")
    elif isinstance(default, int):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{where} must be an integer, got {value!r}")
    elif isinstance(default, float):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            raise ValueError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{where} must be finite, got {value!r}")
    elif isinstance(default, tuple):
        if not isinstance(value, tuple):
            raise ValueError(f"{where} must be a list, got {value!r}")
        if len(value) == 0:  # a list it is (an empty one): "must be a list, got ()" misled
            raise ValueError(f"{where} must be a non-empty list, got []")
        if isinstance(default[0], str):
            if not all(isinstance(v, str) for v in value):
                raise ValueError(f"{where} must be a list of names, got {value!r}")
            return
        if len(value) != len(default):
            raise ValueError(f"{where} must have {len(default)} values, got {value!r}")
        for v in value:
            _check_type(scenario, name, v, default[0])


# ------------------------------------------------------------------------------ corridors


def _corridor_world(length: float, width: float, margin: float, period: float = 0.0) -> World:
    if period > 0:
        walls = np.vstack(
            [
                polyline([(-1.0, 0.0), (period + 1.0, 0.0)]),
                polyline([(-1.0, width), (period + 1.0, width)]),
            ]
        )
        return World(walls, (0.0, -1.0, period, width + 1.0), period=period)
    walls = np.vstack(
        [
            polyline([(-margin, 0.0), (length + margin, 0.0)]),
            polyline([(-margin, width), (length + margin, width)]),
        ]
    )
    return World(walls, (-margin - 2.0, -1.0, length + margin + 2.0, width + 1.0))


def _end_gate(x: float, width: float) -> list[float]:
    return [x, 0.3, x, width - 0.3]


@dataclass(frozen=True)
class Counterflow(Scenario):
    """Bidirectional corridor; lanes form spontaneously.

    Agents are placed mixed at random over the corridor; a fraction ``right_fraction`` walks
    towards +x, the others towards -x. With ``periodic=True`` the corridor wraps around
    (steady state, used for the lane order parameter); otherwise agents leave at the far end
    and sources at both ends keep the flow up (``inflow``).

    Extra attributes: ``width`` (m), ``right_fraction``, ``periodic``, ``inflow``.
    """

    width: float = 6.0
    right_fraction: float = 0.5
    periodic: bool = False
    inflow: bool = True
    name: ClassVar[str] = "counterflow"
    MIN_PERIOD: ClassVar[float] = 6.5
    """Shortest periodic corridor, m: fewer people make it this long, not denser."""

    def validate(self) -> None:
        self._sizes("width")
        self._fraction("right_fraction")
        if self.width < 2 * self.radius[1] + 0.2:
            raise ValueError(
                f"{self.name}.width must be >= {2 * self.radius[1] + 0.2} m, got {self.width}"
            )

    def _length(self) -> float:
        length = lattice_length(self.n_agents, self.width, self.density)
        return max(length, self.MIN_PERIOD if self.periodic else 4.0)

    def build(self, rng: np.random.Generator) -> Setup:
        n, w = self.n_agents, self.width
        length = self._length()
        if self.periodic:  # exactly n / (density * width): the density is the target one
            pos = hex_positions(
                rng, n, 0.0, 0.0, w, self.density, self.radius[1], length=length, ordered=True
            )
        else:
            pos = hex_positions(rng, n, 0.0, 0.0, w, self.density, self.radius[1])
            length = max(length, float(pos[:, 0].max()) + 0.5 / math.sqrt(self.density))
        right = np.zeros(n, dtype=bool)
        right[rng.permutation(n)[: int(round(self.right_fraction * n))]] = True
        margin = 4.0
        if self.periodic:
            world = _corridor_world(length, w, margin, period=length)
            routes = [Route(direction=(1.0, 0.0)), Route(direction=(-1.0, 0.0))]
        else:
            world = _corridor_world(length, w, margin)
            routes = [Route([_end_gate(length + margin, w)]), Route([_end_gate(-margin, w)])]
        agents = AgentBatch.create(
            pos,
            self._radii(rng, n),
            WALKERS.sample(rng, n),
            np.where(right, 0, 1),
            rng,
            self.prominent_fraction,
        )
        sources = []
        if self.inflow and not self.periodic:
            flow = self.density * float(weidmann_speed(self.density)) * w
            sources = [
                Source((-margin, 0.3, -margin + 1.5, w - 0.3), flow * self.right_fraction, 0),
                Source(
                    (length + margin - 1.5, 0.3, length + margin, w - 0.3),
                    flow * (1 - self.right_fraction),
                    1,
                    heading=(-1.0, 0.0),
                ),
            ]
        return Setup(world, routes, agents, sources, {"length": length, "width": w})


@dataclass(frozen=True)
class Commuters(Counterflow):
    """Dense outdoor walking on a wide street: a main flow and a minority walking against it.

    Same geometry as :class:`Counterflow` with ``right_fraction`` 0.8 on a 12 m street. The
    low contrast to the ground of the papers' commuter sequence is a rendering setting (the
    ``contrast`` knob of the sequence spec, e.g. ``ucf9/seq1``), not part of the simulation.
    """

    n_agents: int = 150
    density: float = 2.0
    width: float = 12.0
    right_fraction: float = 0.8
    name: ClassVar[str] = "commuters"


@dataclass(frozen=True)
class Groups(Scenario):
    """Unidirectional corridor in which 2-5-person groups keep formation (Moussaïd 2010).

    ``group_fraction`` of the agents walk in groups of ``group_size`` (inclusive range) people;
    members share one desired speed (the group walks together) and start near each other
    (consecutive places of a grid ordered along the corridor, so some members start a few
    metres apart; the group terms gather them in the first seconds).

    Extra attributes: ``width`` (m), ``group_fraction``, ``group_size``.
    """

    width: float = 8.0
    group_fraction: float = 0.6
    group_size: tuple[int, int] = (2, 5)
    name: ClassVar[str] = "groups"

    def validate(self) -> None:
        self._sizes("width")
        self._fraction("group_fraction")
        lo, hi = self.group_size
        if not 2 <= lo <= hi <= 10:
            raise ValueError(
                f"groups.group_size must satisfy 2 <= low <= high <= 10, got {self.group_size}"
            )

    def build(self, rng: np.random.Generator) -> Setup:
        n, w = self.n_agents, self.width
        pos = hex_positions(rng, n, 0.0, 0.0, w, self.density, self.radius[1])
        length = max(float(pos[:, 0].max()) + 1.0, 4.0)
        margin = 6.0
        world = _corridor_world(length, w, margin)
        v0 = WALKERS.sample(rng, n)
        # Groups are consecutive lattice sites, sorted by position so that members are close.
        order = np.lexsort((pos[:, 1], np.round(pos[:, 0] / 1.5)))
        group = np.full(n, -1, np.int64)
        in_groups = int(round(self.group_fraction * n))
        k, gid = 0, 0
        while k < in_groups:
            size = int(rng.integers(self.group_size[0], self.group_size[1] + 1))
            size = min(size, in_groups - k)
            if size < 2:
                break
            members = order[k : k + size]
            group[members] = gid
            v0[members] = v0[members].mean()
            k += size
            gid += 1
        agents = AgentBatch.create(
            pos, self._radii(rng, n), v0, 0, rng, self.prominent_fraction, group=group
        )
        routes = [Route([_end_gate(length + margin, w)])]
        return Setup(world, routes, agents, [], {"length": length, "width": w, "groups": gid})


@dataclass(frozen=True)
class Anomalies(Scenario):
    """A street flow towards +x in which a fraction of people behaves abnormally.

    Kinds (``ANOMALY_KINDS``): ``against`` walks against the flow, ``stop`` stands still for
    3-8 s from 0.5-4 s after the start (a spec's first frame: a sequence's warm-up is not
    counted; its desired speed is 0, nothing holds it in place: passers-by push it along, and
    it drifts with them), ``cross`` crosses to the other side of the street, ``leave`` leaves
    the flow through a side exit in the middle of the street. Only the starting crowd has
    anomalies: the inflow brings ordinary walkers.

    Extra attributes: ``width`` (m), ``anomaly_fraction``, ``kinds`` (names to use).
    """

    width: float = 10.0
    anomaly_fraction: float = 0.05
    kinds: tuple[str, ...] = ("against", "stop", "cross", "leave")
    name: ClassVar[str] = "anomalies"

    def validate(self) -> None:
        self._sizes("width")
        self._fraction("anomaly_fraction")
        bad = [k for k in self.kinds if k not in ANOMALY_KINDS[1:]]
        if bad or not self.kinds:
            raise ValueError(
                f"anomalies.kinds must be a non-empty subset of "
                f"{ANOMALY_KINDS[1:]}, got {self.kinds!r}"
            )

    def build(self, rng: np.random.Generator) -> Setup:
        n, w = self.n_agents, self.width
        pos = hex_positions(rng, n, 0.0, 0.0, w, self.density, self.radius[1])
        length = max(float(pos[:, 0].max()) + 1.0, 8.0)
        margin = 6.0
        mid = length / 2
        exit_w = 2.0
        # Street walls with a side exit (a gap in the upper wall and a short lane out).
        walls = np.vstack(
            [
                polyline([(-margin, 0.0), (length + margin, 0.0)]),
                polyline([(-margin, w), (mid - exit_w / 2, w), (mid - exit_w / 2, w + 4.0)]),
                polyline(
                    [(mid + exit_w / 2, w + 4.0), (mid + exit_w / 2, w), (length + margin, w)]
                ),
            ]
        )
        world = World(walls, (-margin - 2.0, -1.0, length + margin + 2.0, w + 5.0))
        end, start = _end_gate(length + margin, w), _end_gate(-margin, w)
        side = [mid - exit_w / 2 + 0.4, w + 0.5, mid + exit_w / 2 - 0.4, w + 0.5]
        side_out = [mid - exit_w / 2 + 0.4, w + 3.5, mid + exit_w / 2 - 0.4, w + 3.5]
        routes = [Route([end]), Route([start]), Route([side, side_out])]
        route = np.zeros(n, np.int64)
        wp = np.zeros(n, np.int64)
        anomaly = np.zeros(n, np.int8)
        chosen = rng.permutation(n)[: int(round(self.anomaly_fraction * n))]
        kind_codes = np.array([ANOMALY_KINDS.index(k) for k in self.kinds], np.int8)
        anomaly[chosen] = rng.choice(kind_codes, len(chosen))
        v0 = WALKERS.sample(rng, n)
        route[anomaly == ANOMALY_KINDS.index("against")] = 1
        route[anomaly == ANOMALY_KINDS.index("leave")] = 2
        agents = AgentBatch.create(
            pos,
            self._radii(rng, n),
            v0,
            route,
            rng,
            self.prominent_fraction,
            waypoint=wp,
            anomaly=anomaly,
        )
        # Crossers: a personal route to the opposite side 4 m ahead, then on to the end.
        crossers = np.flatnonzero(anomaly == ANOMALY_KINDS.index("cross"))
        for i in crossers:
            x, y = pos[i]
            ty = 0.6 if y > w / 2 else w - 0.6
            routes.append(Route([[x + 4.0, ty, x + 4.0, ty], end]))
            agents.route[i] = len(routes) - 1
        stoppers = anomaly == ANOMALY_KINDS.index("stop")
        agents.stop_start[stoppers] = rng.uniform(0.5, 4.0, int(stoppers.sum()))
        agents.stop_end[stoppers] = agents.stop_start[stoppers] + rng.uniform(
            3.0, 8.0, int(stoppers.sum())
        )
        flow = self.density * float(weidmann_speed(self.density)) * w
        sources = [Source((-margin, 0.3, -margin + 1.5, w - 0.3), flow, 0)]
        return Setup(world, routes, agents, sources, {"length": length, "width": w})


@dataclass(frozen=True)
class Marathon(Scenario):
    """Dense runners on a road with a bend.

    Runners (desired speeds 2.5-4.5 m/s, mean about 2.9) start packed at ``density`` on a
    road of ``road_width``; the road runs straight, turns left by ``bend_deg`` around an
    inner radius ``bend_radius`` and runs straight again to the finish (a sink). A source at
    the start keeps runners coming at ``inflow_fraction`` of the starting flow.

    Extra attributes: ``road_width``, ``bend_deg``, ``bend_radius`` (m), ``inflow_fraction``.
    """

    n_agents: int = 175
    density: float = 2.5
    road_width: float = 10.0
    bend_deg: float = 90.0
    bend_radius: float = 6.0
    inflow_fraction: float = 0.5
    name: ClassVar[str] = "marathon"

    def validate(self) -> None:
        self._sizes("road_width", "bend_radius")
        self._fraction("inflow_fraction")
        if not 0 <= self.bend_deg <= 180:
            raise ValueError(f"marathon.bend_deg must be in [0, 180], got {self.bend_deg}")

    def build(self, rng: np.random.Generator) -> Setup:
        n, w = self.n_agents, self.road_width
        # Runners fill [-pack, 0] and run towards +x; the bend starts 15 m after the pack.
        pos = hex_positions(rng, n, 0.0, 0.0, w, self.density, self.radius[1], direction=-1.0)
        pack = float(-pos[:, 0].min()) + 1.0
        x_start, x_bend = -pack - 6.0, 15.0
        theta = math.radians(self.bend_deg)
        r_in, r_out = self.bend_radius, self.bend_radius + w
        cx, cy = x_bend, w + r_in  # bend centre (left turn)
        seg = max(2, int(math.ceil(self.bend_deg / 10)))
        inner = arc(cx, cy, r_in, -math.pi / 2, -math.pi / 2 + theta, seg)
        outer = arc(cx, cy, r_out, -math.pi / 2, -math.pi / 2 + theta, seg)
        straight2 = 25.0
        t_dir = np.array([math.cos(theta), math.sin(theta)])
        inner_end = inner[-1] + straight2 * t_dir
        outer_end = outer[-1] + straight2 * t_dir
        walls = np.vstack(
            [
                polyline(np.vstack([[(x_start, w)], inner, [inner_end]])),
                polyline(np.vstack([[(x_start, 0.0)], outer, [outer_end]])),
            ]
        )
        # Gates: radial segments through the bend, then the finish line.
        gates = []
        for a in np.linspace(0.0, theta, seg + 1)[1:]:
            ang = -math.pi / 2 + a
            u = np.array([math.cos(ang), math.sin(ang)])
            centre = np.array([cx, cy])
            gates.append([*(centre + (r_in + 0.5) * u), *(centre + (r_out - 0.5) * u)])
        if self.bend_deg == 0:
            gates = []
        gates.append([*(inner_end - 0.5 * t_dir), *(outer_end - 0.5 * t_dir)])
        pts = np.vstack([walls[:, :2], walls[:, 2:4]])
        bounds = (
            float(pts[:, 0].min()) - 1,
            float(pts[:, 1].min()) - 1,
            float(pts[:, 0].max()) + 1,
            float(pts[:, 1].max()) + 1,
        )
        world = World(walls, bounds)
        # Runners cut the bend: the first gate is reached along the road.
        agents = AgentBatch.create(
            pos, self._radii(rng, n), RUNNERS.sample(rng, n), 0, rng, self.prominent_fraction
        )
        flow = self.inflow_fraction * self.density * RUNNERS.mean * w * 0.5
        sources = [Source((x_start, 0.3, x_start + 2.0, w - 0.3), flow, 0, speeds=RUNNERS)]
        info = {"road_width": w, "pack_length": pack}
        return Setup(world, [Route(np.array(gates), reach=1.0)], agents, sources, info)


@dataclass(frozen=True)
class Crossing(Scenario):
    """Two opposing flows over a street crossing (zebra crossing).

    Half the people wait on each kerb, packed at ``density`` in a band as wide as the
    crossing, cross the street (``street_width`` m) and walk on past the other side's queue
    before they leave. The crossing itself has no walls.

    Extra attributes: ``street_width``, ``crossing_width`` (m).
    """

    n_agents: int = 57
    density: float = 1.5
    street_width: float = 10.0
    crossing_width: float = 6.0
    name: ClassVar[str] = "crossing"

    def validate(self) -> None:
        self._sizes("street_width", "crossing_width")

    def build(self, rng: np.random.Generator) -> Setup:
        n, sw, cw = self.n_agents, self.street_width, self.crossing_width
        n_up = n // 2 + (n % 2) * int(rng.integers(0, 2))
        n_down = n - n_up
        # hex_positions fills a band along x; build along x then rotate into y.
        up = hex_positions(rng, n_up, 0.0, 0.0, cw, self.density, self.radius[1], direction=-1.0)
        down = hex_positions(rng, n_down, 0.0, 0.0, cw, self.density, self.radius[1])
        up = np.column_stack([up[:, 1], up[:, 0] - 0.5])
        down = np.column_stack([down[:, 1], sw + 0.5 + down[:, 0]])
        pos = np.vstack([up, down])
        far = (
            max(
                float(-up[:, 1].min()) if n_up else 0.0,
                float(down[:, 1].max() - sw) if n_down else 0.0,
            )
            + 3.0
        )
        # Kerb walls leave the crossing open.
        walls = np.vstack(
            [
                polyline([(-10.0, 0.0), (-0.5, 0.0)]),
                polyline([(cw + 0.5, 0.0), (cw + 10.0, 0.0)]),
                polyline([(-10.0, sw), (-0.5, sw)]),
                polyline([(cw + 0.5, sw), (cw + 10.0, sw)]),
            ]
        )
        # Walkers leave beyond the opposite queue, outside the area a camera frames.
        world = World(
            walls, (-10.0, -far - EXIT_DISTANCE - 1.0, cw + 10.0, sw + far + EXIT_DISTANCE + 1.0)
        )
        routes = [
            Route(
                [
                    [0.3, sw + 0.5, cw - 0.3, sw + 0.5],
                    [0.3, sw + far + EXIT_DISTANCE, cw - 0.3, sw + far + EXIT_DISTANCE],
                ],
                reach=0.4,
            ),
            Route(
                [
                    [0.3, -0.5, cw - 0.3, -0.5],
                    [0.3, -far - EXIT_DISTANCE, cw - 0.3, -far - EXIT_DISTANCE],
                ],
                reach=0.4,
            ),
        ]
        route = np.r_[np.zeros(n_up, np.int64), np.ones(n_down, np.int64)]
        agents = AgentBatch.create(
            pos, self._radii(rng, n), WALKERS.sample(rng, n), route, rng, self.prominent_fraction
        )
        return Setup(world, routes, agents, [], {"street_width": sw, "crossing_width": cw})


@dataclass(frozen=True)
class Circulation(Scenario):
    """Hajj-like rotation: a dense crowd circles counter-clockwise around a central block.

    The crowd fills an annulus around a square block of side ``block_side`` at ``density``;
    the outer radius follows from the agent count. Radial gates every 15° keep everyone
    turning; nobody enters or leaves.

    Extra attributes: ``block_side`` (m), ``speed_mean`` (m/s).
    """

    n_agents: int = 235
    density: float = 3.0
    block_side: float = 8.0
    speed_mean: float = 1.0
    name: ClassVar[str] = "circulation"

    def validate(self) -> None:
        self._sizes("block_side")
        require_number(self.name, "speed_mean", self.speed_mean, lo=0, hi=MAX_SPEED, lo_open=True)

    def build(self, rng: np.random.Generator) -> Setup:
        n = self.n_agents
        r_in = self.block_side / math.sqrt(2) + 0.8
        r_out = math.sqrt(n / (self.density * math.pi) + r_in**2) + 0.6
        # Place on concentric rings at the requested density; below 62 % coverage, shake
        # them into a relaxed random packing inside the annulus (cf. hex_positions).
        a = 1.0 / math.sqrt(self.density)
        pos_list = []
        r = r_in + self.radius[1] + 0.05
        while sum(len(p) for p in pos_list) < n:
            k = max(1, int(2 * math.pi * r / a))
            ang = rng.uniform(0, 2 * math.pi) + np.arange(k) * 2 * math.pi / k
            pos_list.append(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))
            r += a
        pos = np.vstack(pos_list)
        pos = pos[rng.permutation(len(pos))[:n]]
        r_out = max(r_out, r + 0.3 - a)
        r_lo, r_hi = r_in + self.radius[1] + 0.05, r_out - self.radius[1] - 0.05
        if self.density * math.pi * self.radius[1] ** 2 <= 0.62:
            rings = pos  # a spacing of a >= 2.25 radii: nobody overlaps
            rad = np.sqrt(rng.uniform(r_lo**2, r_hi**2, n))
            ang = rng.uniform(0, 2 * math.pi, n)
            pos = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
            for _ in range(20):
                pos = relax_overlaps(pos, 2 * self.radius[1] + 0.02, -r_hi, r_hi, max_iter=20)
                rad = np.hypot(pos[:, 0], pos[:, 1])
                pos *= (np.clip(rad, r_lo, r_hi) / np.maximum(rad, 1e-9))[:, None]
            # An annulus narrower than two people (a few agents around the block) can jam
            # the shaken packing, the radial clip pushing back what the relaxation spread
            # (34 agents at density 3, seed 65537: two people 0.28 m apart). Where two may
            # overlap by more than a fifth of the smallest radius, keep the rings.
            from scipy.spatial import cKDTree

            r_min, r_max = self.radius
            if len(cKDTree(pos).query_pairs(2 * r_max - 0.2 * r_min)):
                pos = rings
        h = self.block_side / 2
        walls = np.vstack([rectangle(-h, -h, h, h), polyline(arc(0, 0, r_out, 0, 2 * math.pi, 72))])
        world = World(walls, (-r_out - 1, -r_out - 1, r_out + 1, r_out + 1))
        n_gates = 24
        ang = np.arange(n_gates) * 2 * math.pi / n_gates
        gates = np.column_stack(
            [
                r_in * np.cos(ang),
                r_in * np.sin(ang),
                (r_out - 0.3) * np.cos(ang),
                (r_out - 0.3) * np.sin(ang),
            ]
        )
        theta = np.arctan2(pos[:, 1], pos[:, 0]) % (2 * math.pi)
        wp = (np.floor(theta / (2 * math.pi / n_gates)).astype(np.int64) + 1) % n_gates
        speeds = SpeedDistribution(
            self.speed_mean, 0.2 * self.speed_mean, 0.3 * self.speed_mean, 2.0 * self.speed_mean
        )
        agents = AgentBatch.create(
            pos,
            self._radii(rng, n),
            speeds.sample(rng, n),
            0,
            rng,
            self.prominent_fraction,
            waypoint=wp,
        )
        routes = [Route(gates, loop=True, reach=0.3)]
        return Setup(world, routes, agents, [], {"inner_radius": r_in, "outer_radius": r_out})


@dataclass(frozen=True)
class Station(Scenario):
    """A station hall at medium density with ``n_doors`` doors, each a source and a sink.

    People walk from their door to another, random door, around a grid of pillars. They
    leave 3 m outside a door and arrive 1.5-3 m outside one (so that in a video framed on
    the hall they walk in and out across the frame's border); arrivals replace those who
    leave, so the population stays near ``n_agents`` (73 people at 0.5 /m^2: 90-105 over
    the first 90 s, none outside the walls).

    Extra attributes: ``n_doors``, ``door_width`` (m), ``pillar_spacing`` (m, 0 = none),
    ``routes``: the route layout. 2 (the default): an arrival's route starts 1 m inside its
    door, and the arrival rate counts the walk outside the hall. 1: the layout before
    2026-11-27, which the ``ucf9`` and ``galleria`` station specs keep so that their
    calibrated sequences stay the same: a door counted as passed 0.6 m before it, from
    outside, so arrivals headed for the next door along the outside of the walls (up to 27
    people at once on ``ucf9``'s seq7), and the rate left that walk out, so the population
    grew (seq7: 87 people on its first frame, 111 on its last; 73 people became about 145).
    With many people (150 at 0.5 /m^2) two-way flow through the 3 m doors still jams, and
    the population grows with either layout.

    The initial people are thrown at random at least ``2 radius[1] + 0.05`` m apart: a dense
    request that does not fit (1,000 people at 1.5 /m^2, 200 at 2 /m^2) raises
    ``ValueError`` naming the density, where it had placed fewer people than ``n_agents``
    in silence. About 1 /m^2 fits at any ``n_agents``.
    """

    n_agents: int = 73
    density: float = 0.5
    n_doors: int = 4
    door_width: float = 3.0
    pillar_spacing: float = 8.0
    routes: int = 2
    name: ClassVar[str] = "station"

    def validate(self) -> None:
        self._sizes("door_width")
        if self.routes not in (1, 2):
            raise ValueError(f"station.routes must be 1 or 2, got {self.routes}")
        if not 2 <= self.n_doors <= 8:
            raise ValueError(f"station.n_doors must be in [2, 8], got {self.n_doors}")
        lo = PILLAR_SIDE + 2 * self.radius[1] + 0.1  # the widest person between two pillars
        require_number("station", "pillar_spacing", self.pillar_spacing, lo=0)
        if 0 < self.pillar_spacing < lo:
            raise ValueError(
                f"station.pillar_spacing must be 0 (no pillars) or >= {lo:g} m (room for a "
                f"person between two {PILLAR_SIDE:g} m pillars), got {self.pillar_spacing}"
            )

    def _doors(self, side: float) -> np.ndarray:
        """``(n_doors, 4)`` door segments spread over the four walls, and their out-normals."""
        doors = []
        for k in range(self.n_doors):
            wall = k % 4
            slot = k // 4
            per_wall = (self.n_doors - wall + 3) // 4
            c = side * (slot + 1) / (per_wall + 1)
            h = self.door_width / 2
            if wall == 0:
                doors.append([c - h, 0.0, c + h, 0.0, 0.0, -1.0])
            elif wall == 1:
                doors.append([side, c - h, side, c + h, 1.0, 0.0])
            elif wall == 2:
                doors.append([c + h, side, c - h, side, 0.0, 1.0])
            else:
                doors.append([0.0, c + h, 0.0, c - h, -1.0, 0.0])
        return np.array(doors)

    def build(self, rng: np.random.Generator) -> Setup:
        n = self.n_agents
        side = max(math.sqrt(n / self.density), self.door_width * 2 + 4.0)
        doors = self._doors(side)
        corners = np.array([(0, 0), (side, 0), (side, side), (0, side)], dtype=np.float64)
        walls = []
        for wall in range(4):  # each wall from corner to corner, with gaps at its doors
            a, b = corners[wall], corners[(wall + 1) % 4]
            u = (b - a) / side
            centres = sorted(float(np.dot((d[:2] + d[2:4]) / 2 - a, u)) for d in doors[wall::4])
            t = 0.0
            for c in centres:
                walls.append(polyline([a + t * u, a + (c - self.door_width / 2) * u]))
                t = c + self.door_width / 2
            walls.append(polyline([a + t * u, b]))
        if self.pillar_spacing > 0:
            sp = self.pillar_spacing
            k = max(0, math.ceil((side - 1.0 - sp) / sp))  # pillars a row
            require_memory(
                f"station: {k} x {k} pillars (pillar_spacing {sp:g} m in a hall of {side:.4g} m)",
                8.0 * k * k * 4 * (5 + 4),  # 4 segments each, and their wall-grid entries
            )
            ticks = np.arange(sp, side - 1.0, sp)
            px, py = (t.ravel() for t in np.meshgrid(ticks, ticks, indexing="ij"))
            h = PILLAR_SIDE / 2
            offsets = np.column_stack([px, py, px, py, np.zeros(len(px))])
            walls.append((rectangle(-h, -h, h, h)[None] + offsets[:, None]).reshape(-1, 5))
        walls = np.vstack(walls)
        world = World(
            walls,
            (
                -EXIT_DISTANCE - 1,
                -EXIT_DISTANCE - 1,
                side + EXIT_DISTANCE + 1,
                side + EXIT_DISTANCE + 1,
            ),
        )
        # Route j: through door j and on to 3 m outside it (where walkers vanish). Route
        # n_doors + k * n_doors + j: enter through door k first (people arriving outside it).
        gate_in = doors[:, :4]
        gate_out = gate_in + np.tile(doors[:, 4:6] * EXIT_DISTANCE, 2)
        routes = [
            Route(np.array([gate_in[j], gate_out[j]]), reach=0.6) for j in range(self.n_doors)
        ]
        # A gate counts as passed within ``reach`` of it, from either side: an arrival's
        # first gate lies 1 m inside its door (layout 2), or a walker outside would count
        # the door as passed and head for the next one straight through the wall (layout 1)
        inside = 1.0 if self.routes == 2 else 0.0
        gate_entry = gate_in - np.tile(doors[:, 4:6] * inside, 2)
        routes += [
            Route(np.array([gate_entry[k], gate_in[j], gate_out[j]]), reach=0.6)
            for k in range(self.n_doors)
            for j in range(self.n_doors)
        ]
        # Initial people: uniform in the hall (away from pillars), each bound for a random door.
        cand = rng.uniform(0.6, side - 0.6, (4 * n + 16, 2))
        if self.pillar_spacing > 0:
            near = np.abs(
                ((cand + self.pillar_spacing / 2) % self.pillar_spacing) - self.pillar_spacing / 2
            )
            cand = cand[~np.all(near < 0.9, axis=1)]
        dmin = 2 * self.radius[1] + 0.05
        pos = _thin_to_min_distance(cand, dmin, n)
        if len(pos) < n:  # it had started the run with fewer people, the table saying n's density
            raise ValueError(
                f"station.density {self.density:g} /m² is too high for n_agents {n}: only "
                f"{len(pos)} people fit in the hall at least {dmin:g} m apart, away from the "
                "pillars; lower the density (about 1 /m² fits at any n_agents)"
            )
        route = rng.integers(0, self.n_doors, len(pos))
        agents = AgentBatch.create(
            pos,
            self._radii(rng, len(pos)),
            WALKERS.sample(rng, len(pos)),
            route,
            rng,
            self.prominent_fraction,
        )
        # a visit's length: across the hall, and (layout 2) from 1.5-3 m outside the entry
        # door in and on to 3 m outside the exit
        outside = (1.5 + EXIT_DISTANCE) / 2 + EXIT_DISTANCE if self.routes == 2 else 0.0
        trip = (side + outside) / WALKERS.mean
        sources = []
        for k, d in enumerate(doors):
            # People arrive 1.5-3 m outside the door (out of the camera's view) and walk in.
            normal = d[4:6]
            along = (d[2:4] - d[:2]) / self.door_width
            corners_out = np.array(
                [d[:2] + 0.3 * along + 1.5 * normal, d[2:4] - 0.3 * along + EXIT_DISTANCE * normal]
            )
            lo, hi = corners_out.min(axis=0), corners_out.max(axis=0)
            dest = [j for j in range(self.n_doors) if j != k]
            rate = n / trip / self.n_doors / len(dest)
            for j in dest:
                sources.append(
                    Source(
                        (lo[0], lo[1], hi[0], hi[1]),
                        rate,
                        self.n_doors + k * self.n_doors + j,
                        heading=(float(-normal[0]), float(-normal[1])),
                    )
                )
        return Setup(world, routes, agents, sources, {"side": side, "doors": doors[:, :4]})


def _thin_to_min_distance(cand: np.ndarray, dmin: float, n: int) -> np.ndarray:
    """Greedy dart throwing: keep candidates at least ``dmin`` apart, up to ``n`` of them."""
    from scipy.spatial import cKDTree

    tree = cKDTree(cand)
    keep = np.ones(len(cand), dtype=bool)
    pairs = tree.query_pairs(dmin, output_type="ndarray")
    # Drop the later point of each close pair (deterministic, candidate order is random).
    for i, j in pairs[np.argsort(pairs[:, 0], kind="stable")]:
        if keep[i] and keep[j]:
            keep[j] = False
    return cand[keep][:n]


SCENARIOS: dict[str, type[Scenario]] = {
    cls.name: cls
    for cls in (Marathon, Counterflow, Groups, Anomalies, Crossing, Circulation, Station, Commuters)
}
"""Scenario name -> class."""


def make_scenario(name: str, **params: Any) -> Scenario:
    """Build a scenario by name; unknown names and parameters raise ``ValueError``."""
    try:
        cls = SCENARIOS[name]
    except KeyError:
        raise ValueError(
            f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}"
        ) from None
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(
            f"unknown parameter(s) for scenario {name!r}: {', '.join(unknown)}; "
            f"known: {', '.join(known)}"
        )
    for key, value in params.items():
        default = getattr(cls, key, None)
        if isinstance(default, tuple) and isinstance(value, list):
            params[key] = tuple(value)
    return cls(**params)
