"""Tracks lost right after their birth on the frame's edge, per sequence of a suite.

Tracks every sequence of a suite (default ``ucf9``, its first ``--frames``) with births
from the ground truth, as the papers' protocol has it, through the camera output (codec and
JPEG, what a tracker reads). A track *lost at birth* ends within ``--within`` frames of its
start while its person stays in view ``--stays`` frames or more after; an *edge* one ended
within ``--edge-px`` px of the frame's edge. Prints one row per sequence (people, tracks lost
at birth, at the edge, the person-frames those lose and the share of the sequence's), then
each edge case (where its person was born and where it walked) and one JSON object::

    python benchmarks/edge_births.py --frames 150
    python benchmarks/edge_births.py --only seq8 --tracker ncc
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from crowdsim.bench import add_suite_arguments, suite_specs_or_exit


def lost_at_birth(ids, gt, res, within: int, stays: int, edge_px: float, size) -> list[dict]:
    """The tracks of ``res`` (ids are the ground truth's) lost at birth (module docstring)."""
    w, h = size
    seen = np.isfinite(gt).all(2)
    column = {int(i): k for k, i in enumerate(res.ids)}
    out = []
    for j, pid in enumerate(ids):
        k = column.get(int(pid))
        if k is None:
            continue
        tracked = np.flatnonzero(np.isfinite(res.positions[:, k]).all(1))
        if len(tracked) == 0:
            continue
        first, last = int(tracked[0]), int(tracked[-1])
        gone = int(np.flatnonzero(seen[: res.n_frames, j])[-1])
        if last - first > within or gone - last < stays:
            continue
        x, y = res.positions[last, k]
        out.append(
            {
                "id": int(pid),
                "born": first,
                "ended": last,
                "in_view_until": gone,
                "frames_lost": gone - last,
                "at": [round(float(x), 1), round(float(y), 1)],
                "edge": bool(min(x, y, w - 1 - x, h - 1 - y) < edge_px),
                "walks": np.round(gt[last + 1 : last + 4, j], 1).tolist(),
            }
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_suite_arguments(ap, "ucf9")
    ap.add_argument("--tracker", default="bqp", help="a registered detection-free tracker (bqp)")
    ap.add_argument("--frames", type=int, default=150, help="first frames of each sequence (150)")
    ap.add_argument("--within", type=int, default=3, help="frames after birth (3)")
    ap.add_argument("--stays", type=int, default=5, help="frames its person stays after (5)")
    ap.add_argument("--edge-px", type=float, default=3.0, help="edge distance, px (3)")
    args = ap.parse_args()
    if args.frames < 2 or args.within < 0 or args.stays < 1 or not args.edge_px >= 0:
        ap.error("--frames >= 2, --within >= 0, --stays >= 1, --edge-px >= 0")
    from synth_data.sequence import InMemorySequence
    from tracker.registry import get
    from tracker.runner import run_tracker

    try:
        get(args.tracker)
    except (KeyError, ValueError) as exc:
        ap.error(str(exc).strip("'\""))
    head = ("people", "lost at birth", "at the edge", "frames lost", "share")
    print(f"{'sequence':<10}" + "".join(f"{c:>15}" for c in head))
    rows = {}
    for spec in suite_specs_or_exit(ap, args):
        seq = InMemorySequence.from_spec(spec, frames=args.frames, camera_output=True)
        seq = seq.materialize()
        ids, gt = seq.gt_points()
        frame = next(iter(seq.frames()))
        res = run_tracker(args.tracker, seq, metrics="none").result
        cases = lost_at_birth(
            ids, gt, res, args.within, args.stays, args.edge_px, frame.shape[1::-1]
        )
        edge = [c for c in cases if c["edge"]]
        lost = sum(c["frames_lost"] for c in edge)
        visible = int(np.isfinite(gt[: res.n_frames]).all(2).sum())
        rows[spec.name] = {"people": len(ids), "person_frames": visible, "cases": cases}
        cells = (len(ids), len(cases), len(edge), lost, f"{100 * lost / max(visible, 1):.2f} %")
        print(f"{spec.name:<10}" + "".join(f"{c:>15}" for c in cells), flush=True)
    for name, r in rows.items():
        for c in r["cases"]:
            if c["edge"]:
                print(
                    f"  {name} id {c['id']}: born frame {c['born']}, ended {c['ended']} at "
                    f"{c['at']}, in view until {c['in_view_until']}, then {c['walks']}"
                )
    doc = {"suite": args.suite, "tracker": args.tracker, "frames": args.frames, "sequences": rows}
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    from crowdsim.bench import run_script

    raise SystemExit(run_script(main, "edge_births.py"))
