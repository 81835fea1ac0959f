"""Head detector speed at 1280x720: the trained network beside the classical LoG baseline.

Renders crowds of ``--people`` over a 1280x720 frame (:func:`synth_data.sequence.
synthetic_crowd`, template 12 px), then times :meth:`tracker.detect.HeadDetector.detect_points`
(forward pass, peak decoding) and :meth:`tracker.detect.LogDetector.detect_points` on the same
frames, best of ``--repeats`` passes over ``--frames`` frames, with torch and OpenCV on 1 and
on all cores. Also reports F1 at 5 px on those frames (the renderer's default look; the LoG
threshold is fitted on another crowd of the same kind). Prints a
table and one JSON object::

    python benchmarks/detect.py                 # 1 and 2 threads on this machine
    python benchmarks/detect.py --threads 1 2 4 8 16
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--people", type=int, default=1000, help="people in the crowd, 1..100000 (1000)"
    )
    ap.add_argument("--frames", type=int, default=10, help="frames timed, 2..100000 (10)")
    ap.add_argument("--repeats", type=int, default=3, help="timed passes, best kept (3)")
    ap.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=None,
        help="torch and OpenCV thread counts, each 1..cores (default: 1 and all cores)",
    )
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    threads = args.threads or sorted({1, cores})
    for n in threads:
        if not 1 <= n <= cores:
            ap.error(f"--threads must be in [1, {cores}], got {n}")
    for flag, value, lo, hi in (
        ("--people", args.people, 1, 100_000),
        ("--frames", args.frames, 2, 100_000),
        ("--repeats", args.repeats, 1, 1000),
    ):
        if not lo <= value <= hi:
            ap.error(f"{flag} must be in [{lo}, {hi}], got {value}")

    import cv2
    import numpy as np
    import torch

    from synth_data.sequence import synthetic_crowd
    from tracker.detect import HeadDetector, LogDetector, LogParams, fit_threshold, score_frame

    crowd = synthetic_crowd(args.people, args.frames, seed=3, template_px=12)
    frames = list(crowd.frames())
    gt = crowd.gt_points()[1]
    net = HeadDetector(template_size=12)
    fit = synthetic_crowd(args.people, 3, seed=4, template_px=12)  # another crowd
    threshold = fit_threshold(list(fit.frames()), list(fit.gt_points()[1]), 12, polarity="both")
    log = LogDetector(LogParams(template_px=12, threshold=threshold, polarity="both"))
    rows = []
    for n in threads:
        torch.set_num_threads(n)
        cv2.setNumThreads(n)
        for name, det in (("head detector", net), ("LoG baseline", log)):
            det.detect_points(frames[0])  # warm-up
            best = float("inf")
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                found = [det.detect_points(f)[0] for f in frames]
                best = min(best, (time.perf_counter() - t0) / len(frames))
            score = sum(
                (score_frame(p, g, 5.0) for p, g in zip(found, gt, strict=True)),
                start=score_frame(np.zeros((0, 2)), np.zeros((0, 2))),
            )
            rows.append(
                {
                    "method": name,
                    "threads": n,
                    "ms_per_frame": round(1000 * best, 2),
                    "fps": round(1 / best, 1),
                    "f1@5px": round(score.f1, 4),
                }
            )
    print(f"{'method':<14} {'threads':>7} {'ms/frame':>9} {'frames/s':>9} {'F1@5px':>7}")
    for r in rows:
        print(
            f"{r['method']:<14} {r['threads']:>7} {r['ms_per_frame']:>9.1f} {r['fps']:>9.1f} "
            f"{r['f1@5px']:>7.3f}"
        )
    ms = {(r["method"], r["threads"]): r["ms_per_frame"] for r in rows}
    ratios = {str(n): round(ms["head detector", n] / ms["LoG baseline", n], 2) for n in threads}
    print(f"head detector / LoG time per frame: {ratios} (by threads)")
    report = {
        "benchmark": "detect",
        "size": "1280x720",
        "people": args.people,
        "rows": rows,
        "time_ratio_detector_vs_log": ratios,
    }
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except KeyboardInterrupt:  # one line and 130, not a traceback (no crowdsim import: the
        # script also runs against older code)
        print("detect.py: interrupted by SIGINT", file=sys.stderr)
        raise SystemExit(130) from None
