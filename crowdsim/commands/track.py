"""``crowdsim track INPUT``: track people through a sequence and write MOT results.

INPUT is a MOTChallenge sequence folder (targets start from its ground truth: the initial
targets at frame 1, every later id born at its first frame) or a video file (targets come from
``--init points.csv`` with rows ``frame,id,x,y`` in pixels, rows after frame 1 being births;
without ``--init`` the head detector of :mod:`tracker.detect` finds everyone in frame 1).
``--init detect`` starts from the detector on a folder too (ids of heads matched within 5 px
to a ground-truth person at frame 1 take that person's id, so ``--evaluate`` scores them), and
``--births detect`` runs the detector every ``--detect-every`` frames and starts a track for
every head no track covers.
Any registered tracker runs (``--tracker``, see :mod:`tracker.registry`); ``--set`` changes
its parameters. Results are MOT text rows, one head box of the template size centred on each
tracked point. Tracking goes through :func:`tracker.runner.run_tracker`, and ``--evaluate``
scores with :func:`tracker.runner.score` once the tracks are written.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

TRACKER_LIST = "<the registered trackers>"
"""Stands in ``--tracker``'s help for :func:`tracker.registry.listing`, filled in only when
the help is printed: listing the installed plug-ins reads every installed distribution's
entry points (about 50 ms), which no other command, and no run of this one, should pay."""


class _ListingFormatter(argparse.HelpFormatter):
    def _get_help_string(self, action: argparse.Action) -> str:
        text = super()._get_help_string(action) or ""
        if TRACKER_LIST in text:
            from tracker.registry import listing

            text = text.replace(TRACKER_LIST, listing().replace("%", "%%"))
        return text


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.atomic import OVERWRITE_HELP
    from tracker.base import MAX_TEMPLATE_PX

    p = sub.add_parser(
        "track",
        help="track a sequence or video with any registered tracker, write MOT results",
        description=__doc__.splitlines()[0].replace("``", ""),
        formatter_class=_ListingFormatter,
    )
    p.add_argument("input", help="MOT sequence folder or video file")
    p.add_argument(
        "--tracker",
        default=None,
        metavar="NAME",
        help="registered tracker (default bqp; with --params or --policy: the tracker the file "
        f"names). {TRACKER_LIST}",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="tracker parameter, e.g. --set zeta=0.5 (repeatable)",
    )
    p.add_argument("--out", required=True, help="MOT results file to write")
    p.add_argument(
        "--init",
        metavar="CSV|detect",
        help="points CSV (frame,id,x,y or id,x,y), or 'detect': the head detector finds the "
        "people in frame 1 (the default for a video)",
    )
    p.add_argument(
        "--births",
        choices=("source", "detect"),
        default="source",
        help="later arrivals: 'source' (the ground truth, or the CSV's later rows; default) or "
        "'detect' (the head detector every --detect-every frames starts a track for every head "
        "no track covers; scheduled births are kept)",
    )
    p.add_argument(
        "--detect-every",
        type=int,
        default=10,
        metavar="N",
        help="frames between detections with --births detect (10)",
    )
    p.add_argument(
        "--detections",
        choices=("simulated", "detector"),
        default=None,
        help="what feeds a tracking-by-detection tracker (bytetrack, ocsort): detections "
        "simulated from the ground truth (default for a folder) or the head detector run on "
        "the frames (default for a video)",
    )
    p.add_argument(
        "--detector-weights", metavar="FILE", default=None, help="head detector weights (shipped)"
    )
    p.add_argument(
        "--detector-threshold",
        type=float,
        default=None,
        metavar="T",
        help="head detector threshold in (0, 1) (default: the detector's)",
    )
    p.add_argument(
        "--video",
        metavar="OVERLAY.mp4",
        help="also write an overlay MP4 of the frames tracked: ground truth green (a MOT "
        "folder's), tracks yellow, the frame number and legend at the top left",
    )
    p.add_argument(
        "--video-ids",
        action="store_true",
        help="with --video: draw each track's id (the --out file's) beside its box",
    )
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument(
        "--evaluate",
        action="store_true",
        help="print the accuracy table against the sequence's ground truth",
    )
    p.add_argument(
        "--template-size",
        type=int,
        default=None,
        help=f"template (head) size in px, 2..{MAX_TEMPLATE_PX} (default: seqinfo.ini's "
        "templateSize, else the median ground-truth box width, else 12)",
    )
    p.add_argument("--frames", type=int, default=None, help="track only the first N frames")
    p.add_argument(
        "--appearance",
        choices=("kcf", "ncc"),
        default=None,
        help="appearance model of a BQP tracker (same as --set appearance=...)",
    )
    p.add_argument(
        "--dense",
        action="store_true",
        help="BQP with dense candidates instead of the default speed-up sampling "
        "(same as --tracker bqp-dense)",
    )
    tuned = p.add_mutually_exclusive_group()
    tuned.add_argument(
        "--params",
        metavar="JSON",
        help="a tracker with tuned static parameters (best_params.json of crowdsim tune)",
    )
    tuned.add_argument(
        "--policy",
        metavar="ZIP",
        help="a tracker driven by an adaptive policy (model.zip of crowdsim train) or a "
        "scene-aware one (scene_aware.json of crowdsim train --algo scene)",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        metavar="N",
        help="threads of the tracker's parallel stages, 1..cores (default: all cores); the "
        "tracks are the same for any N",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _check_output(
    path: str, flag: str, overwrite: bool, inputs: dict, suffix: str | None = None
) -> Path:
    """Refuse, before any work is done, an output path that cannot be written (a folder,
    under a regular file, in a folder that is not writable), one of the ``inputs`` or inside
    one, and a file there that crowdsim cannot prove it wrote, unless ``overwrite``
    (:func:`crowdsim.atomic.require_replaceable`)."""
    from crowdsim.atomic import require_replaceable
    from crowdsim.checks import require_apart

    if suffix and Path(path).suffix.lower() != suffix:
        raise ValueError(f"{flag} must end in {suffix}, got {path!r}")
    require_apart(flag, path, inputs)
    return require_replaceable(flag, path, overwrite)


def _overrides(args: argparse.Namespace, name: str) -> dict:
    """``--set``, ``--appearance`` and ``--dense`` as parameter values of tracker ``name``,
    checked: unknown or out-of-range values and flags that contradict each other are named."""
    from crowdsim.commands.simulate import parse_assignments
    from tracker.registry import entries, get

    entry = get(name)  # unknown names list the valid ones
    over = parse_assignments(args.set, "--set")
    own = entry.field_names()
    for flag, field, given in (
        ("--appearance", "appearance", args.appearance is not None),
        ("--dense", "speedup", args.dense),
    ):
        if given and field not in own:
            having = [n for n, e in entries().items() if field in e.field_names()]
            raise ValueError(
                f"{flag} sets a parameter that --tracker {name} does not have (trackers "
                f"with it: {', '.join(having)})"
            )
    if args.appearance is not None:
        if "appearance" in over and over["appearance"] != args.appearance:
            raise ValueError(
                f"--appearance {args.appearance} contradicts --set appearance={over['appearance']}"
            )
        over["appearance"] = args.appearance
    if args.dense:
        if "speedup" in over and over["speedup"] is not False:
            raise ValueError(
                f"--dense (no speed-up sampling) contradicts --set speedup={over['speedup']}"
            )
        over["speedup"] = False
    entry.make_params(**over)  # unknown or out-of-range parameters fail here, named
    return over


def _file_tracker(args: argparse.Namespace) -> tuple[str, object]:
    """``(tracker name, params or None)`` of ``--params`` / ``--policy``. The file names its
    tracker; ``--tracker``, when given, must be the same one (a parameters file of ``ncc``
    never silently turns ``--tracker bqp`` into NCC)."""
    from envs.param_space import load_params
    from envs.training import policy_meta

    params = None
    if args.params:
        flag, path = "--params", args.params
        name, params = load_params(path)
    else:
        flag, path = "--policy", args.policy
        name = policy_meta(path)["env_kwargs"].get("tracker", "bqp")
    if args.tracker is not None and args.tracker != name:
        raise ValueError(
            f"{flag} {path}: made for the {name!r} tracker, but --tracker is "
            f"{args.tracker!r} (drop --tracker to follow the file, or give --tracker {name})"
        )
    return name, params


def _tuned(
    args: argparse.Namespace, src: object, name: str, params: object
) -> tuple[object, object, str]:
    """``(tracker, frame source, description)`` for ``--params`` / ``--policy``, whose
    tracker ``name`` and ``params`` :func:`_file_tracker` read."""
    from dataclasses import replace

    from envs.training import load_policy, policy_description, policy_tracker
    from tracker.registry import make_tracker

    path = args.params or args.policy
    over = _overrides(args, name)
    followed = "" if args.tracker is not None else " (the tracker the file names)"
    if args.params:
        tracker = make_tracker(name, replace(params, **over) if over else params)
        return tracker, src, f"{name}{followed} with the parameters of {path}"
    model, meta = load_policy(path)
    tracker, feed, _ = policy_tracker(src, model, meta, over)
    what = f"{policy_description(meta)} of {path}"
    return tracker, feed, f"{name}{followed} with {what}"


def _detector(args: argparse.Namespace) -> object:
    """The head detector of ``--detector-weights`` / ``--detector-threshold``."""
    from crowdsim.commands.detect import detector_params
    from tracker.detect import HeadDetector

    params = detector_params(args.detector_weights, args.detector_threshold, "--detector-threshold")
    return HeadDetector(params, template_size=args.template_size or 12)


def _feed(tracker: object, source: object, detector: object = None) -> None:
    """Give a tracking-by-detection tracker its detections: the head detector's, or ones
    simulated from the source's ground truth."""
    from synth_data.detections import attach_detections

    if detector is None:
        attach_detections(tracker, source)
    elif hasattr(tracker, "use_detections"):
        tracker.use_detections(detector)


def _detected_start(
    args: argparse.Namespace, src: object, detector: object, use_detector: bool
) -> tuple[object, object]:
    """``(start, births)`` for :func:`tracker.runner.run_tracker`: the heads the detector finds
    in frame 1 (``--init detect``) and the births it finds later (``--births detect``), at
    the head size the detector was given (:func:`crowdsim.commands.detect.head_size`), never
    the tracker's template: a body-box folder's template is a body width, which shrank the
    frame 3-4 times over (30 heads found for 66 people) and kept births 40 px apart."""
    import numpy as np

    from synth_data.births import DetectionBirths, births_from_detections

    if detector is None:
        return None, None
    if not (use_detector or args.births == "detect"):
        return None, None
    gt_ids, gt_pts = src.gt_points()
    if use_detector:
        first = next(iter(src.frames()), None)
        if first is None:
            raise ValueError(f"{args.input}: the video has no frames")
        found, _ = detector.detect_points(first)
        if not len(found):
            raise ValueError(
                f"{args.input}: the head detector found nobody in frame 1 (threshold "
                f"{detector.params.threshold:g}); lower --detector-threshold or give --init"
            )
        if len(gt_ids):
            from crowdsim.lab.detector import relabel_to_truth

            ids0, matched = relabel_to_truth(found, gt_ids, gt_pts[0])
            start = ((ids0, found), {})
            print(
                f"head detector: {len(found)} heads in frame 1, {len(matched)} of "
                f"{int(np.isfinite(gt_pts[0]).all(1).sum())} people matched within 5 px",
                file=sys.stderr,
            )
        else:
            start = births_from_detections(found)
            print(f"head detector: {len(found)} heads in frame 1", file=sys.stderr)
    else:
        start = src.births()
    if args.births != "detect":
        return start, None
    (ids0, _), scheduled = start
    known = [ids0, gt_ids] + [b[0] for b in scheduled.values()]
    top = max((int(np.max(k)) for k in known if len(k)), default=0)
    births = DetectionBirths(
        detector.detect_points,
        every=args.detect_every,
        radius=float(detector.template_size),
        first_id=top + 1,
        scheduled=scheduled,
    )
    return start, births


def run(args: argparse.Namespace) -> int:
    from functools import partial

    from crowdsim.atomic import atomic_path, recorded
    from crowdsim.checks import note_line
    from envs.episodes import verify_folder
    from synth_data.mot import box_type_note, write_mot
    from synth_data.sequence import open_sequence
    from tracker.base import MAX_TEMPLATE_PX
    from tracker.metrics import format_table
    from tracker.mot_io import tracks_to_mot_rows
    from tracker.registry import make_tracker
    from tracker.runner import run_tracker, score
    from tracker.threads import check_threads

    if args.threads is not None:
        check_threads(args.threads, "--threads")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    size = args.template_size
    if size is not None and not 2 <= size <= MAX_TEMPLATE_PX:
        raise ValueError(f"--template-size must be in [2, {MAX_TEMPLATE_PX}] px, got {size}")
    is_folder = Path(args.input).is_dir()
    if args.evaluate and not is_folder:
        raise ValueError("--evaluate needs a sequence folder with ground truth as INPUT")
    if args.video_ids and not args.video:
        raise ValueError("--video-ids needs --video OVERLAY.mp4")
    inputs = {
        "INPUT": args.input,
        "--init": args.init if args.init != "detect" else None,
        "--params": args.params,
        "--policy": args.policy,
        "--detector-weights": args.detector_weights,
    }
    out = _check_output(args.out, "--out", args.overwrite, inputs)
    if args.video:
        _check_output(args.video, "--video", args.overwrite, {**inputs, "--out": out}, ".mp4")
    if not (args.params or args.policy):
        over = _overrides(args, args.tracker or "bqp")
    use_detector = args.init == "detect" or (args.init is None and not is_folder)
    if args.detect_every < 1:
        raise ValueError(f"--detect-every must be >= 1, got {args.detect_every}")
    feed_detector = args.detections == "detector" or (args.detections is None and not is_folder)
    uses_detector = use_detector or args.births == "detect" or feed_detector
    given = {
        "--detector-weights": args.detector_weights,
        "--detector-threshold": args.detector_threshold,
    }
    unused = [flag for flag, value in given.items() if value is not None]
    if not uses_detector and unused:  # checked even when unused, and said so
        from crowdsim.commands.detect import detector_params

        detector_params(None, args.detector_threshold, "--detector-threshold")
        weights = args.detector_weights
        if weights is not None and not Path(weights).is_file():
            raise ValueError(f"--detector-weights {weights}: no such file")
        print(
            f"note: {' and '.join(unused)} unused: no head detector runs here (it runs with "
            "--init detect, --births detect, --detections detector, or a video as INPUT)",
            file=sys.stderr,
        )
    # the file's tracker, read once: one of another tracker is refused before any detection
    tuned = _file_tracker(args) if args.params or args.policy else None
    detector = _detector(args) if uses_detector else None
    src = open_sequence(args.input, init=None if use_detector else args.init)
    if is_folder:
        verify_folder(src)  # a damaged, truncated or swapped image is named, not tracked
        if args.evaluate and not len(src.gt_points()[0]):
            raise ValueError(f"--evaluate: {args.input} has no ground truth (gt/gt.txt) to score")
        square = box_type_note(src)
        if square:
            print(note_line("track", square), file=sys.stderr)
    size = int(size or src.template_size)
    if detector is not None:  # heads beyond the sizes it learnt are found on a shrunk frame
        from crowdsim.commands.detect import head_size

        detector.template_size = head_size(src, args.template_size)
    start, births = _detected_start(args, src, detector, use_detector)
    if tuned is not None:
        tracker, feed, what = _tuned(args, src, *tuned)
        print(f"tracking with {what}", file=sys.stderr)
    else:
        tracker, feed = make_tracker(args.tracker or "bqp", **over), src
    tracker.threads = args.threads
    run = run_tracker(
        tracker,
        feed,
        frames=args.frames,
        template_size=size,
        metrics="none",  # scored once the tracks are written: a refused score loses nothing
        progress=not args.no_progress,
        prepare=partial(_feed, detector=detector if feed_detector else None),
        start=start,
        births=births,
    )
    result = run.result
    if births is not None:
        print(f"head detector: {births.born} people born while tracking", file=sys.stderr)
    # the results are renamed into place once the video is written too: a video that fails
    # (a full disk) leaves neither, and the run ends with its one line
    with recorded(out, *([args.video] if args.video else [])), atomic_path(out) as tmp:
        write_mot(tmp, tracks_to_mot_rows(result.ids, result.positions, size))
        if args.video:
            from tracker.overlay import write_overlay

            gt_pts = src.gt_points()[1] if is_folder else None
            write_overlay(
                args.video,
                itertools.islice(src.frames(), result.n_frames),
                size,
                tracks=result.positions,
                ground_truth=gt_pts,
                fps=getattr(src, "frame_rate", 25.0),
                track_ids=result.ids if args.video_ids else None,
            )
    stages = ", ".join(f"{k} {v:.1f} ms" for k, v in run.stage_ms.items())
    speed = f"{run.fps:.1f} frames/s" + (f" ({stages} per frame)" if stages else "")
    if result.n_frames <= 1:
        speed = "no frame stepped"
    print(
        f"{run.tracker}: {result.n_frames} frames, {len(result.ids)} targets, {speed} -> {out}",
        file=sys.stderr,
    )
    if args.video:
        print(f"overlay -> {args.video}", file=sys.stderr)
    if args.evaluate:
        try:
            mapping = getattr(tracker, "id_mapping", "same")
            if args.init is not None or args.births == "detect":
                # ids from a detector or a points CSV are not the ground truth's, whatever
                # their numbers: the evidence decides, as crowdsim evaluate does
                mapping = "auto"
            run.report = score(result, feed, "full", id_mapping=mapping)
        except ValueError as exc:
            raise ValueError(f"{exc} (the tracks are written to {out})") from None
        print(format_table({run.tracker: run.report}))
        print(json.dumps(run.summary()))
    return 0
