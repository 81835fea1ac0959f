"""``crowdsim render``: render trajectories (simulator .npz or a frame,id,x,y CSV) to a sequence.

``crowdsim render --trajectories FILE.csv|FILE.npz --fps F [--frame-step K] [--period M]
[--px-per-m S] [--size WxH] [--seed K] --out SEQ_DIR [--overwrite]``

Frame size and scale default to fitting the trajectories' extent (scale: the template spans
0.5 m). The output is one MOTChallenge sequence folder, written atomically by
:func:`synth_data.writer.write_sequence`: into a temporary sibling folder whose marker file,
written first, proves it is ours, then renamed into place. A temporary folder left by a killed
render is removed by the next render into the same parent folder (only when its marker names a
dead process of this host); SIGINT and SIGTERM remove it at once and say so in one line (one
that lands while the finished sequence is renamed into place waits for it, and the line says
the sequence was written whole).

Exit codes: 0 done; 2 a user or file-system error (one line naming the flag, file or value);
130 SIGINT and 143 SIGTERM (see :func:`crowdsim.cli.main`).

Limits (checked before anything is allocated): frame sides 8..8192 px, scale 1e-3..1e4 px/m,
coordinates within ±1e5 m (:data:`crowdsim.trajectories.MAX_COORD_M`), and an estimated working
set within :data:`crowdsim.checks.MEMORY_LIMIT_BYTES`. ``--overwrite`` replaces only a
folder crowdsim can prove it wrote, file by file: a sequence whose ``checksums.json`` lists every
file in it with its SHA-256 (:func:`synth_data.mot.not_ours`), or a suite folder holding only
its ``manifest.json`` and such sequences (checked again just before the swap); it never replaces
the input file, and refuses anything else naming the first file that is not its own.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

MAX_SIDE_PX = 8192
"""Largest frame width or height (px); one 8192 x 8192 frame peaked at 3.0 GiB resident
(``/usr/bin/time``, 2 cores), so the largest frames run on a 24 GiB machine."""
MIN_SIDE_PX = 8
PX_PER_M_RANGE = (1e-3, 1e4)
"""Allowed ``--px-per-m``: beyond 1e4 px/m a 12 px person is 1 mm wide."""
MAX_FPS = 1000.0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must look like 1280x720, got {text!r}") from None
    return w, h


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render trajectories to a MOTChallenge sequence",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument(
        "--trajectories",
        required=True,
        metavar="FILE",
        help=".npz from crowdsim simulate, or a CSV frame,id,x,y in metres",
    )
    p.add_argument(
        "--fps",
        type=float,
        default=None,
        metavar="F",
        help="frame rate of the trajectories, (0, 1000] (required for CSV; a .npz knows its "
        "dt, and F relabels its steps as F frames/s: the people move at F dt times their speed)",
    )
    p.add_argument(
        "--frame-step",
        type=int,
        default=None,
        metavar="K",
        help="CSV frames annotated every K-th frame (ETH/UCY: 10) become consecutive frames; "
        "frames that all step by more than 1 are refused without it (--frame-step 1 keeps "
        "the gaps)",
    )
    p.add_argument(
        "--period",
        type=float,
        default=None,
        metavar="M",
        help="CSV trajectories of a periodic world: the length (m) of its periodic x axis "
        "(as the meta of a crowdsim simulate .npz records it), so that a person crossing the seam "
        "keeps heading and gait; a .npz carries its own",
    )
    p.add_argument(
        "--px-per-m", type=float, default=None, metavar="S", help="scale, px/m, in [0.001, 10000]"
    )
    p.add_argument(
        "--size",
        type=_size,
        default=None,
        metavar="WxH",
        help=f"frame size, sides {MIN_SIDE_PX}..{MAX_SIDE_PX} px (even with --video)",
    )
    p.add_argument(
        "--template-px",
        type=int,
        default=12,
        metavar="PX",
        help="person template size in pixels, 4..64 (default 12)",
    )
    p.add_argument("--seed", type=int, default=0, metavar="K", help="rendering seed")
    p.add_argument(
        "--video",
        action="store_true",
        help="also write SEQ_DIR/video.mp4, the frames of img1/ as one video",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing crowdsim sequence (or suite) folder SEQ_DIR",
    )
    p.add_argument("--out", required=True, metavar="SEQ_DIR", help="sequence folder to write")
    p.set_defaults(func=run)


# ---------------------------------------------------------------------------- checks
def _check_flags(args: argparse.Namespace) -> None:
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= MAX_FPS):
        raise ValueError(f"--fps must be in (0, {MAX_FPS:g}], got {args.fps}")
    lo, hi = PX_PER_M_RANGE
    if args.px_per_m is not None and not (
        math.isfinite(args.px_per_m) and lo <= args.px_per_m <= hi
    ):
        raise ValueError(f"--px-per-m must be in [{lo:g}, {hi:g}], got {args.px_per_m:g}")
    if args.period is not None and not (math.isfinite(args.period) and args.period > 0):
        raise ValueError(f"--period must be a length > 0 m, got {args.period:g}")
    if not 0 <= args.seed < 2**63:
        raise ValueError(f"--seed must be in [0, 2**63), got {args.seed}")
    if args.size is not None:
        w, h = args.size
        if not (MIN_SIDE_PX <= w <= MAX_SIDE_PX and MIN_SIDE_PX <= h <= MAX_SIDE_PX):
            raise ValueError(
                f"--size must be between {MIN_SIDE_PX}x{MIN_SIDE_PX} and "
                f"{MAX_SIDE_PX}x{MAX_SIDE_PX}, got {w}x{h}"
            )
        if args.video and (w % 2 or h % 2):
            # MPEG-4 frames have even sides: OpenCV's writer cut the odd column and row off
            # in silence, and video.mp4 held other frames than img1/ and seqinfo.ini's size
            raise ValueError(f"--size must have even sides for --video, got {w}x{h}")
    if not 4 <= args.template_px <= 64:
        raise ValueError(f"--template-px must be in [4, 64], got {args.template_px}")


def check_output(out: Path, source: Path, overwrite: bool) -> None:
    """Refuse an ``--out`` that is the input, holds it, or is not ours to replace."""
    src = source.resolve()
    dst = out.resolve()
    if dst == src or dst in src.parents:
        raise ValueError(f"--out {out} would replace the input {source}; choose another folder")
    if not (out.exists() or out.is_symlink()):
        return
    if not overwrite:
        raise ValueError(f"--out {out} already exists; pass --overwrite to replace it")
    if out.is_symlink() or not out.is_dir():
        raise ValueError(
            f"--out {out} is a file, not a crowdsim sequence folder; refusing to "
            "replace it with --overwrite"
        )
    from synth_data.mot import not_ours

    why = not_ours(out)
    if why is not None:
        raise ValueError(
            f"--out {out} is not a crowdsim sequence or suite folder that crowdsim can prove it "
            f"wrote ({why}); refusing to replace it with --overwrite"
        )


# ---------------------------------------------------------------------------- command
def load_trajectories(
    path: Path, fps: float | None, frame_step: int | None = None, period: float | None = None
):
    from crowdsim.trajectories import Trajectories

    if path.suffix == ".npz" and period is not None:
        raise ValueError(
            "--period is for CSV trajectories; a .npz from crowdsim simulate carries its own "
            "(meta.period)"
        )
    if path.suffix == ".npz":
        traj = Trajectories.load(path)
        if fps is not None and abs(fps - traj.fps) > 1e-9:
            traj = Trajectories(
                positions=traj.positions,
                ids=traj.ids,
                dt=1.0 / fps,
                attributes=traj.attributes,
                meta=traj.meta,
            )
    elif path.suffix == ".csv":
        if fps is None:
            raise ValueError("--fps is required for CSV trajectories")
        traj = Trajectories.from_csv(path, fps=fps, frame_step=frame_step, period=period or 0.0)
    else:
        raise ValueError(f"--trajectories must be a .csv or .npz file, got {str(path)!r}")
    if traj.n_steps == 0 or not traj.present.any():
        raise ValueError(f"{path}: the trajectories contain no present position")
    return traj


def run(args: argparse.Namespace) -> int:
    import sys

    from crowdsim.appearance_model import AppearanceParams
    from crowdsim.camera import Camera
    from crowdsim.checks import require_memory, require_output_dir
    from crowdsim.progress import progress_bar
    from crowdsim.render import default_px_per_m, render_bytes
    from synth_data.mot import mot_ids, require_outside_sequences
    from synth_data.writer import clean_stale_tmp, write_sequence

    _check_flags(args)
    path = Path(args.trajectories)
    out = Path(args.out)
    if not out.name or out.name in (".", ".."):
        raise ValueError(f"--out must name a folder, got {args.out!r}")
    require_output_dir("--out", out)
    # a sequence in a sequence (rendering onto one itself, with --overwrite, is allowed)
    require_outside_sequences("--out", out, args.out, itself=False)
    # first the leftovers of killed renders: a sequence a killed --overwrite had moved aside
    # takes its name back before the name is checked
    for p in clean_stale_tmp(out.parent):
        print(f"crowdsim render: removed {p}, left by a render that was killed", file=sys.stderr)
    check_output(out, path, args.overwrite)
    if args.frame_step is not None and (args.frame_step < 1 or path.suffix != ".csv"):
        raise ValueError(
            f"--frame-step must be >= 1 and goes with a CSV, got {args.frame_step} for {path.name}"
        )
    traj = load_trajectories(path, args.fps, args.frame_step, args.period)
    appearance = AppearanceParams(template_px=args.template_px)
    scale = args.px_per_m
    if scale is None and args.size is None:
        scale = default_px_per_m(args.template_px)
    camera = Camera.fit(traj.extent(), px_per_m=scale, size=args.size, seed=args.seed)
    if not (
        MIN_SIDE_PX <= camera.width <= MAX_SIDE_PX and MIN_SIDE_PX <= camera.height <= MAX_SIDE_PX
    ):  # pragma: no cover - fit clips
        raise ValueError(f"frame size {camera.width}x{camera.height} is outside the limits")
    require_memory(
        f"rendering {traj.n_steps} frames of {camera.width}x{camera.height} px with "
        f"{traj.n_agents} people",
        render_bytes(camera.width, camera.height, traj.n_steps, traj.n_agents),
    )
    pix = camera.project(traj.positions[traj.present])
    if not camera.visible(pix).any():
        xmin, ymin, xmax, ymax = traj.extent()
        raise ValueError(
            f"--px-per-m {camera.px_per_m:g}: no trajectory point falls inside "
            f"the {camera.width}x{camera.height} frame (the people span "
            f"{(xmax - xmin) * camera.px_per_m:.3g} x "
            f"{(ymax - ymin) * camera.px_per_m:.3g} px); lower --px-per-m or "
            "enlarge --size"
        )
    meta = {"source": str(path), "seed": args.seed, "fps": traj.fps}
    if "first_frame" in traj.meta:  # a CSV: where each MOT frame and id came from
        meta["csv_frame_of_mot_frame_1"] = traj.meta["first_frame"]
        meta["csv_frame_step"] = traj.meta["frame_step"]
        meta["csv_id_of_mot_id"] = {
            str(int(m)): int(i) for m, i in zip(mot_ids(traj.ids), traj.ids, strict=True)
        }
    out.parent.mkdir(parents=True, exist_ok=True)
    before = out.stat().st_ino if out.is_dir() else None  # an --overwrite's old sequence
    try:
        with progress_bar(total=traj.n_steps, unit="frame", desc="rendering") as bar:
            entry = write_sequence(
                out,
                traj,
                camera=camera,
                appearance=appearance,
                seed=args.seed,
                meta=meta,
                video=args.video,
                overwrite=args.overwrite,
                progress=bar.update,
            )
    except KeyboardInterrupt as exc:  # crowdsim.jobs.Interrupted: SIGINT or SIGTERM
        # a signal during the renames is held until the sequence has its name: then it is whole
        published = out.is_dir() and out.stat().st_ino != before
        exc.detail = (
            f"the sequence was written whole first: {out}"
            if published
            else f"removed the unfinished temporary folder of {out}"
        )
        raise
    except OSError as exc:  # name --out, not the hidden temporary folder (or nothing)
        name = "" if exc.filename is None else Path(os.fsdecode(exc.filename)).name
        # an error of our own (no errno: its message names the folder already) is left alone
        if exc.errno is not None and (exc.filename is None or name.startswith(".crowdsim-tmp-")):
            raise type(exc)(exc.errno, exc.strerror or str(exc), str(out)) from None
        raise
    print(
        f"wrote {out}: {entry['frames']} frames {camera.width}x{camera.height} "
        f"at {camera.px_per_m:.2f} px/m"
    )
    return 0
