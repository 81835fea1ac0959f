"""``crowdsim calibrate``: set a suite's appearance and camera knobs to the papers' difficulty.

``crowdsim calibrate [--suite NAME|DIR] [--only SEQ ...] [--anchor b-ncc|ncc11] [--trials N]
--out DIR [--study FILE] [--update-suite [--force]]``

For each sequence with a paper figure for the anchor, an Optuna study moves the spec's
appearance and camera knobs (never its motion) along one difficulty scale, bracketing the
target, until the anchor's tracker scores that figure at 15 px (see
:mod:`crowdsim.lab.calibration`).

The anchor
    b-ncc (default): paper 1's B(NCC) row of Table 3, a plain template tracker, matched by our
    BQP tracker with the appearance term only and NCC appearance; the camera stays fixed and
    noise, blur, flicker and compression stay within what real surveillance or web video has
    (crowdsim generate --help lists each knob's realistic end and its source).
    ncc11: the papers' NCC column ([11]'s weaker implementation), matched by the independent
    NCC tracker with every knob free up to its hard end, camera shake included (how the
    ucf9-shake suite was made).

Where it writes
    ``--out DIR`` (required) becomes a calibrated *suite folder*: every spec file of the suite
    (the calibrated ones with their new knobs and the achieved score), ``README.md`` (the
    papers' figures beside the achieved), a copy of ``paper.json``, ``calibrate.json`` (the
    record of what was written, with checksums) and the studies ``calibration.db``. Use it
    with ``--suite DIR`` in ``generate``, ``compare``, ``ablation``, ``difficulty`` and
    ``calibrate``. ``DIR`` must be new, empty, or an earlier ``calibrate --out`` of the same
    suite: a rerun resumes its studies, and replaces only files whose checksum proves they
    are its own and unchanged.

The suite itself is never changed unless ``--update-suite`` is given; even then a sequence
whose new calibration is further from the paper's figure than the one its spec records is
kept (said per sequence) unless ``--force``. ``--study FILE`` keeps the studies in another
SQLite file; a file that is not SQLite, an SQLite database with other tables, or an Optuna
file with a study not made by calibrate is refused, and nothing is written into it.

Prints the results as one JSON object. Exit codes: 0 done; 2 bad input (one line naming the
flag, file or value; nothing written); 130 SIGINT, 143 SIGTERM (one line: finished trials
and sequences are kept, rerun to resume).
"""

from __future__ import annotations

import argparse
import json
import re
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate a suite's difficulty to a paper row (into a new suite folder)",
        description=__doc__.split("\n\n")[0].replace("``", ""),
        # the docstring's Sphinx roles read as plain names in --help
        epilog=re.sub(r":mod:`([^`]+)`", r"\1", "\n\n".join(__doc__.split("\n\n")[2:])).replace(
            "``", ""
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--suite",
        default="ucf9",
        metavar="NAME|DIR",
        help="built-in suite (ucf9, ucf9-shake, ucf9-drone, galleria, stress) or a suite "
        "folder of spec files (default ucf9)",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="only these sequences")
    p.add_argument(
        "--anchor",
        default="b-ncc",
        metavar="b-ncc|ncc11",
        help="the paper row to match: b-ncc (paper 1's B(NCC), static camera; default) or "
        "ncc11 (the papers' NCC column)",
    )
    p.add_argument(
        "--trials",
        type=int,
        default=12,
        metavar="N",
        help="Optuna trials per sequence at most (default 12, at most 200; stops within 1 point)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="the calibrated suite folder to write (new, empty, or an earlier calibrate "
        "--out of the same suite, which is resumed)",
    )
    p.add_argument(
        "--study",
        metavar="FILE",
        help="SQLite file of the resumable studies (default DIR/calibration.db)",
    )
    p.add_argument(
        "--update-suite",
        action="store_true",
        help="also write each calibration into the suite's own spec files (never a worse "
        "one than a spec records, unless --force)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="with --update-suite: replace a suite spec's calibration even by a worse one",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.lab.calibration import calibrate_suite

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    results = calibrate_suite(
        args.suite,
        out=args.out,
        only=args.only,
        anchor=args.anchor,
        trials=args.trials,
        study=args.study,
        update_suite=args.update_suite,
        force=args.force,
        log=log,
    )
    print(json.dumps(results))
    log(
        f"calibrated suite -> {args.out} (use --suite {args.out} with generate, compare, "
        "ablation, difficulty)"
    )
    return 0
