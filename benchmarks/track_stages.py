"""Tracker per-stage milliseconds on fixed frames, for comparing two versions of the code.

Runs the BQP tracker (speed-up sampling; ``--tracker pnmc``: PNMC; ``meanshift`` or ``ncc``:
the baselines) on the ``crowdsim bench track`` crowds of ``--targets`` people (spread over
1280x720 and packed at 2.5 people/m^2, 30 frames) and, with ``--sequence DIR``, on the first
``--frames`` frames of a MOT sequence (e.g. the stress suite's 10k sequence); best of
``--repeats`` runs. It only uses interfaces that older versions have too, so the same frames
can be timed before and after a change::

    git archive 4860528 | tar -x -C /tmp/before
    (cd /tmp && PYTHONPATH=/tmp/before python /path/to/benchmarks/track_stages.py --threads 1)
    python benchmarks/track_stages.py --threads 1
    python benchmarks/track_stages.py --threads 2
    python benchmarks/track_stages.py --threads 2 --fw-variant block

``--threads`` sets numba's threads (the code before threads existed used one). Prints a
table and one JSON object; ``tracks_sha1`` identifies the tracks (equal across thread counts)
and, for BQP, ``fw_steps`` is the solver's mean block steps a frame.
PNMC before and after its compiled propagation: ``--tracker pnmc`` with commit a0f25ad as
"before" (``--repeats 2 --sequence stress-10k``; figures in ``docs/tracker-speed.md``). The
mean-shift baseline before and after its compiled search: ``--tracker meanshift --threads 2``
with commit b88d583 as "before".
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path

# as the ``crowdsim`` command sets them (crowdsim/cli.py): numba's OpenMP threads sleep
# between parallel regions instead of spinning on the cores the FFT workers need, and malloc
# keeps the large per-frame blocks instead of having them zeroed and mapped in again. Code
# from before process_settings gets the OpenMP setting only; to time it under the same
# malloc, set MALLOC_MMAP_THRESHOLD_=134217728 MALLOC_TRIM_THRESHOLD_=268435456 for both runs.
try:
    from crowdsim.cli import process_settings
except ImportError:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
else:
    process_settings()

import sys

import numba  # noqa: E402

STAGES = {
    "bqp": ("appearance", "terms", "solve"),
    "pnmc": ("queens", "appearance", "update"),
    "meanshift": ("appearance",),
    "ncc": ("appearance",),
}
"""The stages each tracker times (``Tracker._tick``), in the order of a frame."""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=1, help="numba threads (default: 1)")
    ap.add_argument(
        "--targets", type=int, default=1000, help="people in each bench crowd (default: 1000)"
    )
    ap.add_argument(
        "--repeats", type=int, default=3, help="runs of each case; the fastest counts (default: 3)"
    )
    ap.add_argument("--sequence", default=None, metavar="DIR", help="also time this MOT sequence")
    ap.add_argument(
        "--frames", type=int, default=9, help="frames of --sequence to track (default: 9)"
    )
    ap.add_argument(
        "--fw-variant",
        default=None,
        metavar="NAME",
        help="BQP's Frank-Wolfe variant (fw_variant, e.g. block; default: the tracker's own)",
    )
    ap.add_argument(
        "--tracker",
        choices=sorted(STAGES),
        default="bqp",
        help="bqp (appearance / terms / solve), pnmc (queens / appearance / update), or the "
        "meanshift or ncc baseline (appearance)",
    )
    args = ap.parse_args()
    stages = STAGES[args.tracker]
    over = {}
    if args.fw_variant is not None:
        from tracker.bqp.params import BQPParams

        if args.tracker != "bqp":
            ap.error("--fw-variant is BQP's")
        try:
            BQPParams(fw_variant=args.fw_variant)
        except ValueError as exc:  # older versions know fewer variants
            ap.error(f"--fw-variant: {exc}")
        over["fw_variant"] = args.fw_variant
    if not 1 <= args.threads <= numba.config.NUMBA_NUM_THREADS:
        ap.error(f"--threads must be in [1, {numba.config.NUMBA_NUM_THREADS}], got {args.threads}")
    if not 1 <= args.targets <= 100_000:
        ap.error(f"--targets must be in [1, 100000], got {args.targets}")
    if not 1 <= args.repeats <= 1000:
        ap.error(f"--repeats must be in [1, 1000], got {args.repeats}")
    if args.frames is not None and args.frames < 2:
        ap.error(f"--frames must be >= 2, got {args.frames}")
    if args.sequence and not Path(args.sequence).exists():
        ap.error(f"--sequence {args.sequence}: no such sequence folder or video file")
    numba.set_num_threads(args.threads)

    from crowdsim.bench.track import packed_size
    from crowdsim.render import default_px_per_m
    from synth_data.sequence import open_sequence, synthetic_crowd
    from tracker.registry import make_tracker
    from tracker.runner import run_tracker

    warm = synthetic_crowd(4, 3, 0, 12, size=(160, 120))
    run_tracker(make_tracker(args.tracker), warm, metrics="none")
    cases = {}
    for packed in (False, True):
        size = packed_size(args.targets, default_px_per_m(12)) if packed else (1280, 720)
        crowd = synthetic_crowd(
            args.targets,
            30,
            0,
            12,
            size=size,
            contrast=0.3 if packed else 1.0,
            noise_sigma=8.0 if packed else 3.0,
        )
        cases[f"{args.targets} {'packed' if packed else 'spread'} {size[0]}x{size[1]}"] = (
            crowd,
            None,
            "accuracy",
        )
    if args.sequence:
        cases[args.sequence] = (open_sequence(args.sequence), args.frames, "none")
    rows = {}
    for name, (src, frames, metrics) in cases.items():
        best = None
        for _ in range(args.repeats):
            trk = make_tracker(args.tracker, **over)
            r = run_tracker(trk, src, frames=frames, metrics=metrics)
            row = {"fps": r.fps, **{k: r.stage_ms.get(k, 0.0) for k in stages}}
            if hasattr(trk, "solver_iterations"):  # BQP: Frank-Wolfe block steps a frame
                row["fw_steps"] = trk.solver_iterations / max(r.result.positions.shape[0] - 1, 1)
            if metrics == "accuracy":
                row["acc@15"] = r.report["acc@15"]
            row["tracks_sha1"] = hashlib.sha1(r.result.positions.tobytes()).hexdigest()[:12]
            if best is None or row["fps"] > best["fps"]:
                best = row
        rows[name] = best
    heads = "".join(f"{k[:10]:>11}" for k in stages)
    steps = any("fw_steps" in r for r in rows.values())
    heads += f"{'FW steps':>10}" if steps else ""
    print(f"{'case':<44}{'fps':>7}{heads}  tracks (stages in ms a frame)")
    for name, r in rows.items():
        cells = "".join(f"{r[k]:>11.1f}" for k in stages)
        cells += f"{r.get('fw_steps', 0.0):>10.0f}" if steps else ""
        print(f"{name[-44:]:<44}{r['fps']:>7.2f}{cells}  {r['tracks_sha1']}")
    report = {"benchmark": "track_stages", "tracker": args.tracker, "threads": args.threads}
    print(json.dumps({**report, "cases": rows}))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("track_stages.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
