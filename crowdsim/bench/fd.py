"""``crowdsim bench fd``: validation against real crowds (SPEC §3).

* Fundamental diagram: unidirectional periodic corridors at densities 0.5-4 /m²; PedPy
  measures classic density and mean speed in a 4 m measurement area; each point is compared
  with Weidmann's curve (target: within ±20 %).
* Counterflow lanes: the lane order parameter over time in a periodic bidirectional
  corridor, next to its value for a random mix of the same positions.
* Sanity: the deepest body overlap seen (target: <= 20 % of the radius at <= 4 /m²).

Writes ``fd.png``, ``lanes.png`` and ``fd.json`` into ``--out`` and prints a table and one
JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from crowdsim.atomic import OVERWRITE_HELP
from crowdsim.checks import path_arg

OUTPUTS = ("fd.png", "lanes.png", "fd.json")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--densities",
        default="0.5,1,1.5,2,2.5,3,3.5,4",
        help="corridor densities in /m² (default 0.5,...,4)",
    )
    parser.add_argument("--length", type=float, default=20.0, help="corridor length, m")
    parser.add_argument("--width", type=float, default=5.0, help="corridor width, m")
    parser.add_argument("--warmup", type=float, default=20.0, help="warm-up seconds")
    parser.add_argument("--measure", type=float, default=20.0, help="measured seconds")
    parser.add_argument(
        "--lane-seconds", type=float, default=40.0, help="duration of the counterflow run, s"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--out",
        type=path_arg,
        default=Path("benchmarks/out"),
        help="folder for fd.png, lanes.png and fd.json (default: benchmarks/out, under the "
        "working folder)",
    )
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def run(args: argparse.Namespace) -> int:
    try:
        densities = [float(d) for d in args.densities.split(",") if d.strip()]
    except ValueError:
        raise ValueError(
            f"--densities must be comma-separated numbers, got {args.densities!r}"
        ) from None
    bad = [d for d in densities if not 0 < d <= 6]
    if bad or not densities:
        raise ValueError(f"--densities must lie in (0, 6] /m², got {args.densities!r}")
    from crowdsim.atomic import require_replaceable
    from crowdsim.checks import require_number, require_output_dir
    from crowdsim.scenarios import MAX_AGENTS, MAX_LENGTH_M

    for name, hi in (("length", MAX_LENGTH_M), ("width", MAX_LENGTH_M)) + tuple(
        (name, 3600.0) for name in ("warmup", "measure", "lane_seconds")
    ):
        flag = f"--{name.replace('_', '-')}"
        require_number("", flag, getattr(args, name), lo=0, hi=hi, lo_open=True)
    require_number("", "--seed", args.seed, lo=0, integer=True)
    from crowdsim.scenarios import Counterflow

    # a shorter corridor was built 6.5 m long, and its density reported as the target's
    require_number("", "--length", args.length, lo=Counterflow.MIN_PERIOD)
    width = 2 * Counterflow.radius[1] + 0.2  # the corridor's own check named counterflow.width
    require_number("", "--width", args.width, lo=width)
    from crowdsim.params import SocialForceParams
    from crowdsim.validation import FD_SPEED_FRAME_STEP

    dt = SocialForceParams().dt  # fewer frames gave a NaN speed, or a pandas error
    if round(args.measure / dt) < FD_SPEED_FRAME_STEP + 1:
        raise ValueError(
            f"--measure must be at least {(FD_SPEED_FRAME_STEP + 1) * dt:g} s "
            f"({FD_SPEED_FRAME_STEP + 1} steps of {dt:g} s: PedPy's speeds span "
            f"{FD_SPEED_FRAME_STEP}), got {args.measure:g}"
        )
    crowd = max(densities) * args.length * args.width
    if crowd > MAX_AGENTS:
        raise ValueError(
            f"--length {args.length:g} x --width {args.width:g} m at {max(densities):g} /m² "
            f"holds {crowd:.3g} people, more than the {MAX_AGENTS} a scenario takes"
        )
    require_output_dir("--out", args.out)
    outputs = [args.out / name for name in OUTPUTS]
    for path in outputs:
        require_replaceable("--out", path, args.overwrite)

    from crowdsim.atomic import output_folder, recorded, write_text_atomic
    from crowdsim.validation import fundamental_diagram, lane_formation

    points = fundamental_diagram(
        densities,
        length=args.length,
        width=args.width,
        warmup_s=args.warmup,
        measure_s=args.measure,
        seed=args.seed,
        progress=True,
    )
    lanes = lane_formation(seconds=args.lane_seconds, seed=args.seed)
    fd_rows = [
        {
            "target_density": p.target_density,
            "density": p.density,
            "speed": p.speed,
            "weidmann": p.weidmann,
            "ratio": p.ratio,
            "within_20pct": bool(0.8 <= p.ratio <= 1.2),
            "max_overlap": p.max_overlap,
        }
        for p in points
    ]
    n_late = max(1, len(lanes["lane_order"]) // 4)
    report: dict[str, Any] = {
        "benchmark": "fd",
        "fundamental_diagram": fd_rows,
        "all_within_20pct": all(r["within_20pct"] for r in fd_rows),
        "max_overlap": max(r["max_overlap"] for r in fd_rows),
        "lanes": {
            **lanes,
            "final_lane_order": sum(lanes["lane_order"][-n_late:]) / n_late,
            "final_random_mix": sum(lanes["random_mix"][-n_late:]) / n_late,
        },
    }
    with output_folder(args.out), recorded(*outputs):  # a failure after fd.png notes fd.png
        _plot(report, args.out)
        write_text_atomic(args.out / "fd.json", json.dumps(report) + "\n")

    print(
        f"{'rho target':>10} {'rho PedPy':>10} {'v (m/s)':>8} {'Weidmann':>9} {'ratio':>6} "
        f"{'max ov':>7}"
    )
    for r in fd_rows:
        flag = "" if r["within_20pct"] else "  <- outside ±20 %"
        print(
            f"{r['target_density']:>10.2f} {r['density']:>10.2f} {r['speed']:>8.3f} "
            f"{r['weidmann']:>9.3f} {r['ratio']:>6.2f} {r['max_overlap']:>7.3f}{flag}"
        )
    lane = report["lanes"]
    # the final figure is the mean of the last quarter of the samples, taken every 2 s (one,
    # at t = 0, in a run under 2 s): it had said "after N s" whatever it was
    late = lane["time"][-max(1, len(lane["time"]) // 4) :]
    when = f"at {late[0]:g} s" if len(late) == 1 else f"mean over {late[0]:g}-{late[-1]:g} s"
    print(
        f"\nlane order {when} of {args.lane_seconds:g} s: {lane['final_lane_order']:.2f} "
        f"(random mix {lane['final_random_mix']:.2f}, start {lane['lane_order'][0]:.2f})"
    )
    print(f"plots: {args.out / 'fd.png'}, {args.out / 'lanes.png'}")
    print(json.dumps(report))
    return 0


def _plot(report: dict[str, Any], out: Path) -> None:
    import numpy as np

    from crowdsim.plotting import new_figure, save_figure
    from crowdsim.scenarios import weidmann_speed

    rows = report["fundamental_diagram"]
    fig, ax = new_figure(figsize=(6, 4))
    rho = np.linspace(0.3, 5.3, 200)
    w = weidmann_speed(rho)
    ax.plot(rho, w, "k-", label="Weidmann (1993)")
    ax.fill_between(rho, 0.8 * w, 1.2 * w, color="0.85", label="±20 %")
    ax.plot(
        [r["density"] for r in rows],
        [r["speed"] for r in rows],
        "o",
        color="tab:red",
        label="crowdsim (PedPy)",
    )
    ax.set_xlabel("density (1/m²)")
    ax.set_ylabel("speed (m/s)")
    ax.set_title("Fundamental diagram, periodic corridor")
    ax.legend()
    save_figure(fig, out / "fd.png")

    lanes = report["lanes"]
    fig, ax = new_figure(figsize=(6, 3.5))
    ax.plot(lanes["time"], lanes["lane_order"], "-o", ms=3, label="counterflow")
    ax.plot(lanes["time"], lanes["random_mix"], "--", label="random mix, same positions")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("lane order parameter")
    ax.set_ylim(0, 1)
    ax.legend()
    save_figure(fig, out / "lanes.png")
