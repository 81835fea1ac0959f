"""``crowdsim evaluate RESULTS.txt SEQ_DIR``: the papers' metric and CLEAR MOT / IDF1 / HOTA.

The papers' metric is the percentage of ground-truth points with a tracked point of the same
id within T px (T = 0..25; tables at 5 and 15 px). CLEAR MOT, IDF1 and HOTA come from
TrackEval with the point similarity max(0, 1 - d / T_sim) (T_sim = --similarity-px).

Result ids: when they are the ground truth's (a point tracker's), acc@T compares each person
with the track of their id, and a row whose id the ground truth does not know (a stray row,
a negative id) is scored as unmatched and counted in the output. When they are a tracker's
own (ByteTrack's 0, 1, 2, ...), each track stands for the person it follows in most frames
(majority vote). The output says which; see :func:`tracker.metrics.resolve_id_mapping`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.atomic import OVERWRITE_HELP

    p = sub.add_parser(
        "evaluate",
        help="score MOT results against a sequence's ground truth",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument("results", help="MOT results file (frame,id,left,top,w,h,...)")
    p.add_argument("sequence", help="MOT sequence folder with gt/gt.txt")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--similarity-px",
        type=float,
        default=15.0,
        help="T_sim of the point similarity fed to TrackEval (MOTA, IDF1, HOTA), px in "
        "(0, 1000] (default 15); acc@T never depends on it",
    )
    p.add_argument(
        "--metrics",
        choices=("full", "accuracy"),
        default="full",
        help="full: acc@T and TrackEval's MOTA, IDF1, HOTA (default); accuracy: the papers' "
        "acc@T alone, for crowds too large for TrackEval's dense tables (thousands of people)",
    )
    p.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="score the first N frames only (results of a run cut with track --frames N)",
    )
    p.add_argument(
        "--annotated-frames",
        action="store_true",
        help="score only the frames that hold ground truth (a few hand-annotated frames: "
        "elsewhere every tracked point would count as a false positive)",
    )
    p.add_argument("--plot", help="write the accuracy-curve PNG here")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=run)


def load_results(results: str, seq_dir: str):
    """Read RESULTS and SEQ_DIR: returns (seq, gt ids, gt points, result ids, result points)."""
    import numpy as np

    from synth_data.mot import read_mot_file, read_sequence
    from tracker.mot_io import mot_rows_to_tracks

    seq = read_sequence(seq_dir)  # a binary seqinfo.ini or gt.txt is named by the reader
    gt_ids, gt_pts = seq.gt_points()
    if len(gt_ids) == 0:
        if len(seq.gt):  # rows, but none counts: MOT's conf and class columns
            raise ValueError(
                f"{seq_dir}: gt/gt.txt has {len(seq.gt)} rows but none with conf > 0 and class "
                "1 (a pedestrian), the rows that count as ground truth (a results file's "
                "class -1 and conf -1 are not)"
            )
        raise ValueError(f"{seq_dir}: the sequence has no ground truth (gt/gt.txt)")
    rows = read_mot_file(results)
    ids, pts = mot_rows_to_tracks(
        rows, seq.length, source=str(results), head_in_body=_body_boxes(results, seq, rows)
    )
    if len(ids):
        finite = np.isfinite(pts).all(-1)
        xy = pts[finite]
        margin = seq.template_size
        outside = (
            (xy[:, 0] < -margin)
            | (xy[:, 0] > seq.width + margin)
            | (xy[:, 1] < -margin)
            | (xy[:, 1] > seq.height + margin)
        )
        if outside.any():
            bad = xy[outside][0]
            raise ValueError(
                f"{results}: point ({bad[0]:.1f}, {bad[1]:.1f}) lies outside the "
                f"{seq.width}x{seq.height} frames of {seq_dir} (mismatched "
                "frame sizes?)"
            )
    return seq, gt_ids, gt_pts, ids, pts


def _body_boxes(results: str, seq, rows) -> float | None:
    """:data:`synth_data.mot.HEAD_IN_BODY` when the sequence's ground truth is read as
    full-body boxes (a MOTChallenge folder) and the results hold tall boxes too, so that both
    give the head point the same way (the results' box centres lay 0.42 box heights below
    the ground truth's heads: acc@15 0 % for a copy of the ground truth); with a note. Else
    ``None``: the results' box centres."""
    from crowdsim.checks import note_line
    from synth_data.mot import HEAD_IN_BODY, TALL_BOXES, box_aspect

    # the rows' own check names a bad box later (mot_rows_to_tracks)
    if seq.box_type != "body" or not len(rows) or not box_aspect(rows) >= TALL_BOXES:
        return None
    print(
        note_line(
            "evaluate",
            f"{results} holds body boxes, as {seq.name}'s ground truth does: both are read as "
            f"the head, {HEAD_IN_BODY:g} of a box's height below its top",
        ),
        file=sys.stderr,
    )
    return HEAD_IN_BODY


MAX_SIMILARITY_PX = 1000.0


def check_args(args: argparse.Namespace) -> None:
    """Validate the flags and paths before reading anything large."""
    import math

    from crowdsim.atomic import require_replaceable
    from crowdsim.checks import require_apart

    if not (math.isfinite(args.similarity_px) and 0 < args.similarity_px <= MAX_SIMILARITY_PX):
        raise ValueError(
            f"--similarity-px must be in (0, {MAX_SIMILARITY_PX:g}] px, got {args.similarity_px}"
        )
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    results = Path(args.results)
    if results.is_dir():
        raise ValueError(f"{args.results}: is a folder, not a MOT results file")
    if not results.is_file():
        raise ValueError(f"{args.results}: no such results file")
    if args.plot is not None:
        plot = Path(args.plot)
        if plot.suffix.lower() != ".png":
            raise ValueError(f"--plot must end in .png, got {args.plot!r}")
        require_apart("--plot", plot, {"RESULTS": results, "SEQUENCE": args.sequence})
        require_replaceable("--plot", plot, args.overwrite)


def scored_frames(args: argparse.Namespace, seq, gt_pts, pts):
    """The frames ``--frames`` and ``--annotated-frames`` keep, ``(gt_pts, pts)``; a note on
    stderr for each way the scores would mislead without them, and for head boxes that the
    sequence's seqinfo.ini lets be read as body boxes."""
    import numpy as np

    from crowdsim.checks import note_line

    def note(text: str) -> None:
        print(note_line("evaluate", text), file=sys.stderr)

    n = seq.length
    if args.frames is not None:
        if not 1 <= args.frames <= n:
            raise ValueError(
                f"--frames must be in [1, {n}] (the sequence's frames), got {args.frames}"
            )
        gt_pts, pts, n = gt_pts[: args.frames], pts[: args.frames], args.frames
    tracked = np.flatnonzero(np.isfinite(pts).all(-1).any(1)) if pts.shape[1] else []
    annotated = np.isfinite(gt_pts).all(-1).any(1)
    last = int(tracked[-1]) + 1 if len(tracked) else n
    if args.frames is None and last < n and annotated[last:].any():  # people after the end
        note(
            f"the results end at frame {last} of {n}; the people of frames {last + 1}-{n} count "
            f"as missed (--frames {last} scores the first {last})"
        )
    if not annotated.any():
        raise ValueError(f"{args.sequence}: no ground truth in the {n} frames scored")
    if args.annotated_frames:
        gt_pts, pts = gt_pts[annotated], pts[annotated]
    elif annotated.sum() < n / 2 and np.isfinite(pts[~annotated]).any():  # a few annotated
        note(
            f"ground truth on {int(annotated.sum())} of {n} frames: MOTA, IDF1 and HOTA count "
            "every tracked point of the others as a false positive (--annotated-frames scores "
            "the annotated frames alone)"
        )
    from synth_data.mot import box_type_note

    square = box_type_note(seq)
    if square:
        note(square)
    return gt_pts, pts


def run(args: argparse.Namespace) -> int:
    from crowdsim.atomic import recorded
    from crowdsim.checks import note_line
    from synth_data.mot import verify_frames
    from tracker.metrics import evaluate, format_table, plot_accuracy

    check_args(args)
    seq, gt_ids, gt_pts, ids, pts = load_results(args.results, args.sequence)
    verify_frames(seq)
    if not len(ids):  # a valid result (a tracker that found no one), but never a silent 0
        print(
            note_line("evaluate", f"{args.results} has no result rows; every score is 0"),
            file=sys.stderr,
        )
    gt_pts, pts = scored_frames(args, seq, gt_pts, pts)
    # any result ids: MOTA, IDF1 and HOTA need no correspondence; acc@T uses the ids as they
    # are when they are ground-truth ids (unknown ones unmatched), else a majority mapping
    report = evaluate(
        gt_ids,
        gt_pts,
        ids,
        pts,
        similarity_scale=args.similarity_px,
        id_mapping="auto",
        trackeval=args.metrics == "full",
    )
    name = Path(args.results).stem
    if args.plot:
        with recorded(args.plot):
            plot_accuracy({name: [c["acc"] for c in report["curve"]]}, args.plot, title=seq.name)
    if args.json:
        print(json.dumps({"sequence": seq.name, "results": str(args.results), **report}))
        return 0
    print(f"{seq.name}: {report['gt_points']} ground-truth points of {report['gt_ids']} people")
    print(format_table({name: report}))
    curve = " ".join(f"{c['acc']:.0f}" for c in report["curve"])
    print(f"accuracy (%) for T = 0..25 px: {curve}")
    print(id_mapping_note(report, gt_ids, ids))
    if args.metrics != "full":
        return 0
    print(
        f"CLEAR/IDF1 match within {args.similarity_px / 2:g} px (similarity >= 0.5); "
        f"MOTP {report['motp']:.1f}%, DetA {report['deta']:.1f}%, AssA {report['assa']:.1f}%, "
        f"MT {report['mt']}, ML {report['ml']}, Frag {report['frag']}"
    )
    return 0


def id_mapping_note(report: dict, gt_ids, ids) -> str:
    """One line saying how acc@T related the result ids to the ground truth's."""
    import numpy as np

    if report["id_mapping"] == "majority":
        return (
            "acc@T: the result ids are not the ground truth's; each track stands for the "
            "person it follows in most frames (majority vote)"
        )
    if not len(ids):
        return "acc@T: the results hold no track (no rows), so nothing is matched"
    unknown = np.setdiff1d(np.asarray(ids), np.asarray(gt_ids))
    if not len(unknown):
        return "acc@T: the result ids are the ground truth's"
    return (
        f"acc@T: the result ids are the ground truth's; {len(unknown)} id(s) unknown to it "
        f"(e.g. {', '.join(map(str, unknown[:5].tolist()))}) scored as unmatched"
    )
