"""``crowdsim headroom``: how much a scene-aware tuner and an adaptive policy could win.

``crowdsim headroom (--suite NAME | --scenarios DIST) [--only SEQ ...] [--frames N] [--seeds S]
[--tracker NAME] [--candidates M] [--k K] [--threshold T] [--seed N] --out DIR``

On ``--seeds`` held-out sequences per family (as ``crowdsim heldout`` draws them), scores
``--candidates`` fixed settings (the tracker's defaults and scrambled Sobol points of its
tunables) statically, and a per-segment oracle that copies the tracker's state every ``--k``
frames, tries every candidate on the segment and keeps the best by the ground truth. Reports
per family (a) the best single static setting for all families, (b) the family's own best,
(c) the oracle, and the rooms (b)-(a) and (c)-(b), at ``--threshold`` px. Writes
``DIR/headroom.json`` and ``DIR/headroom.md``; a ``headroom.*`` in DIR that it cannot prove it
wrote is refused. See :mod:`envs.headroom`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from crowdsim.commands._table_args import (
    add_episode_arguments,
    add_tracker_argument,
    episode_objective,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "headroom",
        help="measure the room for scene-aware tuning and adaptive policies (oracle bounds)",
        description=__doc__.split("\n\n")[0].replace("``", "").replace("\n", " "),
    )
    add_episode_arguments(p, only_help="with --suite: these sequences")
    p.add_argument(
        "--seeds", type=int, default=3, metavar="S", help="held-out sequences per family (3)"
    )
    add_tracker_argument(p)
    p.add_argument(
        "--candidates",
        type=int,
        default=17,
        metavar="M",
        help="settings tried: the defaults and M-1 Sobol points (default 17)",
    )
    p.add_argument("--k", type=int, default=25, metavar="K", help="frames per segment (25)")
    p.add_argument(
        "--threshold", type=float, default=5.0, metavar="T", help="accuracy threshold, px (5)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the Sobol candidates (0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.checks import require_number
    from envs.headroom import check_headroom_out, headroom_table, measure_headroom, write_headroom

    require_number("", "--seeds", args.seeds, lo=1, hi=1000, integer=True)
    require_number("", "--candidates", args.candidates, lo=1, hi=1024, integer=True)
    require_number("", "--k", args.k, lo=1, integer=True)
    require_number("", "--threshold", args.threshold, lo=0)
    require_number("", "--seed", args.seed, lo=0, integer=True)
    out = Path(args.out)
    check_headroom_out(out)  # refused before any work
    objective = episode_objective(args, tracker=args.tracker, threshold_px=args.threshold)
    objective.episodes(heldout=True)  # validate suite / scenarios / --only before any work
    doc = measure_headroom(
        objective,
        args.seeds,
        candidates=args.candidates,
        k_frames=args.k,
        seed=args.seed,
        progress=not args.no_progress,
    )
    files = write_headroom(doc, out)
    print(headroom_table(doc), end="")
    print(f"-> {files['headroom.json']}, {files['headroom.md']}")
    return 0
