"""``crowdsim train``: learn an adaptive parameter policy (stable-baselines3) or a scene-aware one.

``crowdsim train --algo ppo|sac|scene [--envs N] [--steps N] (--scenarios DIST | --suite NAME)
[--tracker NAME] --out DIR``

``--algo scene`` (:mod:`envs.scene_aware`, no extra needed): tracks ``--episodes`` training
episodes with each of ``--candidates`` settings from the ``--k``-th frame on, and writes
``DIR/scene_aware.json`` (for ``--policy``: after the first ``--k`` + 1 frames it picks the
setting that did best on the nearest training scenes), ``DIR/static_params.json`` (the best
single setting of the same episodes, for ``--params``), ``DIR/scene_fit.json`` and
``DIR/scene_fit.png`` (leave-one-out scores). ``--envs`` is then its worker processes.

Trains on ``crowdsim/TrackerTuning-v0`` (the policy sets the tracker's parameters, BQP's by
default, every ``--k`` frames) over ``--envs`` asynchronous environments (subprocesses). Writes
``DIR/model.zip`` (for ``crowdsim track --policy``), ``DIR/learning_curve.png`` and
``DIR/learning_curve.json`` (a user's own files of those names are refused, never replaced).
Needs the ``rl`` extra (torch, stable-baselines3). The environment processes die with this one
(a SIGKILL leaves no orphan).
"""

from __future__ import annotations

import argparse

from crowdsim.commands._table_args import (
    add_episode_cache_arguments,
    add_tracker_argument,
    episode_cache_kwargs,
)

SCENE_EPISODES = 40
"""``--algo scene``'s training episodes by default."""
SCENE_CANDIDATES = 17
"""``--algo scene``'s candidate settings by default (as ``crowdsim headroom``)."""
PPO_STEPS = 2048
"""``--algo ppo`` / ``sac``'s environment steps by default (``None`` on the parser, so that
``--algo scene``, which has no steps, can tell a given ``--steps`` from the default)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train an adaptive parameter policy (PPO / SAC) or a scene-aware one",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument(
        "--algo",
        choices=("ppo", "sac", "scene"),
        required=True,
        help="ppo / sac: an adaptive policy (stable-baselines3, the rl extra); scene: a "
        "scene-aware choice among --candidates settings after the first --k frames, from "
        "the nearest of --episodes training episodes",
    )
    p.add_argument(
        "--envs",
        type=int,
        default=1,
        metavar="N",
        help="asynchronous environments (subprocesses; default 1); with --algo scene: "
        "worker processes",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        metavar="N",
        help=f"--algo scene: training episodes, each tracked with every candidate "
        f"({SCENE_EPISODES})",
    )
    p.add_argument(
        "--candidates",
        type=int,
        default=None,
        metavar="M",
        help=f"--algo scene: the defaults and M-1 Sobol settings, as crowdsim headroom "
        f"({SCENE_CANDIDATES})",
    )
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        metavar="N",
        help=f"ppo / sac: environment steps in total (each tracks --k frames; {PPO_STEPS})",
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--scenarios",
        metavar="DIST",
        default=None,
        help="scenario distribution (default 'all'; 'nonstationary': an event part-way "
        "through every episode; see crowdsim tune)",
    )
    src.add_argument(
        "--suite",
        metavar="NAME",
        help="built-in suite, folder of spec files or folder of MOT sequences",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="with --suite: these sequences")
    p.add_argument("--frames", type=int, metavar="N", help="frames per sequence")
    p.add_argument("--k", type=int, default=25, metavar="K", help="frames per step (25)")
    add_episode_cache_arguments(p)
    p.add_argument(
        "--threshold",
        type=float,
        default=5.0,
        metavar="PX",
        help="reward threshold T in px (default 5)",
    )
    add_tracker_argument(p)
    p.add_argument(
        "--extended",
        action="store_true",
        help="the tracker's extra tunables too (BQP: 8 tuned parameters instead of 5)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.checks import require_number
    from envs.training import train

    if args.only and not args.suite:
        raise ValueError("--only needs --suite")
    require_number("", "--k", args.k, lo=1, integer=True)
    require_number("", "--threshold", args.threshold, lo=0)
    if args.frames is not None:
        require_number("", "--frames", args.frames, lo=2, integer=True)
    if args.algo == "scene":  # checked here, where the flags are, before any work
        if args.episodes is None:
            args.episodes = SCENE_EPISODES
        if args.candidates is None:
            args.candidates = SCENE_CANDIDATES
        require_number("", "--candidates", args.candidates, lo=1, hi=1024, integer=True)
        require_number("", "--episodes", args.episodes, lo=1, integer=True)
        if args.steps is not None:  # it had been ignored in silence
            raise ValueError("--steps is for --algo ppo / sac (scene tracks --episodes episodes)")
    else:
        if args.steps is None:
            args.steps = PPO_STEPS
        for flag in ("--episodes", "--candidates"):
            if getattr(args, flag[2:]) is not None:
                raise ValueError(f"{flag} is for --algo scene (ppo / sac learn from --steps)")
    kwargs = {"k_frames": args.k, "threshold_px": args.threshold, "extended": args.extended}
    if args.tracker != "bqp":  # policies of the default tracker keep their metadata as before
        kwargs["tracker"] = args.tracker
    if args.suite:
        kwargs.update(suite=args.suite, only=args.only)
    else:
        kwargs["scenarios"] = args.scenarios or "all"
    if args.frames is not None:
        kwargs["frames"] = args.frames
    if args.algo == "scene":
        return _scene(args, kwargs)
    kwargs.update(episode_cache_kwargs(args))
    doc = train(
        args.algo,
        out=args.out,
        n_envs=args.envs,
        steps=args.steps,
        env_kwargs=kwargs,
        seed=args.seed,
        progress=not args.no_progress,
    )
    eps = doc["episodes"]
    if eps:
        k = max(1, len(eps) // 4)
        first = sum(e["reward_per_step"] for e in eps[:k]) / k
        last = sum(e["reward_per_step"] for e in eps[-k:]) / k
        print(
            f"{len(eps)} episode{'s' if len(eps) != 1 else ''}; mean step reward "
            f"{first:.2f} % (first {k}) -> {last:.2f} % (last {k})"
        )
    print(f"-> {args.out}/model.zip, learning_curve.png")
    return 0


def _scene(args: argparse.Namespace, kwargs: dict) -> int:
    """``--algo scene``: fit and write a scene-aware policy (:mod:`envs.scene_aware`)."""
    from envs.scene_aware import check_scene_out, fit_scene_aware, write_scene_aware
    from envs.tuners import Objective

    if args.episode_cache or args.pool is not None:
        raise ValueError(
            "--episode-cache and --pool are for ppo / sac (scene tracks each episode once)"
        )
    objective = Objective(
        suite=kwargs.get("suite"),
        scenarios=kwargs.get("scenarios"),
        only=tuple(kwargs.get("only") or ()),
        frames=kwargs.get("frames"),
        threshold_px=kwargs["threshold_px"],
        extended=kwargs["extended"],
        tracker=kwargs.get("tracker", "bqp"),
    )
    check_scene_out(args.out)
    pol, record = fit_scene_aware(
        objective,
        episodes=args.episodes,
        candidates=args.candidates,
        k_frames=args.k,
        seed=args.seed,
        workers=args.envs,
        progress=not args.no_progress,
    )
    record["command"] = {
        "scenarios": kwargs.get("scenarios"),
        "suite": kwargs.get("suite"),
        "only": kwargs.get("only"),
        "frames": kwargs.get("frames"),
    }
    write_scene_aware(pol, record, args.out)
    print(f"-> {args.out}/scene_aware.json, static_params.json, scene_fit.png")
    return 0
