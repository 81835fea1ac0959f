"""``crowdsim simulate``: run one scenario and save its trajectories as ``.npz``."""

from __future__ import annotations

import argparse
import math
from typing import Any

from crowdsim.checks import path_arg

DESCRIPTION = """Simulate a crowd scenario and write its trajectories.

The output .npz holds positions (S+1, N_total, 2) in metres (NaN where an agent is absent),
ids (N_total,), dt, and the per-agent attributes attr_group, attr_prominent, attr_anomaly,
attr_radius, attr_desired_speed. A summary table is printed at the end."""


def parse_assignments(items: list[str] | None, flag: str) -> dict[str, Any]:
    """``["a=1", "b=[2, 3]"]`` -> ``{"a": 1, "b": [2, 3]}`` (values parsed as YAML scalars)."""
    import yaml

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"{flag} expects NAME=VALUE, got {item!r}")
        if key.strip() in out:  # the last would win in silence
            raise ValueError(f"{flag} {key.strip()} is given twice")
        try:
            out[key.strip()] = float(value) if _is_float(value) else yaml.safe_load(value)
        except yaml.YAMLError:
            raise ValueError(f"{flag} {key.strip()}: cannot parse value {value!r}") from None
    return out


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return not text.strip().lstrip("+-").isdigit()  # keep integers as int


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.atomic import OVERWRITE_HELP
    from crowdsim.scenarios import SCENARIOS  # light: no numba compile at import

    p = sub.add_parser(
        "simulate",
        help="simulate a scenario, write trajectories (.npz)",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", metavar="SCENARIO", help=f"one of: {', '.join(SCENARIOS)}")
    p.add_argument(
        "--agents",
        type=int,
        default=200,
        metavar="N",
        help="agents placed at the start, 1..1000000 (default 200)",
    )
    p.add_argument(
        "--density",
        type=float,
        default=None,
        metavar="RHO",
        help="initial density in persons/m², (0, 6] (default: the scenario's)",
    )
    p.add_argument(
        "--steps", type=int, default=250, metavar="S", help="time steps to simulate (default 250)"
    )
    p.add_argument(
        "--dt",
        type=float,
        default=0.04,
        metavar="SECONDS",
        help="time step in seconds, (0, 0.2] (default 0.04 = 25 frames/s)",
    )
    p.add_argument("--seed", type=int, default=0, metavar="K", help="random seed (default 0)")
    p.add_argument(
        "--out",
        type=path_arg,
        default=None,
        metavar="FILE.npz",
        help="trajectory file to write (atomically); omit to only print the table",
    )
    p.add_argument(
        "--plot",
        type=path_arg,
        default=None,
        metavar="FILE.png",
        help="also draw the trajectories over the walls as a PNG",
    )
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument(
        "--set",
        dest="scenario_params",
        action="append",
        metavar="NAME=VALUE",
        help="scenario parameter, e.g. --set width=8 for counterflow (repeatable; an "
        "unknown NAME lists the scenario's own)",
    )
    p.add_argument(
        "--param",
        dest="model_params",
        action="append",
        metavar="NAME=VALUE",
        help="social-force parameter, e.g. --param tau=0.4 (repeatable)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="processes that step the world, 1..os.cpu_count() (default 1); N > 1 splits it "
        "into N strips, re-cut when their agent counts drift over 5 %% apart (deterministic for a "
        "given N and seed, not equal to N = 1)",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


MAX_DT = 0.2
BYTES_PER_AGENT_STEP = 64
"""Working set per (step, agent): the recorder's rows (24 B), the dense (S+1, N, 2) float64
trajectories (16 B) and the summary's velocities and speeds (24 B)."""


def check_args(args: argparse.Namespace) -> None:
    """Validate the flags before anything is simulated; errors name the flag and the value."""

    from crowdsim.atomic import require_replaceable
    from crowdsim.checks import require_cpus, require_memory
    from crowdsim.scenarios import MAX_AGENTS

    require_cpus("--workers", args.workers)
    if not 1 <= args.agents <= MAX_AGENTS:
        raise ValueError(f"--agents must be in [1, {MAX_AGENTS}], got {args.agents}")
    if args.steps < 0:
        raise ValueError(f"--steps must be >= 0, got {args.steps}")
    if not 0 <= args.seed < 2**63:
        raise ValueError(f"--seed must be in [0, 2**63), got {args.seed}")
    if not (math.isfinite(args.dt) and 0 < args.dt <= MAX_DT):
        raise ValueError(f"--dt must be in (0, {MAX_DT:g}] seconds, got {args.dt}")
    if args.density is not None and not (math.isfinite(args.density) and 0 < args.density <= 6):
        raise ValueError(f"--density must be in (0, 6] persons/m², got {args.density}")
    if args.out is not None and args.out.suffix != ".npz":
        raise ValueError(f"--out must end in .npz, got {str(args.out)!r}")
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise ValueError(f"--plot must end in .png, got {str(args.plot)!r}")
    require_memory(
        f"--steps {args.steps} x --agents {args.agents}",
        float(BYTES_PER_AGENT_STEP) * (args.steps + 1) * args.agents,
    )
    if args.out is not None:
        require_replaceable("--out", args.out, args.overwrite)
    if args.plot is not None:
        require_replaceable("--plot", args.plot, args.overwrite)


def check_inflow_memory(sim, steps: int) -> None:
    """Refuse, before stepping, a run whose sources would bring more people than the memory
    holds: the trajectories are dense, one column per person who was ever there, so a
    station's inflow makes them grow with the square of the steps (``--agents 50 --steps
    20000`` ended with about 3,400 people and 3.4 GB under the station's route layout 1;
    :func:`check_args` counts ``--agents``)."""
    from crowdsim.checks import require_memory
    from crowdsim.world import expected_arrivals

    seconds = steps * sim.params.dt
    arrivals = expected_arrivals(sim.sources, seconds)
    if arrivals <= 0:
        return
    rate = arrivals / max(seconds, 1e-12)
    people = len(sim.state.ids) + arrivals
    require_memory(
        f"--steps {steps} with the scenario's inflow (about {arrivals:,.0f} more people at "
        f"{rate:.2f} a second, {people:,.0f} in all)",
        float(BYTES_PER_AGENT_STEP) * (steps + 1) * people,
    )


def run(args: argparse.Namespace) -> int:
    check_args(args)

    import sys
    import time

    from crowdsim.atomic import recorded
    from crowdsim.decomposition import WorkerFailed
    from crowdsim.params import SocialForceParams
    from crowdsim.scenarios import make_scenario
    from crowdsim.simulation import Simulation

    scenario_kw = parse_assignments(args.scenario_params, "--set")
    model_kw = parse_assignments(args.model_params, "--param")
    for flag, key, own in (
        ("--set", "n_agents", "--agents"),
        ("--set", "density", "--density"),
        ("--param", "dt", "--dt"),
    ):
        if key in (scenario_kw if flag == "--set" else model_kw):
            raise ValueError(f"{flag} {key}: use {own} instead")
    scenario_kw["n_agents"] = args.agents
    if args.density is not None:
        scenario_kw["density"] = args.density
    scenario = make_scenario(args.scenario, **scenario_kw)
    params = SocialForceParams().replace(dt=args.dt, **model_kw)
    try:
        sim = Simulation(scenario, seed=args.seed, params=params, workers=args.workers)
        with sim:
            check_inflow_memory(sim, args.steps)
            t0 = time.perf_counter()
            traj = sim.run(args.steps, progress=not args.no_progress)
            wall = time.perf_counter() - t0
    # the workers are stopped, or the state overflowed (a dt or force far too large)
    except (WorkerFailed, FloatingPointError) as exc:
        print(f"crowdsim simulate: error: {exc}; nothing written", file=sys.stderr)
        return 2
    assert traj is not None
    outputs = [p for p in (args.out, args.plot) if p is not None]
    with recorded(*outputs):  # a Ctrl-C between the two still notes the first
        if args.out is not None:
            traj.save(args.out)
        if args.plot is not None:
            from crowdsim.plotting import plot_trajectories

            plot_trajectories(
                traj,
                sim.world.walls,
                args.plot,
                title=f"{scenario.name}: {traj.n_agents} agents, seed {args.seed}",
            )
    print(summary_table(sim, traj, args.steps, wall, args.out, args.plot))
    return 0


def summary_table(sim, traj, steps: int, wall: float, out=None, plot=None) -> str:
    """The table ``crowdsim simulate`` prints (also the first part of ``crowdsim demo``)."""
    import numpy as np

    scenario, params = sim.scenario, sim.params
    speed = np.hypot(*np.moveaxis(traj.velocities(), -1, 0))
    start = int(np.isfinite(traj.positions[0]).all(-1).sum())
    rows = [
        ("scenario", scenario.name),
        ("agents (start / total / end)", f"{start} / {traj.n_agents} / {sim.state.n}"),
        ("density asked (/m²)", f"{scenario.density:g}"),  # the scenario's: a small crowd
        # fills a minimum-sized world more thinly (1 agent in a 4 x 6 m corridor: 0.04)
        ("mean speed (m/s)", f"{np.nanmean(speed):.3f}" if np.isfinite(speed).any() else "n/a"),
        ("steps x dt", f"{steps} x {params.dt:g} s = {steps * params.dt:g} s"),
        ("wall time (s)", f"{wall:.2f}"),
        ("steps/s", f"{steps / wall:.1f}" if wall > 0 else "n/a"),
        ("output", str(out) if out else "(not written)"),
        *([("plot", str(plot))] if plot else []),
    ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{key:<{width}}  {value}" for key, value in rows)
