"""``crowdsim demo``: the main job on an embedded default (what ``make demo`` runs)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the embedded default job and print its results",
                       description="Simulate the default marathon scene and print its table.")
    p.add_argument("--out", type=Path, default=Path("demo_out"), metavar="DIR",
                   help="output folder (default ./demo_out)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.cli import main

    args.out.mkdir(parents=True, exist_ok=True)
    return main(["simulate", "marathon", "--agents", "300", "--steps", "250", "--seed", "0",
                 "--out", str(args.out / "marathon.npz")])
