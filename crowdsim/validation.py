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
* :func:`split_validation` checks that splitting the simulator across worker processes
  (``Simulation(..., workers=N)``) changes no physics: speed-density points, overlaps and
  lane order at each worker count next to the one-process run and its seed-to-seed spread.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

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
    return overlap_stats(pos, radius, period)[1]


def overlap_stats(pos: np.ndarray, radius: np.ndarray, period: float = 0.0) -> tuple[float, float]:
    """Mean and deepest overlap ``(r_i + r_j - d_ij) / min(r_i, r_j)`` over the overlapping
    pairs (``(0, 0)`` if none); arguments as :func:`max_overlap`."""
    if len(pos) < 2:
        return 0.0, 0.0
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
        return 0.0, 0.0
    dist = np.hypot(d[:, 0], d[:, 1])
    depth = radius[pairs[:, 0]] + radius[pairs[:, 1]] - dist
    rel = depth / np.minimum(radius[pairs[:, 0]], radius[pairs[:, 1]])
    rel = rel[rel > 0]
    return (float(rel.mean()), float(rel.max())) if len(rel) else (0.0, 0.0)


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


FD_SPEED_FRAME_STEP = 5
"""PedPy's ``frame_step`` for the fundamental diagram's individual speeds: a speed needs
frames ``t`` and ``t + 5``, so a measurement shorter than 6 frames has none."""


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
    record: bool = True,
    *,
    workers: int = 1,
) -> Simulation:
    """A periodic corridor filled at ``density`` (the scenario used by the validations),
    stepped by ``workers`` processes."""
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
    return Simulation(sc, seed=seed, params=params, record=record, workers=workers)


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
    giving each lap of an agent its own PedPy id. A ``measure_s`` shorter than
    ``FD_SPEED_FRAME_STEP + 1`` steps raises ``ValueError`` (it gave a NaN speed, or a
    pandas error with no frame at all).
    """
    import pandas as pd
    import pedpy

    dt = (params or SocialForceParams()).dt
    frames = int(round(measure_s / dt))
    if frames < FD_SPEED_FRAME_STEP + 1:
        raise ValueError(
            f"measure_s must cover at least {FD_SPEED_FRAME_STEP + 1} steps of {dt:g} s "
            f"(PedPy's speeds span {FD_SPEED_FRAME_STEP}), got {measure_s:g} s ({frames} steps)"
        )

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
            frame_step=FD_SPEED_FRAME_STEP,
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
    *,
    workers: int = 1,
) -> dict[str, list[float]]:
    """Lane order over time in a periodic counterflow corridor, and the random-mix level
    (``workers`` processes step the corridor)."""
    sc = make_scenario(
        "counterflow",
        n_agents=n_agents,
        density=density,
        width=width,
        right_fraction=0.5,
        periodic=True,
        inflow=False,
    )
    sim = Simulation(sc, seed=seed, params=params, record=False, workers=workers)
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
    sim.close()
    return {"time": times, "lane_order": order, "random_mix": mix}


SPLIT_SPEED_BAND = 0.2
"""Fundamental-diagram band of :func:`split_validation`: within ±20 % of Weidmann (SPEC §3)."""


def corridor_speed(
    density: float,
    seed: int = 0,
    length: float = 20.0,
    width: float = 5.0,
    warmup_s: float = 10.0,
    measure_s: float = 10.0,
    *,
    workers: int = 1,
) -> dict[str, float]:
    """Mean walking speed (m/s) and overlaps of a unidirectional periodic corridor.

    A light fundamental-diagram point (no PedPy): the global density ``n / (L W)`` and the
    mean x-velocity of all agents over ``measure_s`` seconds after ``warmup_s``; mean and
    deepest overlap over the measured steps (sampled every 25 steps).
    """
    with periodic_corridor(density, length, width, seed=seed, record=False, workers=workers) as sim:
        dt, period = sim.params.dt, sim.world.period
        sim.run(int(round(warmup_s / dt)))
        speeds, means, worst = [], [], 0.0
        for t in range(int(round(measure_s / dt))):
            sim.step()
            speeds.append(float(sim.state.vel[:, 0].mean()))
            if t % 25 == 0:
                mean_ov, max_ov = overlap_stats(sim.state.pos, sim.state.radius, period)
                means.append(mean_ov)
                worst = max(worst, max_ov)
        rho = sim.state.n / (period * width)
    speed = float(np.mean(speeds))
    return {
        "density": rho,
        "speed": speed,
        "weidmann": float(weidmann_speed(rho)),
        "ratio": speed / float(weidmann_speed(rho)),
        "mean_overlap": float(np.mean(means)),
        "max_overlap": worst,
    }


def split_validation(
    workers: list[int],
    densities: tuple[float, ...] = (1.0, 2.0, 3.0),
    seeds: tuple[int, int] = (0, 1),
    lane_seconds: float = 30.0,
    warmup_s: float = 10.0,
    measure_s: float = 10.0,
) -> dict[str, Any]:
    """Does splitting the simulator across processes change its physics?

    For each worker count (and a second seed of the one-process run, the run-to-run
    noise): speed-density points of periodic corridors (:func:`corridor_speed`), checked
    against Weidmann's band (±20 %); mean and deepest overlaps; the final lane order of
    :func:`lane_formation` (mean of its last quarter). A worker count passes when its
    points lie in the band and each figure is within the one-process value by at most
    ``max(2 x seed spread, floor)`` (floors: 0.05 m/s, 0.05 lane order, 0.05 overlap).

    Returns ``{"runs": [{"label", "workers", "seed", "points", "lane_order", ...}],
    "checks": {workers: {...}}}`` (JSON-ready).
    """
    runs = []
    plan = [(1, seeds[0]), (1, seeds[1])] + [(w, seeds[0]) for w in workers if w != 1]
    for w, seed in plan:
        points = [
            corridor_speed(rho, seed, warmup_s=warmup_s, measure_s=measure_s, workers=w)
            for rho in densities
        ]
        lanes = lane_formation(seconds=lane_seconds, seed=seed, workers=w)
        late = max(1, len(lanes["lane_order"]) // 4)
        runs.append(
            {
                "label": f"{w} worker{'s' if w > 1 else ''}, seed {seed}",
                "workers": w,
                "seed": seed,
                "points": points,
                "lane_order": float(np.mean(lanes["lane_order"][-late:])),
                "random_mix": float(np.mean(lanes["random_mix"][-late:])),
                "in_band": all(abs(p["ratio"] - 1) <= SPLIT_SPEED_BAND for p in points),
            }
        )
    ref, other = runs[0], runs[1]

    def tol(key: str, floor: float, a: dict[str, Any], b: dict[str, Any]) -> float:
        return max(2 * abs(a[key] - b[key]), floor)

    checks: dict[str, Any] = {}
    for run in runs[2:]:
        speed_ok = all(
            abs(p["speed"] - q["speed"]) <= tol("speed", 0.05, q, o)
            for p, q, o in zip(run["points"], ref["points"], other["points"], strict=True)
        )
        overlap_ok = all(
            p["max_overlap"] <= q["max_overlap"] + tol("max_overlap", 0.05, q, o)
            for p, q, o in zip(run["points"], ref["points"], other["points"], strict=True)
        )
        lane_ok = abs(run["lane_order"] - ref["lane_order"]) <= tol("lane_order", 0.05, ref, other)
        checks[str(run["workers"])] = {
            "fd_in_band": run["in_band"],
            "speed_matches": speed_ok,
            "overlap_matches": overlap_ok,
            "lanes_match": lane_ok,
            "passed": bool(run["in_band"] and speed_ok and overlap_ok and lane_ok),
        }
    return {"runs": runs, "checks": checks}


def format_split_validation(report: dict[str, Any]) -> str:
    """The table of :func:`split_validation` (one row per run and density)."""
    lines = [
        f"{'run':<22} {'rho':>5} {'v (m/s)':>8} {'Weidmann':>9} {'ratio':>6} "
        f"{'mean ov':>8} {'max ov':>7} {'lanes':>6} {'mix':>5}"
    ]
    for run in report["runs"]:
        for k, p in enumerate(run["points"]):
            lanes = f"{run['lane_order']:>6.2f} {run['random_mix']:>5.2f}" if k == 0 else ""
            lines.append(
                f"{run['label'] if k == 0 else '':<22} {p['density']:>5.2f} {p['speed']:>8.3f} "
                f"{p['weidmann']:>9.3f} {p['ratio']:>6.2f} {p['mean_overlap']:>8.3f} "
                f"{p['max_overlap']:>7.3f} {lanes}"
            )
    for w, c in report["checks"].items():
        verdict = "passed" if c["passed"] else "FAILED"
        detail = ", ".join(f"{k}={v}" for k, v in c.items() if k != "passed")
        lines.append(f"{w} workers vs 1: {verdict} ({detail})")
    return "\n".join(lines)
