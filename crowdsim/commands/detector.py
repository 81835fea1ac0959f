"""``crowdsim detector train|eval``: train the head-point detector, measure it.

``crowdsim detector train --out DIR [--seed N] [--iterations N] [--sequences N] [--workers N]``
    Generates training sequences of every scene and difficulty (``ucf9``-like specs included,
    heads of 8-16 px), trains the network and writes ``DIR/head_points.pt`` with
    ``DIR/head_points.json`` (the command, the data, the settings) and ``DIR/loss.png``. A run
    that stops resumes from ``DIR/checkpoint.pt`` when the same command runs again; the same
    seed gives the same weights. See :mod:`crowdsim.lab.detector`.

``crowdsim detector eval [--weights FILE] [--threshold T] --out DIR``
    Precision, recall and F1 at 5 px and the mean localisation error, per kind (default
    appearance, hard appearance, calibrated ``ucf9``) and per scene or difficulty, on held-out
    sequences never used in training, for the network and the classical LoG baseline side by
    side. ``--tracking`` also tracks every ``ucf9`` sequence with ``--tracker`` (BQP) started
    from the detector (births every 10 frames) and from the ground truth, and compares acc@15
    over the people matched at frame 1. Writes ``DIR/detector_eval.json`` and
    ``DIR/detector_eval.md``.
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "detector",
        help="train or evaluate the head-point detector",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    verbs = p.add_subparsers(dest="verb", metavar="VERB")
    verbs.required = True
    t = verbs.add_parser(
        "train",
        help="train the head detector on generated sequences (resumable)",
        description="Train the head-point detector on generated sequences of every scene and "
        "difficulty; the same command resumes a stopped run; a seed gives the same weights.",
    )
    from crowdsim.lab.detector import TrainConfig

    d = TrainConfig()
    t.add_argument(
        "--out", required=True, metavar="DIR", help="output folder (new, or a run to resume)"
    )
    t.add_argument(
        "--seed", type=int, default=d.seed, help=f"seed of data, weights, batches ({d.seed})"
    )
    t.add_argument(
        "--iterations",
        type=int,
        default=d.iterations,
        metavar="N",
        help=f"optimiser steps ({d.iterations})",
    )
    t.add_argument(
        "--sequences",
        type=int,
        default=d.sequences,
        metavar="N",
        help=f"generated training sequences, at least one per scene kind of the mix, up to "
        f"100000 ({d.sequences})",
    )
    t.add_argument(
        "--batch", type=int, default=d.batch, metavar="B", help=f"crops per step ({d.batch})"
    )
    t.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="processes rendering the data (cores)",
    )
    t.add_argument(
        "--overwrite",
        action="store_true",
        help="replace head_points.pt, head_points.json and loss.png in --out even when "
        "crowdsim cannot prove it wrote them (a user's, or ones edited since)",
    )
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.set_defaults(func=run_train)

    e = verbs.add_parser(
        "eval",
        help="precision / recall / F1 at 5 px on held-out sequences, beside a LoG baseline",
        description="Score the head detector and the classical LoG baseline on held-out "
        "sequences (default and hard appearance, calibrated ucf9), per scene and difficulty.",
    )
    e.add_argument("--weights", default=None, metavar="FILE", help="weights (default: shipped)")
    e.add_argument(
        "--threshold", type=float, default=None, metavar="T", help="detection threshold in (0, 1)"
    )
    e.add_argument(
        "--per-kind", type=int, default=9, metavar="N", help="held-out default/hard sequences (9)"
    )
    e.add_argument("--frames", type=int, default=3, metavar="N", help="frames per sequence (3)")
    e.add_argument("--radius", type=float, default=5.0, metavar="PX", help="match radius, px (5)")
    e.add_argument(
        "--baseline-sequences",
        type=int,
        default=60,
        metavar="N",
        help="training sequences the LoG baseline's threshold is fitted on (60)",
    )
    e.add_argument(
        "--tracking",
        action="store_true",
        help="also track every ucf9 sequence from the detector and from the ground truth",
    )
    e.add_argument("--tracker", default="bqp", metavar="NAME", help="tracker of --tracking (bqp)")
    e.add_argument(
        "--tracking-frames",
        type=int,
        default=None,
        metavar="N",
        help="track only the first N frames of each sequence with --tracking (default: all)",
    )
    e.add_argument("--workers", type=int, default=None, metavar="N", help="render processes")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder")
    e.add_argument("--no-progress", action="store_true", help="no progress bar")
    e.set_defaults(func=run_eval)


def _workers(value: int | None) -> int:
    import os

    from crowdsim.checks import require_workers

    if value is None:
        return os.cpu_count() or 1
    return require_workers("--workers", value)


def run_train(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from crowdsim.lab.detector import TrainConfig, train

    try:
        config = replace(
            TrainConfig(),
            seed=args.seed,
            iterations=args.iterations,
            sequences=args.sequences,
            batch=args.batch,
        )
    except ValueError as exc:  # name the flag the user gave, not the config's field
        raise ValueError(re.sub(r"\bTrainConfig\.(\w+)", r"--\1", str(exc))) from None
    command = "crowdsim " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    rec = train(
        args.out,
        config,
        workers=_workers(args.workers),
        progress=not args.no_progress,
        command=command,
        log=lambda m: print(m, file=sys.stderr),
        overwrite=args.overwrite,
    )
    print(
        f"trained {config.iterations} steps in {rec['train_seconds']:.0f} s (data "
        f"{rec['data_seconds']:.0f} s), final loss {rec['final_loss']:.3f} -> "
        f"{args.out}/head_points.pt",
        file=sys.stderr,
    )
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from crowdsim.commands.detect import detector_params
    from crowdsim.lab.detector import check_eval_out, evaluate, write_eval
    from tracker.registry import get

    check_eval_out(args.out)  # before any work
    get(args.tracker)  # an unknown name lists the valid ones, with or without --tracking
    detector_params(args.weights, args.threshold, "--threshold")
    if args.tracking_frames is not None:
        if not args.tracking:
            raise ValueError("--tracking-frames needs --tracking")
        from crowdsim.checks import require_number

        require_number("", "--tracking-frames", args.tracking_frames, lo=2, integer=True)
    rep = evaluate(
        weights=args.weights,
        threshold=args.threshold,
        per_kind=args.per_kind,
        frames=args.frames,
        radius=args.radius,
        baseline_sequences=args.baseline_sequences,
        workers=_workers(args.workers),
        progress=not args.no_progress,
    )
    if args.tracking:
        from crowdsim.lab.detector import tracking_table

        rep["tracking"] = tracking_table(
            tracker=args.tracker,
            weights=args.weights,
            threshold=args.threshold,
            frames=args.tracking_frames,
            progress=not args.no_progress,
        )
    md = write_eval(args.out, rep)
    print(md)
    return 0
