"""``crowdsim calibrate``: set a suite's appearance and camera knobs to the papers' difficulty.

``crowdsim calibrate --suite ucf9 [--only SEQ ...] [--trials N] [--out DIR]``

For each sequence with a paper NCC figure, an Optuna study moves the spec's appearance and
camera knobs (never its motion) along one difficulty scale, bracketing the target, until the
independent NCC tracker scores that figure at
15 px, then writes the knobs and the achieved score into the spec file and the suite's
README (see :mod:`crowdsim.lab.calibration`). Studies live in ``DIR/calibration.db`` (SQLite):
a killed run resumes.
"""

from __future__ import annotations

import argparse
import json
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate a suite's difficulty to the papers' NCC scores (writes the suite's specs)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument(
        "--suite",
        default="ucf9",
        choices=("ucf9", "galleria", "stress"),
        help="suite whose specs are calibrated (default ucf9)",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="only these sequences")
    p.add_argument(
        "--trials",
        type=int,
        default=12,
        metavar="N",
        help="Optuna trials per sequence at most (default 12; stops within 1 point)",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="folder of the resumable studies (calibration.db); default: a new temporary folder",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.lab.calibration import calibrate_suite

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results = calibrate_suite(args.suite, only=args.only, trials=args.trials, out=args.out, log=log)
    print(json.dumps(results))
    return 0
