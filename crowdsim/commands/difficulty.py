"""``crowdsim difficulty``: which difficulty of a calibrated suite costs which tracker.

``crowdsim difficulty --suite NAME|DIR [--only SEQ ...] [--trackers NAME ...] [--groups G ...]
[--cmc] [--frames N] [--workers N] [--backend local|ray [--address ADDR]] --out DIR``

For every calibrated sequence, tracks the calibrated spec, the spec with one group of
appearance / camera knobs put back to its uncalibrated value (look-alike heads, packing, gait,
clutter, noise and codec, blur, flicker, shake; one group at a time, on the calibrated spec's
ground, so that the still twin of a shaken spec differs by the shake alone) and the
uncalibrated spec, with each tracker (default: ncc pnmc bqp). Writes the run's ``table.md`` /
``table.csv`` and ``attribution.md`` / ``attribution.json``: the acc@15 points each group costs
each tracker.
``--groups`` limits the variants to some groups; ``--cmc`` also runs each tracker with
camera-motion compensation and reports the points it regains, and its share of what shake
costs.
Resumable like ``compare`` (see :mod:`crowdsim.lab.difficulty`); ``--suite`` takes a built-in
name or a calibrated suite folder (``crowdsim calibrate --out``).
"""

from __future__ import annotations

import argparse
import sys

from crowdsim.commands._table_args import add_table_arguments, table_run_kwargs


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.knobs import difficulty_groups

    p = sub.add_parser(
        "difficulty",
        help="attribute a calibrated suite's difficulty to its knob groups, per tracker",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    add_table_arguments(p, writes=", attribution.md, attribution.json")
    p.add_argument(
        "--trackers",
        nargs="+",
        default=["ncc", "pnmc", "bqp"],
        metavar="NAME",
        help="registered trackers to run (default: ncc pnmc bqp)",
    )
    p.add_argument(
        "--groups",
        nargs="+",
        metavar="G",
        help="only these knob groups (default: all of " + ", ".join(difficulty_groups()) + ")",
    )
    p.add_argument(
        "--cmc",
        action="store_true",
        help="also run each tracker with camera-motion compensation (cmc=true) and report "
        "the points it regains and its share of what shake costs",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.lab.difficulty import attribute, attribution_table

    doc = attribute(
        args.suite,
        args.out,
        trackers=args.trackers,
        groups=args.groups,
        cmc=args.cmc,
        **table_run_kwargs(args),
    )
    print(attribution_table(doc))
    print(f"-> {args.out}/attribution.md, {args.out}/table.md", file=sys.stderr)
    return 0
