"""``crowdsim bench render``: renderer frames per second (SPEC §9), encoding excluded.

Cases (targets on a 2-core CPU): 1280x720 with 1,000 agents >= 100 frames/s and 1920x1080
with 10,000 agents >= 20 frames/s. Each case scatters agents uniformly over the visible
ground, walking at 1.34 m/s in random directions, prepares their tracks (projection,
headings, sway; not timed), renders a few warm-up frames (JIT load) and then times
``SceneRenderer.render`` alone, then again with the per-head visibility that the sequence
writer asks for (``fps+vis``). JPEG encoding is timed separately and reported next to it.
``--set KEY=VALUE`` sets appearance knobs (e.g. ``--set body_scale=1.4 arm_swing=0.2``) to
time the realistic-difficulty features.

Prints a table and one JSON object on the last line.
"""

from __future__ import annotations

import argparse
import json
import time

DEFAULT_CASES: tuple[str, ...] = ("1280x720:1000", "1920x1080:10000")
TARGETS: dict[str, float] = {"1280x720:1000": 100.0, "1920x1080:10000": 20.0}
"""Case -> target frames/s (SPEC §9 and issue 3)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cases",
        nargs="+",
        default=list(DEFAULT_CASES),
        metavar="WxH:N",
        help="frame size and agent count per case (default: the SPEC targets)",
    )
    parser.add_argument(
        "--frames", type=int, default=100, metavar="N", help="timed frames per case (default 100)"
    )
    parser.add_argument(
        "--template-px",
        type=int,
        default=10,
        metavar="PX",
        help="person template size in pixels, 4..64 (default 10)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic crowd")
    parser.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        dest="knobs",
        help="appearance knobs, e.g. body_scale=1.4 (numbers or strings)",
    )


def _parse_knobs(items: list[str]) -> dict[str, object]:
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set entries look like body_scale=1.4, got {item!r}")
        try:
            out[key] = int(value)
        except ValueError:
            try:
                out[key] = float(value)
            except ValueError:
                out[key] = value
    return out


def _parse_case(text: str) -> tuple[int, int, int]:
    try:
        size, n = text.split(":")
        w, h = (int(v) for v in size.lower().split("x"))
        return w, h, int(n)
    except ValueError:
        raise ValueError(f"--cases entries look like 1280x720:1000, got {text!r}") from None


def run_case(
    width: int,
    height: int,
    n_agents: int,
    frames: int,
    template_px: int,
    seed: int,
    knobs: dict[str, object] | None = None,
) -> dict[str, float | int | str]:
    """Time one case; returns a JSON-ready row."""
    import numpy as np

    from crowdsim.appearance_model import AppearanceParams
    from crowdsim.camera import Camera
    from crowdsim.render import SceneRenderer, default_px_per_m, encode_jpeg, prepare_agents
    from crowdsim.trajectories import Trajectories

    params = AppearanceParams.from_dict({"template_px": template_px, **(knobs or {})})
    s = default_px_per_m(template_px)
    cam = Camera(px_per_m=s, width=width, height=height, center=(width / s / 2, height / s / 2))
    rng = np.random.default_rng(seed)
    warm = 3
    t_len = frames + warm
    start = rng.uniform((0.0, 0.0), (width / s, height / s), (n_agents, 2))
    ang = rng.uniform(0, 2 * np.pi, n_agents)
    vel = 1.34 * np.column_stack([np.cos(ang), np.sin(ang)])
    dt = 0.04
    pos = start[None] + vel[None] * (np.arange(t_len) * dt)[:, None, None]
    traj = Trajectories(positions=pos, ids=np.arange(n_agents), dt=dt)
    t0 = time.perf_counter()
    renderer = SceneRenderer(cam, params, seed=seed, fps=1 / dt)
    t_setup = time.perf_counter() - t0
    tracks = prepare_agents(traj, cam, params, seed)
    out = np.empty((height, width, 3), np.uint8)
    for t in range(warm):
        renderer.render_tracks(tracks, t, out=out)
    t0 = time.perf_counter()
    c0 = time.process_time()
    for t in range(warm, t_len):
        renderer.render_tracks(tracks, t, out=out)
    t_render = time.perf_counter() - t0
    c_render = time.process_time() - c0
    vis = np.empty(n_agents)
    t0 = time.perf_counter()
    for t in range(warm, t_len):
        renderer.render_tracks(tracks, t, out=out, visibility=vis)
    t_vis = time.perf_counter() - t0
    n_enc = min(frames, 20)
    t0 = time.perf_counter()
    size = 0
    for _ in range(n_enc):
        size += len(encode_jpeg(out, params.jpeg_quality))
    t_jpeg = (time.perf_counter() - t0) / n_enc
    fps = frames / t_render
    case = f"{width}x{height}:{n_agents}"
    target = TARGETS.get(case)
    return {
        "case": case,
        "width": width,
        "height": height,
        "agents": n_agents,
        "frames": frames,
        "fps": round(fps, 1),
        "ms_per_frame": round(1e3 / fps, 2),
        "fps_with_visibility": round(frames / t_vis, 1),
        "cpu_ms_per_frame": round(1e3 * c_render / frames, 2),
        "jpeg_ms_per_frame": round(1e3 * t_jpeg, 2),
        "fps_with_jpeg": round(1.0 / (1.0 / fps + t_jpeg), 1),
        "jpeg_kb_per_frame": round(size / n_enc / 1024, 1),
        "setup_s": round(t_setup, 2),
        "target_fps": target,
        "meets_target": None if target is None else bool(fps >= target),
    }


def run(args: argparse.Namespace) -> int:
    import os

    from crowdsim.checks import require_number
    from crowdsim.scenarios import MAX_AGENTS

    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    require_number("", "--seed", args.seed, lo=0, integer=True)
    require_number("", "--template-px", args.template_px, lo=4, hi=64, integer=True)
    cases = [_parse_case(c) for c in args.cases]
    for w, h, n in cases:
        if not (8 <= w <= 16384 and 8 <= h <= 16384 and 0 <= n <= MAX_AGENTS):
            raise ValueError(
                f"--cases: bad case {w}x{h}:{n} (sides 8..16384 px, 0..{MAX_AGENTS} agents)"
            )
    knobs = _parse_knobs(args.knobs)
    rows = [run_case(w, h, n, args.frames, args.template_px, args.seed, knobs) for w, h, n in cases]
    head = (
        f"{'case':>18} {'fps':>8} {'fps+vis':>8} {'ms/frame':>9} {'cpu ms':>7} "
        f"{'+jpeg fps':>10} {'KB/frame':>9} {'target':>9}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        target = (
            "-"
            if r["target_fps"] is None
            else f"{r['target_fps']:g}{' ok' if r['meets_target'] else ' MISS'}"
        )
        print(
            f"{r['case']:>18} {r['fps']:>8} {r['fps_with_visibility']:>8} "
            f"{r['ms_per_frame']:>9} {r['cpu_ms_per_frame']:>7} "
            f"{r['fps_with_jpeg']:>10} {r['jpeg_kb_per_frame']:>9} {target:>9}"
        )
    print(
        "fps = wall-clock frames/s of SceneRenderer.render (JPEG excluded); fps+vis = the "
        "same with the per-head visibility the writer uses; cpu ms = process CPU time per "
        "frame (all threads), a guide when other jobs share the cores"
    )
    print(
        json.dumps(
            {
                "benchmark": "render",
                "template_px": args.template_px,
                "knobs": knobs,
                "cpu_count": os.cpu_count(),
                "load_avg_1min": os.getloadavg()[0],
                "cases": rows,
            }
        )
    )
    return 0
