"""``crowdsim demo``: the main job on an embedded default (what ``make demo`` runs).

1. simulate the default marathon scene and print its table;
2. generate a short, hard synthetic marathon sequence (MOT layout) from the embedded spec:
   look-alike dark heads, packed bodies, gait and head turns, clutter, noise and H.264;
3. track it with every point tracker of the papers -- BQP (KCF appearance and NCC
   appearance), PNMC, the independent NCC and mean-shift baselines -- and with ByteTrack on
   simulated head detections, all through :func:`tracker.runner.run_tracker`;
4. print the accuracy table (the papers' metric at 5 and 15 px, MOTA, IDF1, HOTA, frames/s);
5. write the accuracy-curve PNG, the overlay MP4 (ground truth green, BQP tracks yellow), the
   MOT result files and ``summary.json`` into the output folder (every file atomically; the
   record ``demo.json`` lists their digests, and a rerun into the folder replaces only files
   an earlier demo wrote: any other file of those names is refused before any work).

Every step calls library functions; nothing re-enters the command line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from crowdsim.checks import path_arg

DEMO_FRAMES = 100
"""Frames of the demo sequence (``frames`` of :data:`DEMO_SPEC`)."""

DEMO_SPEC = f"""\
# crowdsim demo sequence: a short, dense marathon (embedded in crowdsim/commands/demo.py)
name = "marathon_demo"
seed = 7
frames = {DEMO_FRAMES}
fps = 25.0
warmup_steps = 50
description = "crowdsim demo: dense marathon runners on a course with a bend"

[scenario]
name = "marathon"
n_agents = 200
density = 2.5

[camera]
max_width = 960
max_height = 540

[appearance]
template_px = 12
palette = "dark"
n_clusters = 3
contrast = 0.45
motion_blur_px = 1.5
noise_sigma = 8.0
dark_hair_fraction = 0.9   # look-alike heads from above
body_scale = 1.3           # packed bodies: little ground between runners
arm_swing = 0.2            # the template learnt at frame 1 drifts ...
gait_bob = 0.1
head_turn_deg = 30.0       # ... with gait, arms and head turns
distractor_density = 0.2   # static head-like clutter
video_kbps = 1500.0        # H.264 at a CCTV bit rate

[output]
images = true
video = false
"""


DEMO_TRACKERS: tuple[tuple[str, str], ...] = (
    ("BQP", "bqp"),
    ("BQP-NCC", "bqp-ncc"),
    ("PNMC", "pnmc"),
    ("NCC", "ncc"),
    ("mean-shift", "meanshift"),
    ("ByteTrack", "bytetrack"),
)
"""Table label -> registered tracker name, in the order the table lists them."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the embedded default job and print its results",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument(
        "--out",
        type=path_arg,
        default=Path("demo_out"),
        metavar="DIR",
        help="output folder (default ./demo_out): accuracy_curve.png, overlay_bqp.mp4 (ground "
        "truth green, BQP tracks yellow), results_<tracker>.txt, marathon.npz, summary.json, "
        "demo.json (their digests) and the sequence in sequences/",
    )
    p.add_argument(
        "--frames",
        type=int,
        default=None,
        help=f"track the demo sequence's first N frames, 2..{DEMO_FRAMES} (default: all)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


RECORD = "demo.json"
"""The demo's record in its output folder: the digests of the files it wrote
(:mod:`envs.outputs`), so that a rerun replaces those and refuses to replace anything else."""


def _results_name(tracker: str) -> str:
    return f"results_{tracker.replace('-', '_')}.txt"


def demo_files() -> list[str]:
    """The files the demo writes into its output folder (besides ``sequences/``)."""
    results = [_results_name(name) for _, name in DEMO_TRACKERS]
    return ["marathon.npz", *results, "accuracy_curve.png", "overlay_bqp.mp4", "summary.json"]


def _ours(doc: dict) -> bool:
    return doc.get("written_by") == "crowdsim demo"


def _earlier_summary(out: Path) -> bool:
    """``out`` holds a ``summary.json`` as demos before :data:`RECORD` wrote it (it then
    vouches for the files beside it)."""
    try:
        doc = json.loads((out / "summary.json").read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    keys = {"sequence", "frames", "people", "template_px", "results", "files"}
    return isinstance(doc, dict) and set(doc) == keys


def run(args: argparse.Namespace) -> int:
    import time

    from crowdsim.commands.simulate import summary_table
    from crowdsim.scenarios import make_scenario
    from crowdsim.simulation import Simulation
    from envs.outputs import check_outputs
    from synth_data.generate import generate, read_manifest_of
    from synth_data.spec import parse_spec_text, spec_from_dict

    if args.frames is not None and not 2 <= args.frames <= DEMO_FRAMES:
        raise ValueError(
            f"--frames must be in [2, {DEMO_FRAMES}] (the demo sequence's length), "
            f"got {args.frames}"
        )
    out: Path = args.out
    # before any work: a folder that cannot be made or written, and a file of one of the
    # demo's names that an earlier demo did not write, are refused
    check_outputs(out, RECORD, demo_files(), _ours, "crowdsim demo", earlier=_earlier_summary)
    read_manifest_of(out / "sequences")  # and a manifest.json there that is not crowdsim's
    out.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    t_start = time.perf_counter()

    # --- 1. a crowd ------------------------------------------------------------------------
    sim = Simulation(make_scenario("marathon", n_agents=300), seed=0)
    t0 = time.perf_counter()
    traj = sim.run(250, progress=progress)
    wall = time.perf_counter() - t0
    print(summary_table(sim, traj, 250, wall, out / "marathon.npz"), flush=True)

    # --- 2. a synthetic benchmark sequence -------------------------------------------------
    spec = spec_from_dict(parse_spec_text(DEMO_SPEC, "toml", "demo spec"), "demo spec")
    spec = spec.truncated(args.frames)
    print("\ngenerating the demo sequence ...", flush=True)
    generate(
        [spec],
        out / "sequences",
        overwrite=True,
        progress=progress,
        log=lambda msg: print(msg, flush=True),
    )
    return _track_and_report(out, out / "sequences" / spec.name, progress, t_start, traj)


def _track_and_report(out: Path, seq_dir: Path, progress: bool, t_start: float, traj) -> int:
    import time

    from envs.outputs import write_outputs
    from synth_data.detections import attach_detections
    from synth_data.mot import write_mot
    from synth_data.sequence import InMemorySequence, open_sequence
    from tracker.metrics import plot_accuracy
    from tracker.mot_io import tracks_to_mot_rows
    from tracker.overlay import write_overlay
    from tracker.runner import run_tracker

    seq = InMemorySequence.from_source(open_sequence(seq_dir))  # decode the JPEGs once
    gt_ids, gt_pts = seq.gt_points()
    size = seq.template_size
    print(
        f"\ntracking {seq.name}: {seq.length} frames {seq.width}x{seq.height}, "
        f"{len(gt_ids)} people, template {size} px",
        flush=True,
    )
    runs = {}
    files = {}
    writers = {"marathon.npz": traj.save}
    for label, name in DEMO_TRACKERS:
        run = run_tracker(name, seq, progress=progress, prepare=attach_detections)
        rows = tracks_to_mot_rows(run.result.ids, run.result.positions, size)
        writers[_results_name(name)] = lambda p, rows=rows: write_mot(p, rows)
        runs[label], files[label] = run, str(out / _results_name(name))

    head = (
        f"{'method':<11}{'acc@5':>8}{'acc@15':>8}{'MOTA':>8}{'IDF1':>8}{'HOTA':>8}"
        f"{'IDSW':>6}{'fps':>8}"
    )
    print("\n" + head)
    print("-" * len(head))
    for label, run in runs.items():
        r = run.report
        print(
            f"{label:<11}{r['acc@5']:>7.1f}%{r['acc@15']:>7.1f}%{r['mota']:>7.1f}%"
            f"{r['idf1']:>7.1f}%{r['hota']:>7.1f}%{r['idsw']:>6d}{run.fps:>8.1f}"
        )
    stages = ", ".join(f"{k} {v:.1f} ms" for k, v in runs["BQP"].stage_ms.items())
    print(f"BQP per frame: {stages}")
    print(
        "ByteTrack runs on simulated head detections (miss rate 0.1) and names its own "
        "tracks; acc@T maps each track to the person it follows in most frames."
    )

    curve_png = out / "accuracy_curve.png"
    writers["accuracy_curve.png"] = lambda p: plot_accuracy(
        {n: [c["acc"] for c in r.report["curve"]] for n, r in runs.items()},
        p,
        title=f"{seq.name}: tracking accuracy vs pixel threshold",
    )
    overlay = out / "overlay_bqp.mp4"
    writers["overlay_bqp.mp4"] = lambda p: write_overlay(
        p,
        seq.frames(),
        size,
        tracks=runs["BQP"].result.positions,
        ground_truth=gt_pts,
        fps=seq.frame_rate,
    )
    summary = {
        "sequence": str(seq_dir),
        "frames": seq.length,
        "people": int(len(gt_ids)),
        "template_px": int(size),
        "results": {n: {**r.report, "fps": r.fps, "stage_ms": r.stage_ms} for n, r in runs.items()},
        "files": {"accuracy_curve": str(curve_png), "overlay": str(overlay), "results": files},
    }
    writers["summary.json"] = lambda p: p.write_text(json.dumps(summary, indent=1))
    # every file renders to a temporary one first; the record lists them all before any is
    # renamed into place (envs.outputs), so a rerun can prove which files the demo wrote
    write_outputs(out, RECORD, {"written_by": "crowdsim demo"}, writers)
    print(
        f"\naccuracy curve -> {curve_png}\noverlay video  -> {overlay} "
        f"(ground truth green, BQP tracks yellow)\nresults        -> "
        f"{out}/results_*.txt, {out / 'summary.json'}"
    )
    print(f"demo finished in {time.perf_counter() - t_start:.0f} s")
    return 0
