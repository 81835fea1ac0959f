"""Equal strips against strips re-cut at the agents' quantiles, on unevenly spread crowds.

The scenes' crowds are not spread evenly along the strips' axis.

The split simulator (:mod:`crowdsim.decomposition`) starts with ``N`` equal strips. In a
station or a circulation square most people are in the middle of the world: 250 steps into a
5,000-agent station, 8 equal strips hold 0.40 to 1.37x the mean agents, and the barrier waits
for the fullest strip every step. Every :data:`crowdsim.decomposition.BALANCE_EVERY`
steps the parent counts each strip's agents and, past :data:`BALANCE_TOLERANCE`, moves the
borders to the agents' quantiles. This script runs each ``--scenarios`` scene with
``--agents`` people at each ``--workers`` count twice, with the strips fixed
(``BALANCE_EVERY = 0``) and re-cut (the default), each run in a fresh process:
``--warmup`` untimed steps, then ``--steps`` timed ones. It reports steps/s, the speed-up of
re-cutting, the strips' agent counts (fullest / mean) at the end and the slowest strip's ms a
step::

    python benchmarks/split_balance.py --workers 4 8 16 --agents 40000

Prints a table and one JSON object and draws the steps/s as bars (``--png``). The same
seed, scene and ``N`` give the same trajectories run after run; fixed and re-cut strips
give different, equally valid ones (as different ``N`` do).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, sys, time
import numpy as np
import crowdsim.decomposition as dec
from crowdsim.scenarios import make_scenario
from crowdsim.simulation import Simulation

name, n, workers, every, warmup, steps = sys.argv[1:7]
dec.BALANCE_EVERY = int(every)
with Simulation(make_scenario(name, n_agents=int(n)), seed=0, record=False,
                workers=int(workers)) as sim:
    sim.run(int(warmup))
    eng = sim.engine
    if eng is not None:
        eng.reset_timing()
    t0 = time.perf_counter()
    sim.run(int(steps))
    wall = time.perf_counter() - t0
    out = {"steps_per_s": int(steps) / wall, "agents_now": int(sim.state.n)}
    if eng is not None:
        t = eng.timing()
        counts = np.bincount(eng.layout.owner(sim.state.pos[:, eng.layout.axis]),
                             minlength=eng.n_workers)
        out.update(critical_ms=t["critical_ms"], busy_mean_ms=t["busy_mean_ms"],
                   fullest_over_mean=float(counts.max() / counts.mean()),
                   rebalances=eng.rebalances, edges=list(eng.layout.edges))
print(json.dumps(out))
"""


def run_one(name: str, agents: int, workers: int, every: int, warmup: int, steps: int) -> dict:
    """One timed run in a fresh process (``every = 0``: fixed strips)."""
    argv = [sys.executable, "-c", CHILD, name, str(agents), str(workers), str(every)]
    out = subprocess.run(
        [*argv, str(warmup), str(steps)], capture_output=True, text=True, check=False
    )
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{name}, {workers} workers: {tail}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def plot(rows: list[dict], path: str) -> None:
    """Steps/s of fixed and re-cut strips per scene and worker count, written atomically."""
    from crowdsim.plotting import new_figure, save_figure

    fig, ax = new_figure(figsize=(7.0, 3.8))
    labels = [f"{r['scenario']}\n{r['workers']}" for r in rows]
    xs = range(len(rows))
    ax.bar([x - 0.2 for x in xs], [r["fixed"]["steps_per_s"] for r in rows], 0.4, label="fixed")
    ax.bar([x + 0.2 for x in xs], [r["recut"]["steps_per_s"] for r in rows], 0.4, label="re-cut")
    ax.set_xticks(list(xs), labels, fontsize=7)
    ax.set_ylabel("steps/s")
    ax.set_title("split simulator: equal strips against strips re-cut at the agents' quantiles")
    ax.legend(fontsize=8)
    save_figure(fig, path)


def main() -> int:
    from crowdsim.atomic import OVERWRITE_HELP, recorded, require_replaceable
    from crowdsim.checks import require_cpus
    from crowdsim.decomposition import BALANCE_EVERY
    from crowdsim.scenarios import SCENARIOS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--scenarios",
        nargs="+",
        default=["station", "circulation"],
        help="scenarios to split (station circulation)",
    )
    ap.add_argument(
        "--workers", type=int, nargs="+", default=[2], help="worker counts, each 2..cores (2)"
    )
    ap.add_argument("--agents", type=int, default=40_000, help="agents per scene (40000)")
    ap.add_argument("--warmup", type=int, default=100, help="steps before timing (100)")
    ap.add_argument("--steps", type=int, default=100, help="timed steps (100)")
    ap.add_argument(
        "--png",
        default=str(Path(__file__).resolve().parent / "out" / "split_balance.png"),
        metavar="FILE",
        help="bars of steps/s, fixed or re-cut (default: out/split_balance.png beside this script)",
    )
    ap.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    args = ap.parse_args()
    try:
        require_replaceable("--png", args.png, args.overwrite)
    except ValueError as exc:
        ap.error(str(exc))
    try:
        require_cpus("--workers", args.workers, lo=2)
    except ValueError as exc:
        ap.error(str(exc))
    unknown = [s for s in args.scenarios if s not in SCENARIOS]
    if unknown:
        ap.error(f"--scenarios: unknown {unknown[0]!r}; choose from {', '.join(SCENARIOS)}")
    if min(args.agents, args.warmup, args.steps) < 1:
        ap.error("--agents, --warmup and --steps must be >= 1")
    from crowdsim.progress import progress_bar

    jobs = [(s, w) for s in args.scenarios for w in [1, *sorted(set(args.workers))]]
    rows, one = [], {}
    try:
        for name, w in progress_bar(jobs, desc="split_balance", unit="scene", leave=True):
            run = (name, args.agents, w)
            if w == 1:
                one[name] = run_one(*run, 0, args.warmup, args.steps)
                continue
            fixed = run_one(*run, 0, args.warmup, args.steps)
            recut = run_one(*run, BALANCE_EVERY, args.warmup, args.steps)
            base = one[name]["steps_per_s"]
            rows.append(
                {
                    "scenario": name,
                    "workers": w,
                    "one_worker_steps_per_s": base,
                    "fixed": fixed,
                    "recut": recut,
                    "gain": recut["steps_per_s"] / fixed["steps_per_s"],
                    "speedup_fixed": fixed["steps_per_s"] / base,
                    "speedup_recut": recut["steps_per_s"] / base,
                }
            )
    except RuntimeError as exc:  # e.g. strips narrower than twice the halo
        ap.error(str(exc))
    print(
        f"{args.agents} agents, steps {args.warmup}..{args.warmup + args.steps}; steps/s "
        f"(speed-up over 1 worker), fullest strip / mean strip agents, slowest strip ms a step"
    )
    print(
        f"{'scene':<12} {'workers':>7} {'1 worker':>8} {'fixed':>14} {'re-cut':>14} "
        f"{'gain':>6} {'fullest/mean':>14} {'slowest ms':>13}"
    )
    for r in rows:
        f, c = r["fixed"], r["recut"]
        print(
            f"{r['scenario']:<12} {r['workers']:>7} {r['one_worker_steps_per_s']:>8.2f} "
            f"{f['steps_per_s']:>6.2f} ({r['speedup_fixed']:.2f}x) "
            f"{c['steps_per_s']:>6.2f} ({r['speedup_recut']:.2f}x) {r['gain']:>5.2f}x "
            f"{f['fullest_over_mean']:>6.2f} / {c['fullest_over_mean']:.2f} "
            f"{f['critical_ms']:>6.1f} / {c['critical_ms']:.1f}"
        )
    try:
        with recorded(args.png):
            plot(rows, args.png)
        print(f"-> {args.png}")
    except OSError as exc:  # an unwritable folder costs the picture, not the figures above
        print(f"could not write {args.png}: {exc.strerror or exc}")
    report = {"benchmark": "split_balance", "agents": args.agents, "warmup": args.warmup}
    print(json.dumps({**report, "steps": args.steps, "balance_every": BALANCE_EVERY, "rows": rows}))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("split_balance.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
