"""What camera-motion compensation costs a tracker: frames/s with and without it.

For each sequence of a suite (default the static ``ucf9``), renders the whole sequence once
into memory (camera output: codec and JPEG, what a tracker reads), then tracks it with the
tracker (default BQP with KCF appearance) without compensation and with it at each
``--corners`` count, back to back in one process, ``--rounds`` times; the best round of each
counts (the rounds alternate, so a slower spell of a shared machine falls on all). Reports
frames/s (tracking alone, :attr:`tracker.runner.TrackRun.fps`), the frames/s compensation
takes, its ms a frame (the ``cmc`` stage) and acc@15::

    python benchmarks/cmc_fps.py --only seq8 seq2 seq6 seq4 --corners 100 400
    python benchmarks/cmc_fps.py --suite ucf9-shake --rounds 1 --model auto

``--model`` is :attr:`tracker.cmc.CMCParams.model` (default ``similarity``).

Prints a table and one JSON object. The corner count is chosen by the estimate's error
(``benchmarks/cmc_error.py``), never by a tracker's score.
"""

from __future__ import annotations

import argparse
import json

from crowdsim.bench import add_suite_arguments, cmc_tracker_or_exit, suite_specs_or_exit


def measure(
    spec,
    tracker: str,
    corners: list[int],
    rounds: int,
    redetect: float = 1.0,
    model: str = "similarity",
) -> dict:
    """Best frames/s, ``cmc`` ms a frame and acc@15 of ``tracker`` on ``spec`` per setting."""
    from synth_data.sequence import InMemorySequence
    from tracker.cmc import CMCParams
    from tracker.runner import run_tracker

    seq = InMemorySequence.from_spec(spec, camera_output=True).materialize()
    settings = [("off", None)] + [(f"cmc{c}", c) for c in corners]
    rows: dict[str, dict] = {}
    for _ in range(rounds):
        for name, c in settings:

            def prepare(trk, _source, c=c):
                if c is not None:
                    trk.cmc_settings = CMCParams(max_corners=c, redetect=redetect, model=model)

            run = run_tracker(
                tracker, seq, params={"cmc": c is not None}, metrics="accuracy", prepare=prepare
            )
            best = rows.get(name)
            if best is None or run.fps > best["fps"]:
                rows[name] = {
                    "fps": run.fps,
                    "cmc_ms": run.stage_ms.get("cmc", 0.0),
                    "acc@15": float(run.report["acc@15"]),
                }
    off = rows["off"]["fps"]
    for name, _ in settings[1:]:
        rows[name]["fps_cost"] = 1.0 - rows[name]["fps"] / off
    return {"size": [seq.width, seq.height], "people": len(seq.gt_points()[0]), **rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_suite_arguments(ap, "ucf9")
    ap.add_argument("--tracker", default="bqp", help="a registered detection-free tracker")
    ap.add_argument("--corners", nargs="+", type=int, default=[100], metavar="N")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument(
        "--redetect",
        type=float,
        default=1.0,
        help="CMCParams.redetect: 1 detects corners on every frame, below 1 tracks them forward",
    )
    ap.add_argument(
        "--model",
        default="similarity",
        help="CMCParams.model: similarity (the default), affine, translation or auto",
    )
    args = ap.parse_args()
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, got {args.rounds}")
    from tracker.cmc import CMCParams

    for c in args.corners:
        try:
            CMCParams(max_corners=c, redetect=args.redetect, model=args.model)
        except ValueError as exc:
            ap.error(f"--corners {c} --redetect {args.redetect} --model {args.model}: {exc}")
    cmc_tracker_or_exit(ap, args.tracker)
    specs = suite_specs_or_exit(ap, args)
    names = ["off"] + [f"cmc{c}" for c in args.corners]
    rows = {}
    head = "".join(f"{n:>24}" for n in names)
    print(
        f"{'sequence':<10}{'size':>11}{'people':>7}{head}"
        "   (frames/s, cost, cmc ms a frame; acc@15 of each)"
    )
    for spec in specs:
        r = rows[spec.name] = measure(
            spec, args.tracker, args.corners, args.rounds, args.redetect, args.model
        )
        cells = f"{r['off']['fps']:>24.1f}" + "".join(
            f"{r[n]['fps']:>10.1f}{-100 * r[n]['fps_cost']:>+6.0f} %{r[n]['cmc_ms']:>5.1f} ms"
            for n in names[1:]
        )
        size = "x".join(map(str, r["size"]))
        acc = " / ".join(f"{r[n]['acc@15']:.1f}" for n in names)
        print(f"{spec.name:<10}{size:>11}{r['people']:>7}{cells}   {acc}", flush=True)
    print(
        json.dumps(
            {
                "suite": args.suite,
                "tracker": args.tracker,
                "rounds": args.rounds,
                "redetect": args.redetect,
                "model": args.model,
                "sequences": rows,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
