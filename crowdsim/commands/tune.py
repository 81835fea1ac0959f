"""``crowdsim tune``: tune a tracker's parameters (BQP's by default) with Optuna (or Ray Tune).

``crowdsim tune (--suite NAME | --scenarios DIST) [--only SEQ ...] [--frames N] --trials N
[--sampler tpe|cmaes] [--study URL] [--workers N] [--backend local|ray] [--address ADDR]
--out DIR``

Every trial tracks the tuning sequences with one parameter set (the bandit environment
``crowdsim/TrackerTuningBandit-v0``) and scores the mean accuracy at ``--threshold`` px. The
study lives in ``DIR/study.db`` (SQLite) unless ``--study`` names a shared one (a
``postgresql://`` URL or a journal file, for several machines); rerunning the same command
resumes it: ``--trials`` is the total of finished trials wanted. Writes ``DIR/best_params.json``
(for ``crowdsim track --params``), ``DIR/history.png``, ``DIR/importance.png`` and
``DIR/heldout.json`` / ``.md`` / ``.png``: the best parameters against the paper defaults on
``--heldout`` held-out seeds per sequence or scenario family (never tuned on; ``crowdsim
heldout`` scores a trained policy beside them; a rerun with ``--heldout 0`` removes the ones an
earlier run wrote, so that they never read as the new parameters' scores). Files of those
names in DIR that it cannot prove it wrote are refused, never replaced. See :mod:`envs.tuners`.
"""

from __future__ import annotations

import argparse

from crowdsim.commands._table_args import (
    add_episode_arguments,
    add_tracker_argument,
    episode_objective,
)


def register(sub: argparse._SubParsersAction) -> None:
    from envs.param_space import extended_summary

    p = sub.add_parser(
        "tune",
        help="tune a tracker's parameters, BQP's by default (Optuna / Ray Tune)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    add_episode_arguments(p, only_help="with --suite: tune on these")
    p.add_argument(
        "--trials",
        type=int,
        required=True,
        metavar="N",
        help="finished trials wanted in the study (a rerun resumes)",
    )
    p.add_argument("--sampler", choices=("tpe", "cmaes"), default="tpe")
    p.add_argument(
        "--study",
        metavar="URL",
        help="shared study: postgresql://..., sqlite:///file.db or a journal file "
        "(*.log); default DIR/study.db",
    )
    p.add_argument("--study-name", default="crowdsim-tune", metavar="NAME")
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="parallel trials (processes, or concurrent Ray trials)",
    )
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--address", metavar="ADDR", help="Ray cluster address (--backend ray)")
    p.add_argument(
        "--train-episodes",
        type=int,
        default=3,
        metavar="N",
        help="sequences each trial is scored on: the first N of the scenario stream or of "
        "the suite's sequences (default 3)",
    )
    p.add_argument(
        "--heldout",
        type=int,
        default=3,
        metavar="N",
        help="held-out seeds per sequence or scenario family to score the best parameters "
        "against the defaults on (default 3; 0: skip; see crowdsim heldout)",
    )
    p.add_argument(
        "--threshold",
        type=float,
        default=5.0,
        metavar="PX",
        help="accuracy threshold T in px (default 5)",
    )
    p.add_argument(
        "--extended",
        action="store_true",
        help=f"also tune the tracker's extra parameters ({extended_summary()})",
    )
    add_tracker_argument(p)
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="sampler seed: one worker draws the same trials every run; with several, the "
        "order in which trials finish changes what the sampler draws next",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from crowdsim.checks import require_number
    from envs.tuners import tune

    require_number("", "--train-episodes", args.train_episodes, lo=1, integer=True)
    require_number("", "--threshold", args.threshold, lo=0)
    objective = episode_objective(
        args,
        train_episodes=args.train_episodes,
        threshold_px=args.threshold,
        extended=args.extended,
        tracker=args.tracker,
    )
    res = tune(
        objective,
        trials=args.trials,
        out=args.out,
        sampler=args.sampler,
        study=args.study,
        study_name=args.study_name,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        seed=args.seed,
        heldout=args.heldout,
        progress=not args.no_progress,
    )
    t = args.threshold
    default = "n/a" if res.default_value is None else f"{res.default_value:.2f} %"
    print(
        f"{res.trials} trials; best acc@{t:g} on the tuning sequences {res.best_value:.2f} % "
        f"(paper defaults {default}; scored on the frames after the first, where track "
        "--evaluate and the held-out scores count the first too)"
    )
    print("best: " + ", ".join(f"{k}={v:.4g}" for k, v in res.best_params.items()))
    if res.heldout:
        from envs.heldout import heldout_table

        n = len(res.heldout["sequences"])
        per = res.heldout["seeds_per_family"]
        print(f"held-out ({n} sequences, {per} per family, mean ± std):")
        print(heldout_table(res.heldout), end="")
    print(f"-> {res.files['best_params']}")
    return 0
