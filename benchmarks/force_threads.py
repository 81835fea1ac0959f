"""The social-force kernel on 1..N numba threads, after a small crowd compiled the serial one.

:func:`crowdsim.forces.social_force` runs a serial kernel below
:data:`crowdsim.forces.PARALLEL_MIN_AGENTS` agents and a parallel one from there. Until
2026-11-26 the two shared one entry of numba's disk cache (numba keys it by function name and
signature, not by ``parallel``), so once any small crowd had compiled the serial kernel, every
later process ran the "parallel" one on a single thread. This script first calls the kernel
on 50 agents, as a test or a demo would, then times ``--agents`` agents of the ``crowdsim
bench sim`` corridor (2 /m², walking along x) on each ``--threads`` count, best of
``--repeats`` calls::

    python benchmarks/force_threads.py --threads 1 2 4 8 16

Prints a table and one JSON object (ms a call, speed-up over the first count). On the 2-core
machine, 100k agents: about 50 ms on one thread and 29-35 ms on two.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def crowd(n: int) -> tuple:
    """``social_force``'s arrays for the first ``n`` agents of the bench corridor."""
    from crowdsim.bench.sim import corridor_layout

    lay = corridor_layout(n)
    rng = np.random.default_rng(0)
    vel = np.column_stack([rng.uniform(0.8, 1.2, n), rng.normal(0.0, 0.1, n)])
    e = np.tile([1.0, 0.0], (n, 1))
    return lay.positions, vel, lay.radii, np.full(n, 1.34), e, np.full(n, -1, np.int64)


def main() -> int:
    import os

    import numba

    from crowdsim.forces import social_force
    from crowdsim.params import SocialForceParams
    from crowdsim.scenarios import MAX_AGENTS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--threads", type=int, nargs="+", default=[1, 2], help="numba thread counts (1 2)"
    )
    ap.add_argument("--agents", type=int, default=100_000, help=f"agents, 1..{MAX_AGENTS} (100000)")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls, best kept (5)")
    args = ap.parse_args()
    most = numba.config.NUMBA_NUM_THREADS
    bad = [t for t in args.threads if not 1 <= t <= most]
    if bad:
        ap.error(f"--threads must be in [1, {most}] (NUMBA_NUM_THREADS), got {bad[0]}")
    if args.agents < 1 or args.repeats < 1:
        ap.error("--agents and --repeats must be >= 1")
    if args.agents > MAX_AGENTS:
        ap.error(f"--agents must be in [1, {MAX_AGENTS}], got {args.agents}")
    params, walls = SocialForceParams(), np.zeros((0, 5))
    social_force(*crowd(50), walls, params)  # compiles (or loads) the serial kernel first
    arrays = crowd(args.agents)
    ms = {}
    for t in args.threads:
        numba.set_num_threads(t)
        social_force(*arrays, walls, params)
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            social_force(*arrays, walls, params)
            best = min(best, time.perf_counter() - t0)
        ms[t] = 1e3 * best
    first = ms[args.threads[0]]
    print(f"social force, {args.agents} agents, best of {args.repeats} ({os.cpu_count()} cpus)")
    print(f"{'threads':>7} {'ms':>8} {'speed-up':>9}")
    for t, v in ms.items():
        print(f"{t:>7} {v:>8.2f} {first / v:>8.2f}x")
    report = {"benchmark": "force_threads", "agents": args.agents, "repeats": args.repeats}
    print(json.dumps({**report, "ms": {str(t): v for t, v in ms.items()}}))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("force_threads.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
