"""``crowdsim demo``: the main job on an embedded default (what ``make demo`` runs).

1. simulate the default marathon scene and print its table;
2. generate a short synthetic marathon sequence (MOT layout) from the embedded spec;
3. track it with the BQP tracker (KCF appearance, and the NCC-template alternative) and the
   independent NCC baseline;
4. print the accuracy table (the papers' metric at 5 and 15 px, MOTA, IDF1, HOTA, frames/s);
5. write the accuracy-curve PNG, the overlay MP4 (ground truth green, BQP tracks yellow), the
   MOT result files and ``summary.json`` into the output folder.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

DEMO_SPEC = """\
# crowdsim demo sequence: a short, dense marathon (embedded in crowdsim/commands/demo.py)
name = "marathon_demo"
seed = 7
frames = 100
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

[output]
images = true
video = false
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the embedded default job and print its results",
                       description=__doc__.splitlines()[0].replace("``", ""))
    p.add_argument("--out", type=Path, default=Path("demo_out"), metavar="DIR",
                   help="output folder (default ./demo_out)")
    p.add_argument("--frames", type=int, default=None,
                   help="truncate the demo sequence to N frames (default: the spec's 100)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from crowdsim.cli import main

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rc = main(["simulate", "marathon", "--agents", "300", "--steps", "250", "--seed", "0",
               "--out", str(out / "marathon.npz")])
    if rc:
        return rc

    # --- synthetic benchmark sequence ---------------------------------------------------
    spec = out / "marathon_demo.toml"
    spec.write_text(DEMO_SPEC)
    gen = ["generate", "--spec", str(spec), "--out", str(out / "sequences"), "--workers", "1",
           "--overwrite"]
    if args.frames is not None:
        if args.frames < 2:
            raise ValueError(f"--frames must be >= 2, got {args.frames}")
        gen += ["--frames", str(args.frames)]
    if args.no_progress:
        gen.append("--no-progress")
    print("\ngenerating the demo sequence ...", flush=True)
    rc = main(gen)
    if rc:
        return rc
    return _track_and_report(out, out / "sequences" / "marathon_demo", not args.no_progress,
                             t_start)


def _track_and_report(out: Path, seq_dir: Path, progress: bool, t_start: float) -> int:
    import time

    import numpy as np

    from synth_data.mot import read_sequence, write_mot
    from tracker.baselines.ncc import NCCTracker
    from tracker.bqp.params import BQPParams
    from tracker.bqp.tracker import BQPTracker
    from tracker.metrics import evaluate, plot_accuracy
    from tracker.mot_io import births_from_ground_truth, tracks_to_mot_rows
    from tracker.overlay import write_overlay

    seq = read_sequence(seq_dir)
    gt_ids, gt_pts = seq.gt_points()
    (ids, pts), births = births_from_ground_truth(gt_ids, gt_pts)
    frames = list(seq.frames())
    size = seq.template_size
    print(f"\ntracking {seq.name}: {len(frames)} frames {seq.width}x{seq.height}, "
          f"{len(gt_ids)} people, template {size} px", flush=True)
    reports: dict[str, dict] = {}
    tracks: dict[str, np.ndarray] = {}
    trackers = (("BQP", BQPTracker()),
                ("BQP-NCC", BQPTracker(BQPParams(appearance="ncc"))),
                ("NCC", NCCTracker()))
    for name, tracker in trackers:
        res = tracker.track(frames, ids, pts, size, births=births, n_frames=len(frames),
                            progress=progress)
        write_mot(out / f"results_{name.lower().replace('-', '_')}.txt",
                  tracks_to_mot_rows(res.ids, res.positions, size))
        rep = evaluate(gt_ids, gt_pts, res.ids, res.positions, strict=True)
        steps = max(res.n_frames - 1, 1)
        rep["fps"] = steps / max(res.timings.get("total", 0.0), 1e-9)
        rep["stage_ms"] = {k: 1000.0 * v / steps for k, v in res.timings.items()
                           if k != "total"}
        reports[name] = rep
        tracks[name] = res.positions

    head = (f"{'method':<9}{'acc@5':>8}{'acc@15':>8}{'MOTA':>8}{'IDF1':>8}{'HOTA':>8}"
            f"{'IDSW':>6}{'fps':>8}")
    print("\n" + head)
    print("-" * len(head))
    for name, r in reports.items():
        print(f"{name:<9}{r['acc@5']:>7.1f}%{r['acc@15']:>7.1f}%{r['mota']:>7.1f}%"
              f"{r['idf1']:>7.1f}%{r['hota']:>7.1f}%{r['idsw']:>6d}{r['fps']:>8.1f}")
    stages = ", ".join(f"{k} {v:.1f} ms" for k, v in reports["BQP"]["stage_ms"].items())
    print(f"BQP per frame: {stages}")

    curve_png = out / "accuracy_curve.png"
    plot_accuracy({n: [c["acc"] for c in r["curve"]] for n, r in reports.items()}, curve_png,
                  title=f"{seq.name}: tracking accuracy vs pixel threshold")
    overlay = out / "overlay_bqp.mp4"
    write_overlay(overlay, frames, size, tracks=tracks["BQP"], ground_truth=gt_pts,
                  fps=seq.frame_rate)
    summary = {"sequence": str(seq_dir), "frames": len(frames), "people": int(len(gt_ids)),
               "template_px": int(size),
               "results": {n: {k: v for k, v in r.items()} for n, r in reports.items()},
               "files": {"accuracy_curve": str(curve_png), "overlay": str(overlay)}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"\naccuracy curve -> {curve_png}\noverlay video  -> {overlay} "
          f"(ground truth green, BQP tracks yellow)\nresults        -> "
          f"{out / 'results_bqp.txt'}, {out / 'results_ncc.txt'}, {out / 'summary.json'}")
    print(f"demo finished in {time.perf_counter() - t_start:.0f} s")
    return 0
