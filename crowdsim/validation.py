"""Validation against real crowds: fundamental diagram, lane formation, sanity checks.

* :func:`fundamental_diagram` runs unidirectional periodic corridors at given densities and
  measures density and speed with PedPy (classic density and mean speed in a measurement
  area in the middle of the corridor), next to Weidmann's curve.
* :func:`lane_order_parameter` measures lane formation in counterflow (Rex & Löwen 2007
  style): for each agent, ``phi_i = ((n_same - n_opp) / (n_same + n_opp))^2`` over the agents
  in a thin band along its walking axis; the mean is 1 for perfect lanes and about
  ``1 / (neighbours in the band)`` for a random mix, which :func:`random_mix_lane_order`
  estimates on the same positions by shuffling the walking directions.
* :func:`max_overlap` returns the deepest body overlap as a fraction of the smaller radius.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from crowdsim.params import SocialForceParams
from crowdsim.scenarios import make_scenario, weidmann_speed
from crowdsim.simulation import Simulation


def max_overlap(pos: np.ndarray, radius: np.ndarray, period: float = 0.0) -> float:
    """Deepest pairwise overlap ``(r_i + r_j - d_ij) / min(r_i, r_j)`` (0 if none).

    Parameters
    ----------
    pos : (n, 2) m; radius : (n,) m; period : periodic x length in m (0 = none).
    """
    if len(pos) < 2:
        return 0.0
    rmax = float(radius.max())
    if period > 0:
        span = float(pos[:, 1].max() - pos[:, 1].min()) + 4 * rmax + 1.0
        shifted = np.column_stack([pos[:, 0] % period, pos[:, 1] - pos[:, 1].min()])
        tree = cKDTree(shifted, boxsize=[period, span])
        pairs = tree.query_pairs(2 * rmax, output_type="ndarray")
        d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
        d[:, 0] -= period * np.round(d[:, 0] / period)
    else:
        tree = cKDTree(pos)
        pairs = tree.query_pairs(2 * rmax, output_type="ndarray")
        d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
    if len(pairs) == 0:
        return 0.0
    dist = np.hypot(d[:, 0], d[:, 1])
    depth = radius[pairs[:, 0]] + radius[pairs[:, 1]] - dist
    rel = depth / np.minimum(radius[pairs[:, 0]], radius[pairs[:, 1]])
    return float(max(0.0, rel.max()))


def lane_order_parameter(
    pos: np.ndarray, sign: np.ndarray, band: float = 0.3, window: float = 5.0, period: float = 0.0
) -> float:
    """Mean lane order ``<phi_i>`` for walkers along x with directions ``sign`` (+1/-1).

    Neighbours of ``i`` are agents with ``|dy| < band`` and ``|dx| < window``; agents with no
    neighbour are skipped. Returns NaN if nobody has a neighbour.
    """
    if len(pos) < 2:
        return float("nan")
    tree = cKDTree(
        pos if period <= 0 else np.column_stack([pos[:, 0] % period, pos[:, 1] - pos[:, 1].min()]),
        boxsize=None if period <= 0 else [period, float(np.ptp(pos[:, 1])) + 2 * window + 1],
    )
    pairs = tree.query_pairs(np.hypot(window, band), output_type="ndarray")
    if len(pairs) == 0:
        return float("nan")
    d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
    if period > 0:
        d[:, 0] -= period * np.round(d[:, 0] / period)
    keep = (np.abs(d[:, 1]) < band) & (np.abs(d[:, 0]) < window)
    i, j = pairs[keep, 0], pairs[keep, 1]
    same = (sign[i] == sign[j]).astype(np.float64)
    n = len(pos)
    n_same = np.bincount(i, same, n) + np.bincount(j, same, n)
    n_all = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    has = n_all > 0
    if not has.any():
        return float("nan")
    phi = ((2 * n_same[has] - n_all[has]) / n_all[has]) ** 2
    return float(phi.mean())


def random_mix_lane_order(
    pos: np.ndarray, sign: np.ndarray, rng: np.random.Generator, repeats: int = 20, **kw: float
) -> float:
    """Lane order of the same positions with walking directions shuffled (random mix)."""
    return float(
        np.nanmean([lane_order_parameter(pos, rng.permutation(sign), **kw) for _ in range(repeats)])
    )


@dataclass
class FDPoint:
    """One point of the fundamental diagram."""

    target_density: float
    global_density: float
    density: float
    speed: float
    weidmann: float
    max_overlap: float

    @property
    def ratio(self) -> float:
        return self.speed / self.weidmann if self.weidmann > 0 else float("nan")


def periodic_corridor(
    density: float,
    length: float,
    width: float,
    right_fraction: float = 1.0,
    seed: int = 0,
    params: SocialForceParams | None = None,
) -> Simulation:
    """A periodic corridor filled at ``density`` (the scenario used by the validations)."""
    n = max(2, int(round(density * length * width)))
    sc = make_scenario(
        "counterflow",
        n_agents=n,
        density=density,
        width=width,
        right_fraction=right_fraction,
        periodic=True,
        inflow=False,
    )
    return Simulation(sc, seed=seed, params=params)


def fundamental_diagram(
    densities: list[float],
    length: float = 20.0,
    width: float = 5.0,
    warmup_s: float = 20.0,
    measure_s: float = 20.0,
    seed: int = 0,
    params: SocialForceParams | None = None,
    progress: bool = False,
) -> list[FDPoint]:
    """Speed-density points of unidirectional periodic corridors, measured with PedPy.

    Each corridor walks ``warmup_s`` seconds, then ``measure_s`` seconds are recorded. PedPy
    computes the classic density and the mean individual speed (``frame_step`` 5) in a 4 m
    long measurement area in the middle of the corridor. Periodic wrapping is handled by
    giving each lap of an agent its own PedPy id.
    """
    import pandas as pd
    import pedpy

    points = []
    it = densities
    if progress:
        from crowdsim.progress import progress_bar

        it = progress_bar(densities, desc="fundamental diagram", unit="density", leave=True)
    for rho in it:
        sim = periodic_corridor(rho, length, width, seed=seed, params=params)
        period = sim.world.period
        dt = sim.params.dt
        sim.run(int(round(warmup_s / dt)))
        n_meas = int(round(measure_s / dt))
        xs = np.empty((n_meas, sim.state.n))
        ys = np.empty_like(xs)
        overlap = 0.0
        ids = sim.state.ids.copy()
        for t in range(n_meas):
            sim.step()
            if not np.array_equal(sim.state.ids, ids):
                raise RuntimeError("agents left a periodic corridor")
            xs[t], ys[t] = sim.state.pos[:, 0], sim.state.pos[:, 1]
            if t % 25 == 0:
                overlap = max(overlap, max_overlap(sim.state.pos, sim.state.radius, period))
        lap = np.vstack(
            [
                np.zeros((1, len(ids)), np.int64),
                np.cumsum(np.abs(np.diff(xs, axis=0)) > period / 2, axis=0),
            ]
        )
        frames = np.broadcast_to(np.arange(n_meas)[:, None], xs.shape)
        df = pd.DataFrame(
            {
                "id": (ids[None, :] * 10_000 + lap).ravel(),
                "frame": frames.ravel(),
                "x": xs.ravel(),
                "y": ys.ravel(),
            }
        )
        traj = pedpy.TrajectoryData(data=df, frame_rate=1.0 / dt)
        x0 = period / 2 - 2.0
        area = pedpy.MeasurementArea(
            [(x0, 0.0), (x0 + 4.0, 0.0), (x0 + 4.0, sim.info["width"]), (x0, sim.info["width"])]
        )
        dens = pedpy.compute_classic_density(traj_data=traj, measurement_area=area)
        ind = pedpy.compute_individual_speed(
            traj_data=traj,
            frame_step=5,
            speed_calculation=pedpy.SpeedCalculation.BORDER_SINGLE_SIDED,
        )
        speed = pedpy.compute_mean_speed_per_frame(
            traj_data=traj, individual_speed=ind, measurement_area=area
        )
        d = float(dens["density"].mean())
        points.append(
            FDPoint(
                target_density=rho,
                global_density=len(ids) / (period * width),
                density=d,
                speed=float(speed["speed"].mean()),
                weidmann=float(weidmann_speed(d)),
                max_overlap=overlap,
            )
        )
    return points


def lane_formation(
    n_agents: int = 240,
    density: float = 1.0,
    width: float = 6.0,
    seconds: float = 40.0,
    every_s: float = 2.0,
    seed: int = 0,
    params: SocialForceParams | None = None,
) -> dict[str, list[float]]:
    """Lane order over time in a periodic counterflow corridor, and the random-mix level."""
    sc = make_scenario(
        "counterflow",
        n_agents=n_agents,
        density=density,
        width=width,
        right_fraction=0.5,
        periodic=True,
        inflow=False,
    )
    sim = Simulation(sc, seed=seed, params=params, record=False)
    sign = np.where(sim.state.route == 0, 1, -1)
    period = sim.world.period
    rng = np.random.default_rng(seed)
    every = max(1, int(round(every_s / sim.params.dt)))
    times, order, mix = [], [], []
    for k in range(int(round(seconds / sim.params.dt)) + 1):
        if k % every == 0:
            times.append(sim.time)
            order.append(lane_order_parameter(sim.state.pos, sign, period=period))
            mix.append(random_mix_lane_order(sim.state.pos, sign, rng, period=period))
        sim.step()
    return {"time": times, "lane_order": order, "random_mix": mix}
