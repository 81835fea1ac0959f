"""``crowdsim render``: render trajectories (simulator .npz or a frame,id,x,y CSV) to a sequence.

``crowdsim render --trajectories FILE.csv|FILE.npz --fps F [--px-per-m S] [--size WxH]
[--seed K] --out SEQ_DIR``

Frame size and scale default to fitting the trajectories' extent (scale: the template spans
0.5 m). The output is one MOTChallenge sequence folder, written atomically.
"""

from __future__ import annotations

import argparse


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must look like 1280x720, got {text!r}") from None
    return w, h


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="render trajectories to a MOTChallenge sequence",
                       description=__doc__.splitlines()[0].replace("``", ""))
    p.add_argument("--trajectories", required=True, metavar="FILE",
                   help=".npz from crowdsim simulate, or a CSV frame,id,x,y in metres")
    p.add_argument("--fps", type=float, default=None, metavar="F",
                   help="frame rate of the trajectories (required for CSV; .npz knows its dt)")
    p.add_argument("--px-per-m", type=float, default=None, metavar="S", help="scale, px/m")
    p.add_argument("--size", type=_size, default=None, metavar="WxH", help="frame size")
    p.add_argument("--template-px", type=int, default=12, metavar="PX",
                   help="person template size in pixels (default 12)")
    p.add_argument("--seed", type=int, default=0, metavar="K", help="rendering seed")
    p.add_argument("--video", action="store_true", help="also write video.mp4")
    p.add_argument("--overwrite", action="store_true", help="replace an existing SEQ_DIR")
    p.add_argument("--out", required=True, metavar="SEQ_DIR", help="sequence folder to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from tqdm import tqdm

    from crowdsim.appearance_model import AppearanceParams
    from crowdsim.camera import Camera
    from crowdsim.render import default_px_per_m
    from crowdsim.trajectories import Trajectories
    from synth_data.writer import write_sequence

    path = Path(args.trajectories)
    if args.fps is not None and not (args.fps > 0):
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    if args.px_per_m is not None and not (args.px_per_m > 0):
        raise ValueError(f"--px-per-m must be > 0, got {args.px_per_m}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if path.suffix == ".npz":
        traj = Trajectories.load(path)
        if args.fps is not None and abs(args.fps - traj.fps) > 1e-9:
            traj = Trajectories(positions=traj.positions, ids=traj.ids, dt=1.0 / args.fps,
                                attributes=traj.attributes, meta=traj.meta)
    elif path.suffix == ".csv":
        if args.fps is None:
            raise ValueError("--fps is required for CSV trajectories")
        traj = Trajectories.from_csv(path, fps=args.fps)
    else:
        raise ValueError(f"--trajectories must be a .csv or .npz file, got {str(path)!r}")
    appearance = AppearanceParams(template_px=args.template_px)
    if args.size is not None:
        w, h = args.size
        if not (8 <= w <= 16384 and 8 <= h <= 16384):
            raise ValueError(f"--size must be between 8x8 and 16384x16384, got {w}x{h}")
    scale = args.px_per_m
    if scale is None and args.size is None:
        scale = default_px_per_m(args.template_px)
    camera = Camera.fit(traj.extent(), px_per_m=scale, size=args.size, seed=args.seed)
    meta = {"source": str(path), "seed": args.seed, "fps": traj.fps}
    with tqdm(total=traj.n_steps, unit="frame", desc="rendering") as bar:
        entry = write_sequence(args.out, traj, camera=camera, appearance=appearance,
                               seed=args.seed, meta=meta, video=args.video,
                               overwrite=args.overwrite, progress=bar.update)
    print(f"wrote {args.out}: {entry['frames']} frames {camera.width}x{camera.height} "
          f"at {camera.px_per_m:.2f} px/m")
    return 0
