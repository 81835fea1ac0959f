"""``crowdsim track INPUT``: track people through a sequence and write MOT results.

INPUT is a MOTChallenge sequence folder (targets start from its ground truth: the initial
targets at frame 1, every later id born at its first frame) or a video file (targets come from
``--init points.csv`` with rows ``frame,id,x,y`` in pixels; rows after frame 1 are births).
Results are MOT text rows, one head box of the template size centred on each tracked point.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

TRACKERS = ("bqp", "ncc")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="track a sequence or video (BQP or NCC), write MOT results",
                       description=__doc__.splitlines()[0].replace("``", ""))
    p.add_argument("input", help="MOT sequence folder or video file")
    p.add_argument("--tracker", choices=TRACKERS, default="bqp",
                   help="bqp: the BQP/Frank-Wolfe tracker; ncc: independent NCC templates")
    p.add_argument("--out", required=True, help="MOT results file to write")
    p.add_argument("--init", help="points CSV (frame,id,x,y or id,x,y); required for a video")
    p.add_argument("--video", help="write an overlay MP4 (gt green, tracks yellow)")
    p.add_argument("--evaluate", action="store_true",
                   help="print the accuracy table against the sequence's ground truth")
    p.add_argument("--template-size", type=int, default=None,
                   help="template (head) size in px (default: from seqinfo.ini, or 12)")
    p.add_argument("--frames", type=int, default=None, help="track only the first N frames")
    p.add_argument("--appearance", choices=("kcf", "ncc"), default="kcf",
                   help="appearance model of the BQP tracker")
    p.add_argument("--dense", action="store_true",
                   help="BQP with dense candidates instead of the default speed-up sampling "
                   "(m=3 extrema + 10 samples each)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


class _VideoInput:
    """Frames of a video file (the tracker runs on real video, not only on sequences)."""

    def __init__(self, path: Path):
        import cv2

        cap = cv2.VideoCapture(str(path))
        ok, first = cap.read() if cap.isOpened() else (False, None)
        if not ok:
            cap.release()
            raise ValueError(f"{path}: not a readable video file")
        self.path = path
        self.frame_rate = float(cap.get(cv2.CAP_PROP_FPS) or 25.0)
        self.length = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
        self.height, self.width = first.shape[:2]
        cap.release()

    def frames(self):
        import cv2

        cap = cv2.VideoCapture(str(self.path))
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    return
                yield img
        finally:
            cap.release()


def load_input(path: str, init: str | None, template_size: int | None):
    """Open INPUT: returns (source, template_size, (ids, points) init, births, gt or None)."""
    from synth_data.mot import DEFAULT_TEMPLATE_SIZE, read_sequence
    from tracker.mot_io import births_from_ground_truth, births_from_points, read_points_csv

    p = Path(path)
    gt = None
    if p.is_dir():
        src = read_sequence(p)
        size = template_size or src.template_size
        gt_ids, gt_pts = src.gt_points()
        gt = (gt_ids, gt_pts)
    elif p.is_file():
        src = _VideoInput(p)
        size = template_size or DEFAULT_TEMPLATE_SIZE
        if init is None:
            raise ValueError(f"{p}: a video input needs --init points.csv (frame,id,x,y)")
    else:
        raise ValueError(f"{p}: no such sequence folder or video file")
    if template_size is not None and template_size < 2:
        raise ValueError(f"--template-size must be >= 2 px, got {template_size}")
    if init is not None:
        frames, ids, pts = read_points_csv(init)
        (i_ids, i_pts), births = births_from_points(frames, ids, pts)
        if gt is not None and len(ids):
            unknown = sorted(set(ids.tolist()) - set(gt[0].tolist()))
            if unknown and len(gt[0]):
                raise ValueError(f"{init}: ids {unknown[:5]} are unknown to the ground truth "
                                 f"of {p}")
    else:
        if gt is None or len(gt[0]) == 0:
            raise ValueError(f"{p}: no ground truth to start from; pass --init points.csv")
        (i_ids, i_pts), births = births_from_ground_truth(*gt)
    return src, int(size), (i_ids, i_pts), births, gt


def make_tracker(name: str, appearance: str = "kcf", dense: bool = False):
    from tracker.baselines.ncc import NCCTracker
    from tracker.bqp.params import BQPParams
    from tracker.bqp.tracker import BQPTracker

    if name == "bqp":
        return BQPTracker(BQPParams(appearance=appearance, speedup=not dense))
    if name == "ncc":
        return NCCTracker()
    raise ValueError(f"unknown tracker {name!r}; expected one of {TRACKERS}")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from synth_data.mot import write_mot
    from tracker.metrics import evaluate, format_table
    from tracker.mot_io import tracks_to_mot_rows

    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if args.evaluate and not Path(args.input).is_dir():
        raise ValueError("--evaluate needs a sequence folder with ground truth as INPUT")
    src, size, (ids, pts), births, gt = load_input(args.input, args.init, args.template_size)
    tracker = make_tracker(args.tracker, args.appearance, args.dense)
    n_total = src.length if args.frames is None else min(args.frames, src.length or args.frames)
    frames = itertools.islice(src.frames(), n_total)
    result = tracker.track(frames, ids, pts, size, births=births, n_frames=n_total,
                           progress=not args.no_progress)
    rows = tracks_to_mot_rows(result.ids, result.positions, size)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_mot(out, rows)
    t = result.timings
    stages = ", ".join(f"{k} {1000 * v / max(result.n_frames - 1, 1):.1f} ms"
                       for k, v in t.items() if k != "total")
    print(f"{tracker.name}: {result.n_frames} frames, {len(result.ids)} targets, "
          f"{(result.n_frames - 1) / max(t.get('total', 0.0), 1e-9):.1f} frames/s "
          f"({stages} per frame) -> {out}", file=sys.stderr)
    if args.video:
        from tracker.overlay import write_overlay

        gt_pts = gt[1] if gt is not None else None
        write_overlay(args.video, itertools.islice(src.frames(), result.n_frames), size,
                      tracks=result.positions, ground_truth=gt_pts,
                      fps=getattr(src, "frame_rate", 25.0))
        print(f"overlay -> {args.video}", file=sys.stderr)
    if args.evaluate:
        gt_ids, gt_pts = gt
        gt_pts = gt_pts[:result.n_frames]
        report = evaluate(gt_ids, gt_pts, result.ids, result.positions, strict=False)
        print(format_table({tracker.name: report}))
        print(json.dumps({k: v for k, v in report.items() if k != "curve"} |
                         {"fps": float(np.round((result.n_frames - 1) / max(
                             t.get("total", 0.0), 1e-9), 2))}))
    return 0
