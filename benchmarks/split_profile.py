"""Why the split simulator gains less than N with N workers: where a step's time goes.

For each ``--workers`` count the 100k-agent ``crowdsim bench sim`` corridor runs in this
process with that many strips, first side by side (the normal barrier) and then with the
workers stepped one after another (:attr:`crowdsim.decomposition.StripEngine.serial`, the
same physics), ``--steps`` steps each after ``--warmup``. Per run it reports, in ms a step:
the parent's own part, the barrier (messages and wake-ups), the slowest worker's strip and
the mean worker's strip, side by side and alone (also split into the strip's stages:
finding its agents, the social force, pymunk's contacts, writing back), and so:

* **contention** = mean strip side by side / mean strip alone (> 1: the workers slow each
  other down through what they share: memory bandwidth, caches, the clock);
* **straggling** = slowest strip / mean strip, side by side (> 1: the barrier waits).

The one-process run (1 worker) is split the same way, by timing its social force (on all
of numba's threads) and pymunk's contact steps (one thread). Then two probes of the machine
itself, each run in ``N`` processes at once against one alone: a compute-only numba loop
(slows down only if the clock drops with more busy cores) and a streaming pass over 64 MB
(slows down when the cores share memory bandwidth)::

    python benchmarks/split_profile.py --workers 2 4 8 16

Prints a table and one JSON object, and draws the steps as stacked bars (``--png``).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np


def _spin(n: int) -> float:
    from numba import njit

    @njit(cache=False)
    def spin(n):
        x = 0.0
        for i in range(n):
            x = x * 0.999999 + (i & 7)
        return x

    spin(10)
    t0 = time.perf_counter()
    spin(n)
    return time.perf_counter() - t0


def _stream(reps: int) -> float:
    a = np.ones(8 << 20)  # 64 MB, far past any cache
    a.sum()
    t0 = time.perf_counter()
    for _ in range(reps):
        a.sum()
    return time.perf_counter() - t0


def _probe(kind: str, n_proc: int) -> float:
    """Mean seconds of one probe when ``n_proc`` processes run it at once."""
    fn, arg = (_spin, 200_000_000) if kind == "compute" else (_stream, 40)
    with mp.get_context("spawn").Pool(n_proc) as pool:
        return float(np.mean(pool.map(fn, [arg] * n_proc)))


class _Clock:
    """Seconds spent in the one-process simulator's social force and pymunk steps, taken by
    wrapping the two calls (the split's workers time the same stages themselves)."""

    def __init__(self) -> None:
        import crowdsim.simulation as simulation

        self.sf = self.contacts = 0.0
        self._sf, self._space_step = simulation.social_force, simulation.pymunk.Space.step

        def sf(*a, **kw):
            t0 = time.perf_counter()
            try:
                return self._sf(*a, **kw)
            finally:
                self.sf += time.perf_counter() - t0

        def space_step(space, dt):
            t0 = time.perf_counter()
            try:
                return self._space_step(space, dt)
            finally:
                self.contacts += time.perf_counter() - t0

        simulation.social_force, simulation.pymunk.Space.step = sf, space_step

    def close(self) -> None:
        import crowdsim.simulation as simulation

        simulation.social_force, simulation.pymunk.Space.step = self._sf, self._space_step


def _profile(n_agents: int, workers: int, warmup: int, steps: int) -> dict:
    from crowdsim.bench.sim import _ours_scenario, corridor_layout
    from crowdsim.simulation import Simulation

    row: dict = {"agents": n_agents, "workers": workers}
    scenario = _ours_scenario(corridor_layout(n_agents))
    with Simulation(scenario, seed=0, record=False, workers=workers) as sim:
        sim.run(warmup)
        eng = sim.engine
        for mode in ("side_by_side", "alone") if eng is not None else ("one_process",):
            if eng is not None:
                eng.serial = mode == "alone"
                eng.reset_timing()
            clock = _Clock() if eng is None else None
            t0 = time.perf_counter()
            sim.run(steps)
            wall = (time.perf_counter() - t0) / steps * 1e3
            t = eng.timing() if eng is not None else {}
            if clock is not None:
                clock.close()
                t["stage_ms"] = {
                    "social_force": clock.sf / steps * 1e3,
                    "contacts": clock.contacts / steps * 1e3,
                }
            if eng is not None:
                t["parent_ms"] = wall - t["step_ms"]
            row[mode] = {"wall_ms": wall, **t}  # t's step_ms: the engine's part of it
    if "alone" in row:
        side, alone = row["side_by_side"], row["alone"]
        row["contention"] = side["busy_mean_ms"] / alone["busy_mean_ms"]
        row["straggling"] = side["critical_ms"] / side["busy_mean_ms"]
    return row


def plot(rows: list[dict], path: str) -> None:
    """Stacked bars of where a step's ms go at each worker count (the one-process run at 1),
    beside the ideal ``one process / N``; written atomically to ``path``."""
    from crowdsim.decomposition import STRIP_STAGES
    from crowdsim.plotting import new_figure, save_figure

    one = rows[0]["one_process"]
    parts = [*STRIP_STAGES, "straggling", "barrier", "parent"]
    fig, ax = new_figure(figsize=(7.0, 4.0))
    labels, bottoms = [], []
    for x, r in enumerate(rows):
        if "one_process" in r:
            sf, contacts = one["stage_ms"]["social_force"], one["stage_ms"]["contacts"]
            heights = {"social_force": sf, "contacts": contacts}
            heights["other"] = one["wall_ms"] - sf - contacts
        else:
            s = r["side_by_side"]
            heights = dict(s["stage_ms"])
            heights["straggling"] = s["critical_ms"] - s["busy_mean_ms"]
            heights["barrier"] = s["barrier_ms"]
            heights["parent"] = s["parent_ms"]
        base = 0.0
        for i, name in enumerate([*parts, "other"]):
            h = heights.get(name, 0.0)
            if h > 0:
                ax.bar(x, h, bottom=base, color=f"C{i}", label=name if name not in labels else None)
                labels.append(name)
                base += h
        bottoms.append(base)
    ideal = [one["wall_ms"] / r["workers"] for r in rows]
    ax.plot(range(len(rows)), ideal, "k--", marker="o", label="one process / N")
    ax.set_xticks(range(len(rows)), [str(r["workers"]) for r in rows])
    ax.set_xlabel("workers")
    ax.set_ylabel("ms a step")
    ax.set_title(f"split simulator, {rows[0]['agents']:,} agents: where a step goes")
    ax.legend(fontsize=7, ncol=2)
    save_figure(fig, path)


def main() -> int:
    from crowdsim.atomic import OVERWRITE_HELP, recorded, require_replaceable
    from crowdsim.checks import require_cpus
    from crowdsim.scenarios import MAX_AGENTS

    cores = os.cpu_count() or 1
    default_workers = sorted({min(2, cores), min(4, cores)} - {1}) or [1]
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--workers",
        type=int,
        nargs="+",
        default=default_workers,
        help=f"worker counts beside 1, each 1..cores (default here: {default_workers})",
    )
    ap.add_argument("--agents", type=int, default=100_000, help=f"agents, 1..{MAX_AGENTS} (100000)")
    ap.add_argument("--warmup", type=int, default=10, help="steps before timing (10)")
    ap.add_argument("--steps", type=int, default=20, help="timed steps (20)")
    ap.add_argument("--no-probes", action="store_true", help="skip the machine probes")
    ap.add_argument(
        "--png",
        default=str(Path(__file__).resolve().parent / "out" / "split_profile.png"),
        metavar="FILE",
        help="stacked bars of each step (default: out/split_profile.png beside this script)",
    )
    ap.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    args = ap.parse_args()
    try:
        require_replaceable("--png", args.png, args.overwrite)
    except ValueError as exc:
        ap.error(str(exc))
    try:
        require_cpus("--workers", args.workers)
    except ValueError as exc:
        ap.error(str(exc))
    if min(args.agents, args.warmup, args.steps) < 1:
        ap.error("--agents, --warmup and --steps must be >= 1")
    if args.agents > MAX_AGENTS:
        ap.error(f"--agents must be in [1, {MAX_AGENTS}], got {args.agents}")
    from crowdsim.progress import progress_bar

    counts = [1] + [w for w in args.workers if w > 1]
    try:
        rows = [
            _profile(args.agents, w, args.warmup, args.steps)
            for w in progress_bar(counts, desc="split_profile", unit="run", leave=True)
        ]
    except ValueError as exc:  # e.g. strips narrower than the halo for this crowd
        ap.error(str(exc))
    probes = {}
    if not args.no_probes:
        for kind in progress_bar(("compute", "stream"), desc="probes", unit="probe"):
            alone = _probe(kind, 1)
            probes[kind] = {w: _probe(kind, w) / alone for w in args.workers}

    one = rows[0]["one_process"]["wall_ms"]
    sf1 = rows[0]["one_process"]["stage_ms"]
    print(
        f"{args.agents} agents; ms a step (1 worker, one process with {numba.get_num_threads()} "
        f"numba threads: {one:.1f} ms, of which social force {sf1['social_force']:.1f} and "
        f"pymunk's contact steps {sf1['contacts']:.1f})"
    )
    print(
        f"{'workers':>7} {'step':>7} {'parent':>7} {'barrier':>7} {'slowest':>7} "
        f"{'strip':>7} {'alone':>7} {'contention':>10} {'straggling':>10} {'ideal':>7}"
    )
    for r in rows[1:]:
        s, a = r["side_by_side"], r["alone"]
        print(
            f"{r['workers']:>7} {s['wall_ms']:>7.2f} {s['parent_ms']:>7.2f} "
            f"{s['barrier_ms']:>7.2f} {s['critical_ms']:>7.2f} {s['busy_mean_ms']:>7.2f} "
            f"{a['busy_mean_ms']:>7.2f} {r['contention']:>9.2f}x {r['straggling']:>9.2f}x "
            f"{one / r['workers']:>7.2f}"
        )
    from crowdsim.decomposition import STRIP_STAGES

    print("mean strip's stages, ms a step side by side / alone (contention per stage)")
    print(f"{'workers':>7} " + " ".join(f"{name:>22}" for name in STRIP_STAGES))
    for r in rows[1:]:
        s, a = r["side_by_side"]["stage_ms"], r["alone"]["stage_ms"]
        cells = (
            f"{s[n]:>6.2f} / {a[n]:>5.2f} ({s[n] / max(a[n], 1e-9):.2f}x)" for n in STRIP_STAGES
        )
        print(f"{r['workers']:>7} " + " ".join(f"{c:>22}" for c in cells))
    for kind, by in probes.items():
        print(
            f"probe {kind}: time with N processes at once / alone: "
            + ", ".join(f"N={w} {v:.2f}x" for w, v in by.items())
        )
    try:
        with recorded(args.png):
            plot(rows, args.png)
        print(f"-> {args.png}")
    except OSError as exc:  # an unwritable folder costs the picture, not the figures above
        print(f"could not write {args.png}: {exc.strerror or exc}")
    print(json.dumps({"benchmark": "split_profile", "rows": rows, "probes": probes}))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("split_profile.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
