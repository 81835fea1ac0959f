"""``crowdsim detect INPUT --out points.csv``: head points from the trained detector.

INPUT is a video file or a MOTChallenge sequence folder. The output is the points CSV the
trackers read (``crowdsim track --init points.csv``): a header ``frame,id,x,y`` and one row per
head, pixels, frames 1-based. By default only frame 1 is detected (the people a tracker starts
from, ids 1, 2, ...); ``--frames N`` (N > 1) and ``--all`` detect more frames and write
per-frame detections, not tracks: the header is ``frame,detection,x,y`` and each head of each
frame has its own number, so ``track --init`` refuses the file (it would start every
detection as a new person). ``--scores`` adds a ``score`` column.
"""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.atomic import OVERWRITE_HELP

    p = sub.add_parser(
        "detect",
        help="find heads with the trained detector, write a frame,id,x,y points CSV",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument("input", help="video file or MOT sequence folder")
    p.add_argument("--out", required=True, metavar="CSV", help="points CSV to write")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    frames = p.add_mutually_exclusive_group()
    frames.add_argument(
        "--frames",
        type=int,
        default=1,
        metavar="N",
        help="detect the first N frames (1); past frame 1 the file holds per-frame detections "
        "(header frame,detection,x,y), not an --init file",
    )
    frames.add_argument("--all", action="store_true", help="detect every frame")
    p.add_argument("--weights", default=None, metavar="FILE", help="weights (default: shipped)")
    p.add_argument(
        "--threshold", type=float, default=None, metavar="T", help="detection threshold in (0, 1)"
    )
    p.add_argument(
        "--scores", action="store_true", help="add a score column (then not an --init file)"
    )
    p.add_argument(
        "--template-size",
        type=int,
        default=None,
        metavar="PX",
        help="head size in px (default: the sequence's, else 12); heads above the 8-16 px the "
        "detector learnt from are found on the frame shrunk to 12 px heads",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def head_size(src: object, given: int | None) -> float:
    """The head size, px, the detector is told for ``src``: ``given`` (``--template-size``),
    else the sequence's own where it is a head size (a video's, a MOT folder's
    ``templateSize`` or head boxes), else 12: a MOT17 folder's template size is the median
    width of its body boxes, not of heads."""
    if given:
        return float(given)
    info = getattr(src, "info", None)
    if info is not None and "templateSize" not in info and getattr(src, "box_type", "") != "head":
        return 12.0
    return float(getattr(src, "template_size", 12))


def detector_params(weights: str | None, threshold: float | None, flag: str) -> object:
    """:meth:`tracker.detect.DetectorParams.given`, a bad threshold named by its flag."""
    from tracker.detect import DetectorParams

    try:
        return DetectorParams.given(weights, threshold)
    except ValueError as exc:
        raise ValueError(str(exc).replace("DetectorParams.threshold", flag)) from None


def run(args: argparse.Namespace) -> int:
    import io
    import itertools
    import time
    from pathlib import Path

    from crowdsim.atomic import recorded, require_replaceable, write_text_atomic
    from crowdsim.checks import require_apart
    from crowdsim.progress import progress_bar
    from synth_data.sequence import open_sequence
    from tracker.base import MAX_TEMPLATE_PX
    from tracker.detect import HeadDetector

    if not args.all and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if Path(args.out).suffix.lower() != ".csv":
        raise ValueError(f"--out must end in .csv, got {args.out!r}")
    require_apart("--out", args.out, {"INPUT": args.input, "--weights": args.weights})
    out = require_replaceable("--out", args.out, args.overwrite)  # before any work
    if args.template_size is not None and not 2 <= args.template_size <= MAX_TEMPLATE_PX:
        raise ValueError(
            f"--template-size must be in [2, {MAX_TEMPLATE_PX}] px, got {args.template_size}"
        )
    detector = HeadDetector(detector_params(args.weights, args.threshold, "--threshold"))
    src = open_sequence(args.input)
    detector.template_size = head_size(src, args.template_size)
    n = src.length if args.all else min(args.frames, src.length)
    buf = io.StringIO()
    key = "id" if n == 1 else "detection"  # detections of several frames are no --init file
    buf.write(f"frame,{key},x,y,score\n" if args.scores else f"frame,{key},x,y\n")
    next_id, done, seconds = 1, 0, 0.0
    bar = progress_bar(total=n, desc="detect", unit="frame", enabled=not args.no_progress)
    try:
        for t, frame in enumerate(itertools.islice(src.frames(), n), start=1):
            t0 = time.perf_counter()
            pts, scores = detector.detect_points(frame)
            seconds += time.perf_counter() - t0
            for (x, y), s in zip(pts, scores, strict=True):
                row = f"{t},{next_id},{x:.2f},{y:.2f}"
                buf.write(f"{row},{s:.4f}\n" if args.scores else f"{row}\n")
                next_id += 1
            done += 1
            bar.update(1)
    finally:
        bar.close()
    if done == 0:
        raise ValueError(f"{args.input}: no frames to detect in")
    with recorded(out):
        write_text_atomic(out, buf.getvalue())
    print(
        f"{next_id - 1} heads in {done} frame(s) of {src.width}x{src.height}, "
        f"{done / max(seconds, 1e-9):.1f} frames/s -> {out}",
        file=sys.stderr,
    )
    return 0
