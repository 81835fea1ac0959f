"""``crowdsim bench solver``: Frank-Wolfe variants vs an interior-point QP solver (paper Sec. 7.4).

Reproduces two claims on the relaxed per-frame QP of the BQP tracker:

* Fig. 13: iterations of FW-SWAP < away-step FW < plain FW (same problems, same ``eps``);
  our ``"block"`` variant (SWAP steps on a target until its gap closes, in closed form) is
  timed beside them;
* Fig. 12 / SPEC §9: FW-SWAP at least 20x faster than an interior-point solver (Clarabel,
  standing in for CPLEX) at 1,000 targets, to the same objective within 1e-3 relative.

Problems come from one of three sources:

* ``--tracker-frames N``: the BQP tracker (:class:`tracker.bqp.tracker.BQPTracker`) itself runs N
  frames on a crowd rendered by :func:`synth_data.sequence.synthetic_crowd` at each size and
  its recorded per-frame QPs are taken;
* ``--from-npz FILE``: QPs dumped from tracking frames with :func:`tracker.bqp.qp.save_many`
  (e.g. ``BQPTracker(record_qps=True).recorded_qps``), for instance on real video;
* default: :func:`synthetic_frame_qp`, which builds a denser frame the way the tracker
  does: targets on a dense jittered lattice, a dense candidate grid in each
target's search window (2x the target size), appearance + motion linear costs with
look-alike neighbours, and ``Q = w_sp C_sp + w_g C_g`` where ``C_sp`` (Eq. 9) and ``C_g``
(Eq. 10, over a minimum spanning tree per group) are sparse normalised Laplacians.

Prints a table and one JSON object on stdout; writes ``solver_convergence.png`` (objective
and duality gap vs iteration for every variant) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import asdict

import numpy as np

from crowdsim.atomic import OVERWRITE_HELP
from tracker.bqp.frank_wolfe import VARIANTS, FWParams, solve
from tracker.bqp.qp import BlockQP, load_many
from tracker.testing import FrameSpec, synthetic_frame_qp

# ------------------------------------------------------------------------------ benchmark
CLAIM_SPEEDUP: float = 20.0
"""FW-SWAP must be at least this many times faster than the interior-point solver (SPEC §9)."""
CLAIM_REL_OBJECTIVE: float = 1e-3
"""... to the same relaxed objective within this relative difference."""
CLAIM_SIZE: int = 1000
"""Number of targets at which the speed claim is checked."""
PLOT: str = "solver_convergence.png"
"""The convergence plot's name in ``--out``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sizes",
        default="100,300,1000",
        help="comma-separated numbers of targets of the synthetic frames (default: %(default)s)",
    )
    parser.add_argument(
        "--frames",
        type=int,
        default=2,
        help="synthetic frames (QPs) per size (default: %(default)s)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic frames")
    parser.add_argument(
        "--from-npz",
        action="append",
        default=[],
        metavar="FILE",
        help="QPs dumped from real tracking frames (tracker.bqp.qp.save_many); "
        "repeatable; replaces the synthetic frames",
    )
    parser.add_argument(
        "--tracker-frames",
        type=int,
        default=0,
        metavar="N",
        help="instead of synthetic QPs, run the BQP tracker for N frames on a "
        "rendered crowd of each --sizes (crowdsim.bench.track) and take "
        "the QPs of its last --frames frames",
    )
    parser.add_argument(
        "--tracker-dense",
        action="store_true",
        help="with --tracker-frames: dense candidates instead of the "
        "tracker's default speed-up sampling",
    )
    parser.add_argument(
        "--save-npz", metavar="FILE", help="also write the benchmarked QPs to FILE (.npz)"
    )
    parser.add_argument(
        "--eps", type=float, default=0.01, help="duality-gap stop of every FW variant (paper: 0.01)"
    )
    parser.add_argument(
        "--max-iter",
        type=int,
        default=20_000_000,
        help="iteration cap (block steps) of every FW variant",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="timed runs per FW variant and QP; the median is reported",
    )
    parser.add_argument(
        "--reference",
        choices=("clarabel", "osqp", "none"),
        default="clarabel",
        help="interior-point / ADMM reference solver",
    )
    parser.add_argument(
        "--reference-tol",
        type=float,
        default=1e-6,
        help="relative/absolute gap tolerance of the reference solver "
        "(default: %(default)s; FW's eps=0.01 is ~1e-5 relative here)",
    )
    parser.add_argument(
        "--reference-max-targets",
        type=int,
        default=1000,
        help="skip the reference solver above this many targets",
    )
    parser.add_argument(
        "--out",
        default=os.path.join("benchmarks", "out"),
        help="folder of the convergence plot (default: %(default)s, under the working folder)",
    )
    parser.add_argument("--no-plot", action="store_true", help="skip the PNG")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def _parse_sizes(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--sizes must be comma-separated integers, got {text!r}") from None
    if not sizes or any(s < 1 for s in sizes):
        raise ValueError(f"--sizes must list positive integers, got {text!r}")
    return sizes


def _problems(args: argparse.Namespace) -> list[tuple[str, BlockQP]]:
    if args.from_npz:
        out = []
        for path in args.from_npz:
            for i, qp in enumerate(load_many(path)):
                out.append((f"{os.path.basename(path)}#{i}", qp))
        return out
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if args.tracker_frames:
        return _tracker_problems(args)
    seeds = np.random.SeedSequence(args.seed)
    out = []
    for n in _parse_sizes(args.sizes):
        for f, child in enumerate(seeds.spawn(args.frames)):
            qp = synthetic_frame_qp(FrameSpec(n_targets=n), np.random.default_rng(child))
            out.append((f"synthetic n={n} frame={f}", qp))
    return out


def _tracker_problems(args: argparse.Namespace) -> list[tuple[str, BlockQP]]:
    """QPs recorded by the BQP tracker itself on rendered crowds (``--tracker-frames``)."""
    from crowdsim.bench.track import run_tracker
    from synth_data.sequence import synthetic_crowd
    from tracker.bqp.params import BQPParams
    from tracker.bqp.tracker import BQPTracker

    if args.tracker_frames < args.frames:
        raise ValueError(
            f"--tracker-frames ({args.tracker_frames}) must be >= --frames ({args.frames})"
        )
    out = []
    for n in _parse_sizes(args.sizes):
        crowd = synthetic_crowd(n, args.tracker_frames + 1, seed=args.seed)
        trk = BQPTracker(BQPParams(speedup=not args.tracker_dense), record_qps=True)
        run_tracker(trk, crowd)
        qps = trk.recorded_qps[-args.frames :]
        first = len(trk.recorded_qps) - len(qps) + 1
        out += [(f"tracker n={n} frame={first + i}", qp) for i, qp in enumerate(qps)]
    return out


def _time_fw(qp: BlockQP, params: FWParams, repeats: int):
    """``(result, median wall s, median CPU s)``; CPU time is less inflated than wall time
    when other jobs share the cores."""
    wall, cpu = [], []
    res = None
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        res = solve(qp, params=params)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return res, float(np.median(wall)), float(np.median(cpu))


def _order_txt(order: bool | None) -> str:
    return "n/a" if order is None else ("ok" if order else "NO")


def _plot(path: str, label: str, runs: dict, f_ref: float) -> None:
    from crowdsim.plotting import new_figure, save_figure

    fig, (ax1, ax2) = new_figure(figsize=(11, 4.2), ncols=2)
    for v, res in runs.items():
        it = np.arange(res.history.shape[0])
        ax1.loglog(it + 1, np.maximum(res.history - f_ref, 1e-12), label=f"FW-{v}")
        ax2.loglog(it + 1, np.maximum(res.gap_history, 1e-12), label=f"FW-{v}")
    ax1.set_xlabel("iteration (block steps) + 1")
    ax1.set_ylabel("f(x_k) - f*")
    ax2.set_xlabel("iteration (block steps) + 1")
    ax2.set_ylabel("duality gap")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(f"Frank-Wolfe variants on {label}")
    save_figure(fig, path, dpi=110)


def run(args: argparse.Namespace) -> int:
    from crowdsim.atomic import recorded, require_replaceable
    from crowdsim.checks import require_apart, require_number, require_output_dir

    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    require_number("", "--seed", args.seed, lo=0, integer=True)
    require_number("", "--max-iter", args.max_iter, lo=1, integer=True)
    require_number("", "--frames", args.frames, lo=1, hi=10_000, integer=True)
    require_number("", "--tracker-frames", args.tracker_frames, lo=0, hi=100_000, integer=True)
    require_number("", "--reference-tol", args.reference_tol, lo=0, lo_open=True)
    require_number("", "--reference-max-targets", args.reference_max_targets, lo=0, integer=True)
    if args.save_npz:  # the files are written after the runs: check where they go first
        if not str(args.save_npz).lower().endswith(".npz"):
            raise ValueError(f"--save-npz must end in .npz, got {args.save_npz!r}")
        for given in args.from_npz or ():
            require_apart("--save-npz", args.save_npz, {"--from-npz": given})
        require_replaceable("--save-npz", args.save_npz, args.overwrite)
    if not args.no_plot:
        require_output_dir("--out", args.out)
        require_replaceable("--out", os.path.join(args.out, PLOT), args.overwrite)
    require_number("", "--eps", args.eps, lo=0)
    params = {v: FWParams(variant=v, eps=args.eps, max_iter=args.max_iter) for v in VARIANTS}
    t0 = time.perf_counter()
    problems = _problems(args)
    if args.save_npz:
        from tracker.bqp.qp import save_many

        with recorded(args.save_npz):
            save_many(args.save_npz, [qp for _, qp in problems])
    build_s = time.perf_counter() - t0
    # Compile (or load from cache) the numba kernels outside the timings.
    solve(problems[0][1], params=FWParams(max_iter=1))

    ref_solver = None
    if args.reference != "none":
        from tracker.bqp.qp_baselines import SOLVERS

        ref_solver = SOLVERS[args.reference]

    rows = []
    hdr = (
        f"{'problem':<26} {'n':>5} {'l':>7} {'nnz(Q)':>9} | "
        + " ".join(f"{'it ' + v:>9} {'ms':>7}" for v in VARIANTS)
        + f" | {args.reference:>9} {'ms':>8} {'speedup':>8} {'rel.diff':>9}"
    )
    print(hdr)
    print("-" * len(hdr))
    for label, qp in problems:
        # What a tracker pays per frame besides the solve: validating the problem container.
        t = time.perf_counter()
        BlockQP(qp.c, qp.Q, qp.block_ptr)
        build = time.perf_counter() - t
        row = {
            "problem": label,
            "n_targets": qp.n_blocks,
            "n_vars": qp.n_vars,
            "nnz_Q": int(qp.Q.nnz),
            "blockqp_seconds": build,
            "variants": {},
        }
        for v in VARIANTS:
            res, wall, cpu = _time_fw(qp, params[v], args.repeats)
            row["variants"][v] = {
                "iterations": res.iterations,
                "seconds": wall,
                "cpu_seconds": cpu,
                "converged": res.converged,
                "objective": res.objective,
                "gap": res.gap,
                "rounded_objective": res.rounded_objective,
                "steps": res.steps,
                "support": int(np.count_nonzero(res.x)),
            }
        line = f"{label:<26} {qp.n_blocks:>5} {qp.n_vars:>7} {qp.Q.nnz:>9} | " + " ".join(
            f"{row['variants'][v]['iterations']:>9} {row['variants'][v]['seconds'] * 1e3:>7.1f}"
            for v in VARIANTS
        )
        if ref_solver is not None and qp.n_blocks <= args.reference_max_targets:
            t, cpu = time.perf_counter(), time.process_time()
            ref = ref_solver(qp, tol=args.reference_tol)
            wall = time.perf_counter() - t
            cpu = time.process_time() - cpu
            sw = row["variants"]["swap"]
            scale = max(abs(ref.objective), 1e-12)
            rel, rel_block = (
                (row["variants"][v]["objective"] - ref.objective) / scale for v in ("swap", "block")
            )
            row["reference"] = {
                "solver": args.reference,
                "seconds": wall,
                "cpu_seconds": cpu,
                "solve_seconds": ref.solve_time,
                "status": ref.status,
                "iterations": ref.iterations,
                "objective": ref.objective,
                "speedup_swap": wall / sw["seconds"],
                "speedup_swap_cpu": cpu / sw["cpu_seconds"],
                "rel_objective_diff": rel,
                "rel_objective_diff_block": rel_block,
            }
            line += (
                f" | {ref.status[:9]:>9} {wall * 1e3:>8.0f} {wall / sw['seconds']:>7.0f}x "
                f"{rel:>9.1e}"
            )
        print(line, flush=True)
        rows.append(row)

    # Per size: mean iterations, median times, the claims.
    sizes = sorted({r["n_targets"] for r in rows})
    summary = {}
    for n in sizes:
        rs = [r for r in rows if r["n_targets"] == n]
        s = {
            f"iterations_{v}": float(np.mean([r["variants"][v]["iterations"] for r in rs]))
            for v in VARIANTS
        }
        s.update(
            {
                f"ms_{v}": 1e3 * float(np.median([r["variants"][v]["seconds"] for r in rs]))
                for v in VARIANTS
            }
        )
        s.update(
            {
                f"cpu_ms_{v}": 1e3 * float(np.median([r["variants"][v]["cpu_seconds"] for r in rs]))
                for v in VARIANTS
            }
        )
        s["ms_blockqp"] = 1e3 * float(np.median([r["blockqp_seconds"] for r in rs]))
        s["all_converged"] = all(r["variants"][v]["converged"] for r in rs for v in VARIANTS)
        # Frames with (almost) no quadratic coupling are solved at the start vertex by every
        # variant: they say nothing about Fig. 13 (None, not False).
        trivial = s["iterations_plain"] <= n
        s["order_swap_lt_away_lt_plain"] = (
            None
            if trivial
            else bool(s["iterations_swap"] < s["iterations_away"] < s["iterations_plain"])
        )
        refs = [r["reference"] for r in rs if "reference" in r]
        if refs:
            s["ref_ms"] = 1e3 * float(np.median([r["seconds"] for r in refs]))
            s["speedup_swap_vs_ref"] = float(np.median([r["speedup_swap"] for r in refs]))
            s["speedup_swap_vs_ref_cpu"] = float(np.median([r["speedup_swap_cpu"] for r in refs]))
            s["max_abs_rel_objective_diff"] = float(max(abs(r["rel_objective_diff"]) for r in refs))
            s["max_abs_rel_objective_diff_block"] = float(
                max(abs(r["rel_objective_diff_block"]) for r in refs)
            )
        summary[str(n)] = s

    print()
    print(
        f"{'n':>5} | "
        + " ".join(f"{'it ' + v:>9}" for v in VARIANTS)
        + " | "
        + " ".join(f"{'ms ' + v:>9}" for v in VARIANTS)
        + f" | {'order':>5} | {'ref ms':>8} {'speedup':>8} {'cpu':>6} {'rel.diff':>9}"
    )
    for n in sizes:
        s = summary[str(n)]
        ref_txt = (
            f"{s['ref_ms']:>8.0f} {s['speedup_swap_vs_ref']:>7.0f}x "
            f"{s['speedup_swap_vs_ref_cpu']:>5.0f}x {s['max_abs_rel_objective_diff']:>9.1e}"
            if "speedup_swap_vs_ref" in s
            else f"{'-':>8} {'-':>8} {'-':>6} {'-':>9}"
        )
        print(
            f"{n:>5} | "
            + " ".join(f"{s['iterations_' + v]:>9.0f}" for v in VARIANTS)
            + " | "
            + " ".join(f"{s['ms_' + v]:>9.1f}" for v in VARIANTS)
            + f" | {_order_txt(s['order_swap_lt_away_lt_plain']):>5} | {ref_txt}"
        )
    print(
        "(iterations: mean block steps; ms: median wall; order: swap < away < plain, n/a when "
        "plain FW needs <= n steps (no coupling); speedup: reference wall / FW-SWAP wall, cpu: "
        "same on process CPU time; rel.diff: max |f_swap - f_ref| / |f_ref|)"
    )

    orders = [summary[str(n)]["order_swap_lt_away_lt_plain"] for n in sizes]
    claims = {
        "fig13_order_all_sizes": all(o for o in orders if o is not None)
        if any(o is not None for o in orders)
        else None
    }
    big = summary.get(str(CLAIM_SIZE))
    if big is not None and "speedup_swap_vs_ref" in big:
        claims["speedup_at_1000"] = big["speedup_swap_vs_ref"]
        claims["speedup_at_1000_cpu"] = big["speedup_swap_vs_ref_cpu"]
        claims["speedup_at_1000_ok"] = big["speedup_swap_vs_ref"] >= CLAIM_SPEEDUP
        claims["rel_objective_at_1000_ok"] = (
            big["max_abs_rel_objective_diff"] <= CLAIM_REL_OBJECTIVE
        )

    plot_path = None
    if not args.no_plot:
        label, qp = max(problems, key=lambda p: p[1].n_blocks)
        rec = {}
        for v in VARIANTS:
            first = next(r for r in rows if r["problem"] == label)["variants"][v]
            rec[v] = solve(
                qp,
                params=FWParams(
                    variant=v, eps=args.eps, max_iter=first["iterations"], record_history=True
                ),
            )
        f_ref = min(r.objective for r in rec.values())
        ref_row = next(r for r in rows if r["problem"] == label).get("reference")
        if ref_row is not None:
            f_ref = min(f_ref, ref_row["objective"])
        os.makedirs(args.out, exist_ok=True)
        plot_path = os.path.join(args.out, PLOT)
        with recorded(plot_path):
            _plot(plot_path, label, rec, f_ref - 1e-9)
        print(f"\nconvergence plot: {plot_path}")

    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    report = {
        "benchmark": "solver",
        "eps": args.eps,
        "reference": args.reference,
        "reference_tol": args.reference_tol,
        "source": "npz" if args.from_npz else ("tracker" if args.tracker_frames else "synthetic"),
        "frame_spec": None
        if args.from_npz or args.tracker_frames
        else {k: v for k, v in asdict(FrameSpec()).items() if k != "n_targets"},
        "iteration_unit": "block step (one target's simplex per iteration)",
        "timing": "FW: median wall seconds of --repeats solve() calls (BlockQP validation "
        "reported apart as blockqp_seconds); reference: one run, wall incl. its "
        "matrix assembly and setup (solve_seconds: its solve phase only)",
        "summary": summary,
        "claims": claims,
        "problems": rows,
        "plot": plot_path,
        "build_seconds": build_s,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "loadavg": load},
    }
    print(json.dumps(report))
    return 0
