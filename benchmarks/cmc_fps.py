"""What camera-motion compensation costs a tracker: frames/s with and without it.

For each sequence of a suite (default the static ``ucf9``), renders the whole sequence once
into memory (camera output: codec and JPEG, what a tracker reads), then tracks it with the
tracker (default BQP with KCF appearance) without compensation and with it at each
``--corners`` count and each ``--redetect`` setting, back to back in one process, ``--rounds``
times; the best round of each counts (the rounds alternate, so a slower spell of a shared
machine falls on all). Reports frames/s (tracking alone, :attr:`tracker.runner.TrackRun.fps`),
the frames/s compensation takes, its ms a frame (the ``cmc`` stage) and acc@15::

    python benchmarks/cmc_fps.py --only seq8 seq2 seq6 seq4 --redetect 0.5 1
    python benchmarks/cmc_fps.py --only seq8 --corners 100 400
    python benchmarks/cmc_fps.py --suite ucf9-shake --rounds 1 --model auto

``--redetect`` and ``--model`` are :attr:`tracker.cmc.CMCParams.redetect` (default
:class:`~tracker.cmc.CMCParams`' own: corners detected on every frame) and ``.model`` (default
``similarity``). The trackers run under the ``crowdsim`` command's process settings
(:func:`crowdsim.cli.process_settings`).

Prints a table and one JSON object. The corner count is chosen by the estimate's error
(``benchmarks/cmc_error.py``), never by a tracker's score.
"""

from __future__ import annotations

import argparse
import json
from itertools import product

from crowdsim.bench import add_suite_arguments, cmc_tracker_or_exit, suite_specs_or_exit
from crowdsim.cli import process_settings


def setting_names(corners: list[int], redetect: list[float]) -> list[str]:
    """``off``, then ``cmc<corners>`` for each count, suffixed ``/r<redetect>`` when more
    than one ``redetect`` is compared (corners outer, redetect inner)."""
    tag = (lambda r: f"/r{r:g}") if len(redetect) > 1 else (lambda r: "")
    return ["off"] + [f"cmc{c}{tag(r)}" for c, r in product(corners, redetect)]


def measure(
    spec,
    tracker: str,
    corners: list[int],
    rounds: int,
    redetect: list[float],
    model: str = "similarity",
) -> dict:
    """Best frames/s, ``cmc`` ms a frame and acc@15 of ``tracker`` on ``spec`` per setting
    (:func:`setting_names`)."""
    from synth_data.sequence import InMemorySequence
    from tracker.cmc import CMCParams
    from tracker.runner import run_tracker

    seq = InMemorySequence.from_spec(spec, camera_output=True).materialize()
    options = [None, *product(corners, redetect)]
    settings = list(zip(setting_names(corners, redetect), options, strict=True))
    rows: dict[str, dict] = {}
    for _ in range(rounds):
        for name, c in settings:

            def prepare(trk, _source, c=c):
                if c is not None:
                    trk.cmc_settings = CMCParams(max_corners=c[0], redetect=c[1], model=model)

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
    ap.add_argument(
        "--corners",
        nargs="+",
        type=int,
        default=[100],
        metavar="N",
        help="CMCParams.max_corners, one or more (100)",
    )
    ap.add_argument(
        "--rounds", type=int, default=2, help="runs of each setting in turn, best kept (2)"
    )
    ap.add_argument(
        "--redetect",
        nargs="+",
        type=float,
        default=None,
        metavar="R",
        help="CMCParams.redetect, one or more: 1 detects corners on every frame, below 1 tracks "
        "them forward (default: CMCParams' own)",
    )
    ap.add_argument(
        "--model",
        default="similarity",
        help="CMCParams.model: similarity (the default), affine, translation or auto",
    )
    args = ap.parse_args()
    process_settings()  # time the trackers as the crowdsim command runs them
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, got {args.rounds}")
    from tracker.cmc import CMCParams

    if args.redetect is None:
        args.redetect = [CMCParams().redetect]
    for c, r in product(args.corners, args.redetect):
        try:
            CMCParams(max_corners=c, redetect=r, model=args.model)
        except ValueError as exc:
            ap.error(f"--corners {c} --redetect {r:g} --model {args.model}: {exc}")
    cmc_tracker_or_exit(ap, args.tracker)
    specs = suite_specs_or_exit(ap, args)
    names = setting_names(args.corners, args.redetect)
    rows = {}
    head = f"{names[0]:>24}" + "".join(f"{n:>26}" for n in names[1:])
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
    from crowdsim.bench import run_script

    raise SystemExit(run_script(main, "cmc_fps.py"))
