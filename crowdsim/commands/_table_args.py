"""Flags shared by the commands that fan work out (one place, one wording).

:func:`add_jobs_arguments`: ``--workers``, ``--backend``, ``--address`` of the jobs runner
(:mod:`crowdsim.jobs`), for ``generate``, ``compare`` and ``ablation``;
:func:`add_table_arguments`: everything ``compare`` and ``ablation`` take.
"""

from __future__ import annotations

import argparse
import sys


def add_jobs_arguments(p: argparse.ArgumentParser, workers_help: str, workers: int | None) -> None:
    """``--workers N``, ``--backend local|ray``, ``--address ADDR`` (see :mod:`crowdsim.jobs`)."""
    p.add_argument("--workers", type=int, default=workers, metavar="N", help=workers_help)
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local process pool (default) or Ray tasks",
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="Ray cluster address (default: start a local Ray instance)",
    )


def add_table_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--suite",
        default="ucf9",
        choices=("ucf9", "galleria", "stress"),
        help="suite to run (default ucf9)",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="only these sequences")
    p.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="truncate every sequence to its first N frames (quick runs)",
    )
    add_jobs_arguments(p, "parallel cells (local processes or Ray tasks; default 1)", 1)
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder: sequences/, cells.json (resume), table.md, table.csv, curves/*.png",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")


def run_table_command(args: argparse.Namespace, rows, title: str, paper_table: str) -> int:
    from crowdsim.experiments import run_table

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    text = run_table(
        rows,
        args.suite,
        args.out,
        only=args.only,
        frames=args.frames,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        progress=not args.no_progress,
        title=title,
        paper_table=paper_table,
        log=log,
    )
    print(text)
    print(
        f"table -> {args.out}/table.md, {args.out}/table.csv; curves -> {args.out}/curves/",
        file=sys.stderr,
    )
    return 0
