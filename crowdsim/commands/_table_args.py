"""Flags shared by ``crowdsim compare`` and ``crowdsim ablation`` (one place, one wording)."""

from __future__ import annotations

import argparse
import sys


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
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="parallel cells (local processes or Ray tasks; default 1)",
    )
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
        help="Ray cluster address (default: a local Ray instance)",
    )
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
