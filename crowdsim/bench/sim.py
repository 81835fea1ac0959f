"""``crowdsim bench sim``: simulator speed next to JuPedSim and PySocialForce (SPEC §9).

The side-by-side corridor is the same for every simulator: a straight corridor of width
``W = L / 4``; agents of radius 0.2-0.25 m on a square grid at 2 /m² in its first section,
desired speed 1.34 m/s towards an exit at the far end; ``L`` is chosen so that nobody
reaches the exit during the measured steps. Each simulator runs at its own stable time step
(ours 0.04 s, JuPedSim's SocialForceModel 0.01 s and CollisionFreeSpeedModel 0.05 s,
PySocialForce 0.4 s, its documented default); 10 warm-up steps, then 50 timed steps. The
figure of merit is simulated seconds per wall second; mean and maximal body overlap are
reported so that speed is never bought with interpenetration.

Peers come from the ``bench`` extra (``pip install -e '.[bench]'``); a missing peer is
reported as skipped. ``--scale N`` also runs ours alone with N agents in a fresh process and
reports its steps/s and peak memory (RSS); ``--scale-workers W`` splits that run across W
processes and adds the workers' peak RSS (``--scale 1000000 --scale-workers 16``: issue 16's
1M-agent run).

``--workers 1 2 4`` adds the simulator split across processes (:mod:`crowdsim.decomposition`):
ours alone on the same corridor at each ``--split-sizes`` count (default 10k and 100k
agents), each worker count in a fresh process, with steps/s and the speed-up over one
worker (SPEC §9: 100k agents >= 1.7x with 2 workers), and where a split step's time goes
(:meth:`crowdsim.decomposition.StripEngine.timing`). ``--validate`` also checks that the
split changes no physics, at every worker count next to the 1-worker run
(:func:`crowdsim.validation.split_validation`: fundamental-diagram band, overlaps, lane
order). Without ``--workers`` the benchmark is the one-process comparison above.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from crowdsim.atomic import OVERWRITE_HELP
from crowdsim.optional import DependencyNotInstalled, require

DENSITY = 2.0
V0 = 1.34
WARMUP = 10
STEPS = 50


@dataclass
class Layout:
    """The shared corridor: ``positions (n, 2)`` m, ``radii (n,)`` m, length and width."""

    length: float
    width: float
    positions: np.ndarray
    radii: np.ndarray


def corridor_layout(n: int, seed: int = 0) -> Layout:
    """Agents on a square grid at 2 /m² in the first section of an ``L x L/4`` corridor."""
    # Section length s = n / (DENSITY W) with W = L / 4, plus 12 m of free corridor ahead:
    # L = s + 12  =>  L^2 - 12 L - 4 n / DENSITY = 0.
    length = 6.0 + math.sqrt(36.0 + 4.0 * n / DENSITY)
    width = length / 4.0
    a = 1.0 / math.sqrt(DENSITY)
    rows = int((width - 0.6) // a) + 1
    cols = int(math.ceil(n / rows))
    gx, gy = np.meshgrid(0.5 + a * np.arange(cols), 0.3 + a * np.arange(rows), indexing="ij")
    positions = np.column_stack([gx.ravel(), gy.ravel()])[:n]
    radii = np.random.default_rng(seed).uniform(0.2, 0.25, n)
    return Layout(length, width, positions, radii)


def overlap_stats(pos: np.ndarray, radii: np.ndarray) -> tuple[float, float]:
    """Mean and max overlap depth relative to the smaller radius, over touching pairs."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(pos).query_pairs(2 * float(radii.max()), output_type="ndarray")
    if len(pairs) == 0:
        return 0.0, 0.0
    d = np.hypot(*(pos[pairs[:, 0]] - pos[pairs[:, 1]]).T)
    rel = (radii[pairs[:, 0]] + radii[pairs[:, 1]] - d) / np.minimum(
        radii[pairs[:, 0]], radii[pairs[:, 1]]
    )
    rel = rel[rel > 0]
    return (float(rel.mean()), float(rel.max())) if len(rel) else (0.0, 0.0)


def _timed(step: Callable[[], Any], warm: Callable[[], Any] | None = None) -> float:
    """Wall seconds of ``STEPS`` calls of ``step`` after ``WARMUP`` untimed ones (then
    ``warm()``, if given)."""
    for _ in range(WARMUP):
        step()
    if warm is not None:
        warm()
    t0 = time.perf_counter()
    for _ in range(STEPS):
        step()
    return time.perf_counter() - t0


def _peak_rss_mb(pids: list[int]) -> float | None:
    """Sum of the peak resident sets (``VmHWM``) of the processes ``pids``, in MB; None where
    ``/proc`` cannot be read. Pages of the shared position block count once per process, so
    the sum bounds the simultaneous peak from above."""
    total = 0.0
    for pid in pids:
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            return None
        kb = next((ln.split()[1] for ln in status.splitlines() if ln.startswith("VmHWM:")), None)
        if kb is None:
            return None
        total += int(kb) / 1024
    return total


def _result(
    name: str, n: int, dt: float, wall: float, pos: np.ndarray, radii: np.ndarray, **extra: Any
) -> dict[str, Any]:
    mean_ov, max_ov = overlap_stats(pos, radii)
    return {
        "simulator": name,
        "agents": n,
        "dt": dt,
        "steps": STEPS,
        "wall_s": wall,
        "steps_per_s": STEPS / wall,
        "sim_s_per_wall_s": STEPS * dt / wall,
        "mean_overlap": mean_ov,
        "max_overlap": max_ov,
        **extra,
    }


# ------------------------------------------------------------------------------ ours


def _ours_scenario(layout: Layout):
    from crowdsim.scenarios import Scenario, Setup
    from crowdsim.world import AgentBatch, Route, World, polyline

    @dataclass(frozen=True)
    class BenchCorridor(Scenario):
        """The side-by-side corridor with a prescribed layout."""

        layout: Any = field(default=None, compare=False)
        name: ClassVar[str] = "bench-corridor"

        def build(self, rng: np.random.Generator) -> Setup:
            lay = self.layout
            walls = np.vstack(
                [
                    polyline([(0.0, 0.0), (lay.length, 0.0)]),
                    polyline([(0.0, lay.width), (lay.length, lay.width)]),
                    polyline([(0.0, 0.0), (0.0, lay.width)]),
                ]
            )
            world = World(walls, (-1.0, -1.0, lay.length + 1.0, lay.width + 1.0))
            exit_gate = [lay.length - 0.5, 0.3, lay.length - 0.5, lay.width - 0.3]
            agents = AgentBatch.create(
                lay.positions, lay.radii, np.full(len(lay.radii), V0), 0, rng, 0.0
            )
            return Setup(world, [Route([exit_gate])], agents, [], {})

    return BenchCorridor(
        n_agents=len(layout.radii), density=DENSITY, prominent_fraction=0.0, layout=layout
    )


def run_ours(layout: Layout, workers: int = 1) -> dict[str, Any]:
    from crowdsim.simulation import Simulation

    extra: dict[str, Any] = {}
    with Simulation(_ours_scenario(layout), seed=0, record=False, workers=workers) as sim:
        engine = sim.engine
        wall = _timed(sim.step, None if engine is None else engine.reset_timing)
        if engine is not None:
            extra["workers"] = workers
            extra["workers_peak_rss_mb"] = _peak_rss_mb(sim.worker_pids)
            extra["rebalances"] = engine.rebalances  # strips re-cut (decomposition)
            extra["timing"] = timing = engine.timing()
            # the parent's own part of a step: everything but the engine's send-and-wait
            timing["parent_ms"] = wall / STEPS * 1e3 - timing["step_ms"]
    if sim.state.n != len(layout.radii):
        raise RuntimeError("agents left the benchmark corridor; make it longer")
    return _result(
        "crowdsim", len(layout.radii), sim.params.dt, wall, sim.state.pos, sim.state.radius, **extra
    )


# ------------------------------------------------------------------------------ JuPedSim


def run_jupedsim(layout: Layout, model: str) -> dict[str, Any]:
    jps = require("jupedsim", "bench", "crowdsim bench sim")

    L, W = layout.length, layout.width
    if model == "sfm":
        sim = jps.Simulation(
            model=jps.SocialForceModel(), geometry=[(0, 0), (L, 0), (L, W), (0, W)], dt=0.01
        )
    else:
        sim = jps.Simulation(
            model=jps.CollisionFreeSpeedModel(), geometry=[(0, 0), (L, 0), (L, W), (0, W)], dt=0.05
        )
    exit_id = sim.add_exit_stage([(L - 1.0, 0.0), (L, 0.0), (L, W), (L - 1.0, W)])
    journey = sim.add_journey(jps.JourneyDescription([exit_id]))
    for (x, y), r in zip(layout.positions, layout.radii, strict=True):  # set-up only
        if model == "sfm":
            params = jps.SocialForceModelAgentParameters(
                position=(float(x), float(y)),
                orientation=(1.0, 0.0),
                journey_id=journey,
                stage_id=exit_id,
                desired_speed=V0,
                radius=float(r),
            )
        else:
            params = jps.CollisionFreeSpeedModelAgentParameters(
                position=(float(x), float(y)),
                journey_id=journey,
                stage_id=exit_id,
                desired_speed=V0,
                radius=float(r),
            )
        sim.add_agent(params)
    wall = _timed(sim.iterate)
    agents = list(sim.agents())
    pos = np.array([a.position for a in agents])
    radii = np.array([a.model.radius for a in agents])
    name = "JuPedSim SocialForceModel" if model == "sfm" else "JuPedSim CollisionFreeSpeed"
    return _result(
        name, len(layout.radii), sim.delta_time(), wall, pos, radii, version=jps.__version__
    )


# ------------------------------------------------------------------------------ PySocialForce


def run_pysocialforce(layout: Layout, dt: float = 0.4) -> dict[str, Any]:
    import logging
    import os
    import tempfile

    logging.getLogger("matplotlib").setLevel(logging.WARNING)  # psf logs at DEBUG on import
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)  # psf opens a "file.log" in the working directory on import
        try:
            psf = require("pysocialforce", "bench", "crowdsim bench sim")
        finally:
            os.chdir(cwd)

    logging.getLogger().setLevel(logging.WARNING)
    L, W = layout.length, layout.width
    n = len(layout.radii)
    state = np.zeros((n, 6))
    state[:, :2] = layout.positions
    state[:, 4] = L + 5.0
    state[:, 5] = layout.positions[:, 1]
    obstacles = [[0.0, L, 0.0, 0.0], [0.0, L, W, W]]
    fd, cfg = tempfile.mkstemp(suffix=".toml")
    with os.fdopen(fd, "w") as fh:
        fh.write(
            f"[scene]\nenable_group = false\nagent_radius = 0.225\nstep_width = {dt}\n"
            "max_speed_multiplier = 1.3\ntau = 0.5\nresolution = 10\n"
        )
    try:
        sim = psf.Simulator(state, groups=None, obstacles=obstacles, config_file=cfg)
    finally:
        os.unlink(cfg)
    sim.peds.initial_speeds = np.full(n, V0)
    sim.peds.max_speeds = 1.3 * sim.peds.initial_speeds
    wall = _timed(sim.step)
    pos = sim.peds.pos()
    return _result(
        "PySocialForce",
        n,
        dt,
        wall,
        pos,
        np.full(n, 0.225),
        version=getattr(psf, "__version__", "1.1"),
    )


# ------------------------------------------------------------------------------ scale run


def run_scale(n: int, workers: int = 1) -> dict[str, Any]:
    """Ours alone with ``n`` agents, in a fresh process, for a clean peak-RSS figure:
    ``peak_rss_mb`` is the parent's; with ``workers > 1``, ``total_peak_rss_mb`` adds each
    worker's peak (an upper bound of the whole run's memory)."""
    code = (
        "import json,resource,sys;from crowdsim.bench.sim import corridor_layout,run_ours;"
        f"r=run_ours(corridor_layout({n}),{int(workers)});"
        "r['peak_rss_mb']=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss/1024;"
        "w=r.get('workers_peak_rss_mb');"
        "r['total_peak_rss_mb']=None if w is None else r['peak_rss_mb']+w;"
        "print(json.dumps(r))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"scale run with {n} agents failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------ CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sizes",
        default="1000,5000,10000",
        help="agent counts for the side-by-side runs (default 1000,5000,10000)",
    )
    parser.add_argument(
        "--psf-max",
        type=int,
        default=2000,
        help="largest count given to PySocialForce, which is O(n²) (default "
        "2000; it also runs at this count for the ratio)",
    )
    parser.add_argument(
        "--scale",
        type=int,
        default=0,
        metavar="N",
        help="also run ours alone with N agents and report peak RSS (e.g. 100000)",
    )
    parser.add_argument(
        "--scale-workers",
        type=int,
        default=1,
        metavar="W",
        help="worker processes of the --scale run (default 1; with W > 1 the peak RSS "
        "adds the workers', e.g. --scale 1000000 --scale-workers 16)",
    )
    parser.add_argument(
        "--peers",
        default="jupedsim,pysocialforce",
        help="peers to run: jupedsim, pysocialforce, or none",
    )
    parser.add_argument(
        "--workers",
        type=int,
        nargs="+",
        default=None,
        metavar="N",
        help="also run ours split across N worker processes, for each N given "
        "(1..os.cpu_count(), e.g. --workers 1 2 4), and report the speed-up over 1 and "
        "where a step's time goes (the parent, the barrier, the slowest and the mean strip)",
    )
    parser.add_argument(
        "--split-sizes",
        default="10000,100000",
        help="agent counts for the --workers runs (default 10000,100000)",
    )
    parser.add_argument(
        "--validate",
        action="store_true",
        help="with --workers: check the split changes no physics (fundamental diagram, "
        "overlaps, lane order at each worker count next to 1 worker)",
    )
    parser.add_argument(
        "--json-out", default=None, metavar="FILE", help="also write the JSON to FILE"
    )
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def _parse_sizes(text: str, flag: str = "--sizes") -> list[int]:
    from crowdsim.scenarios import MAX_AGENTS

    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"{flag} must be comma-separated integers, got {text!r}") from None
    if not sizes or min(sizes) < 1 or max(sizes) > MAX_AGENTS:
        raise ValueError(f"{flag} must be integers in [1, {MAX_AGENTS}], got {text!r}")
    return sizes


def _parse_workers(values: list[int] | None, flag: str = "--workers") -> list[int]:
    from crowdsim.checks import require_cpus

    if values is None:
        return []
    require_cpus(flag, values)
    return sorted(set(values) | {1})


def run_split(sizes: list[int], workers: list[int]) -> list[dict[str, Any]]:
    """Steps/s of ours at each worker count (fresh process each) and the speed-up over 1."""
    from crowdsim.progress import progress_bar

    rows = []
    jobs = [(n, w) for n in sizes for w in workers]
    for n, w in progress_bar(jobs, desc="bench sim --workers", unit="run", leave=True):
        r = run_scale(n, w)
        r["workers"] = w
        rows.append(r)
    for r in rows:
        base = next(b for b in rows if b["agents"] == r["agents"] and b["workers"] == 1)
        r["speedup"] = r["steps_per_s"] / base["steps_per_s"]
    return rows


def run(args: argparse.Namespace) -> int:
    from crowdsim.atomic import require_replaceable
    from crowdsim.checks import require_number
    from crowdsim.scenarios import MAX_AGENTS

    sizes = _parse_sizes(args.sizes)
    workers = _parse_workers(args.workers)
    _parse_workers([args.scale_workers], flag="--scale-workers")
    split_sizes = _parse_sizes(args.split_sizes, "--split-sizes") if workers else []
    require_number("", "--scale", args.scale, lo=0, hi=MAX_AGENTS, integer=True)
    require_number("", "--psf-max", args.psf_max, lo=1, hi=MAX_AGENTS, integer=True)
    if args.json_out is not None:
        require_replaceable("--json-out", args.json_out, args.overwrite)  # before any run
    if args.validate and not workers:
        raise ValueError("--validate needs --workers (e.g. --workers 1 2 4)")
    peers = {p.strip() for p in args.peers.split(",") if p.strip() and p.strip() != "none"}
    unknown = peers - {"jupedsim", "pysocialforce"}
    if unknown:
        raise ValueError(f"--peers: unknown peer(s) {', '.join(sorted(unknown))}")
    from crowdsim.progress import progress_bar

    counts = sorted(set(sizes) | ({args.psf_max} if "pysocialforce" in peers else set()))
    results: list[dict[str, Any]] = []
    skipped: dict[str, str] = {}
    jobs = []
    for n in counts:
        if n in sizes:
            jobs.append(("crowdsim", n))
            if "jupedsim" in peers:
                jobs += [("jupedsim-sfm", n), ("jupedsim-cfsm", n)]
        if "pysocialforce" in peers and n <= args.psf_max:
            jobs.append(("pysocialforce", n))
            if n not in sizes:
                jobs.append(("crowdsim", n))
    for name, n in progress_bar(jobs, desc="bench sim", unit="run", leave=True):
        layout = corridor_layout(n)
        try:
            if name == "crowdsim":
                results.append(run_ours(layout))
            elif name.startswith("jupedsim"):
                results.append(run_jupedsim(layout, name.split("-")[1]))
            else:
                results.append(run_pysocialforce(layout))
        except DependencyNotInstalled as exc:
            skipped[name] = str(exc)
    scale = run_scale(args.scale, args.scale_workers) if args.scale else None
    split = run_split(split_sizes, workers) if workers else None
    validation = None
    if args.validate:
        from crowdsim.validation import split_validation

        validation = split_validation(workers)
    ratios = []
    for ours in (r for r in results if r["simulator"] == "crowdsim"):
        for peer in results:
            if peer["simulator"] != "crowdsim" and peer["agents"] == ours["agents"]:
                ratios.append(
                    {
                        "agents": ours["agents"],
                        "peer": peer["simulator"],
                        "ratio": ours["sim_s_per_wall_s"] / peer["sim_s_per_wall_s"],
                    }
                )
    report = {
        "benchmark": "sim",
        "corridor": {
            "density": DENSITY,
            "desired_speed": V0,
            "warmup_steps": WARMUP,
            "timed_steps": STEPS,
        },
        "results": results,
        "ratios": ratios,
        "scale": scale,
        "split": split,
        "split_validation": validation,
        "skipped": skipped,
    }
    _print_table(report)
    text = json.dumps(report, indent=None)
    print(text)
    if args.json_out:
        from crowdsim.atomic import recorded, write_text_atomic

        with recorded(args.json_out):
            write_text_atomic(args.json_out, text + "\n")
    return 0


def _print_table(report: dict[str, Any]) -> None:
    head = (
        f"{'simulator':<28} {'agents':>7} {'dt':>5} {'steps/s':>9} {'sim s/wall s':>12} "
        f"{'mean ov':>8} {'max ov':>7}"
    )
    print(head)
    print("-" * len(head))
    for r in report["results"]:
        print(
            f"{r['simulator']:<28} {r['agents']:>7} {r['dt']:>5.2f} {r['steps_per_s']:>9.1f} "
            f"{r['sim_s_per_wall_s']:>12.3f} {r['mean_overlap']:>8.3f} {r['max_overlap']:>7.3f}"
        )
    if report["ratios"]:
        print("\nours / peer (simulated seconds per wall second)")
        for q in report["ratios"]:
            print(f"  {q['agents']:>7} agents vs {q['peer']:<28} {q['ratio']:>8.1f}x")
    if report["scale"]:
        s = report["scale"]
        total = s.get("total_peak_rss_mb")
        print(
            f"\nscale: {s['agents']} agents, {s.get('workers', 1)} worker(s), "
            f"{s['steps_per_s']:.2f} steps/s, peak RSS {s['peak_rss_mb']:.0f} MB"
            + (f" (with the workers: {total:.0f} MB)" if total is not None else "")
        )
    if report.get("split"):
        print("\nsplit across processes (ours alone, fresh process per run; ms a step:")
        print("  the parent's own part, the barrier's messages and wake-ups, the slowest")
        print("  worker's strip, the mean worker's strip; how often the strips were re-cut)")
        print(
            f"  {'agents':>7} {'workers':>7} {'steps/s':>9} {'speed-up':>9} {'mean ov':>8}"
            f" {'parent':>7} {'barrier':>7} {'slowest':>7} {'strip':>7} {'re-cuts':>7}"
        )
        for r in report["split"]:
            t = r.get("timing")
            ms = (
                f" {t['parent_ms']:>7.2f} {t['barrier_ms']:>7.2f}"
                f" {t['critical_ms']:>7.2f} {t['busy_mean_ms']:>7.2f} {r['rebalances']:>7}"
                if t
                else ""
            )
            print(
                f"  {r['agents']:>7} {r['workers']:>7} {r['steps_per_s']:>9.2f} "
                f"{r['speedup']:>8.2f}x {r['mean_overlap']:>8.3f}{ms}"
            )
    if report.get("split_validation"):
        from crowdsim.validation import format_split_validation

        print("\n" + format_split_validation(report["split_validation"]))
    for name, why in report["skipped"].items():
        print(f"skipped {name}: {why}")
