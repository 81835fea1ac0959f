"""``crowdsim heldout``: score the paper defaults, tuned parameters and policies on held-out
sequences.

``crowdsim heldout (--suite NAME | --scenarios DIST) [--only SEQ ...] [--frames N] [--seeds S]
[--params [LABEL=]FILE ...] [--policy [LABEL=]FILE ...] --out DIR``

Draws ``--seeds`` held-out sequences per family (each ``--only`` sequence of a built-in suite
re-seeded, or each scenario family of a distribution) from seed streams that ``crowdsim tune``
and ``crowdsim train`` never use, and tracks every one with the tracker's paper defaults,
with each ``best_params.json`` of ``crowdsim tune`` and with each ``model.zip`` of ``crowdsim
train`` (the policy sets the parameters every K frames). Writes ``DIR/heldout.json`` (every
sequence's acc@5, acc@15, HOTA, MOTA, IDF1; mean and std per family and overall),
``DIR/heldout.md`` (the table it prints) and ``DIR/heldout.png``; a ``heldout.*`` already in
DIR that it cannot prove it wrote (its SHA-256 listed in its ``heldout.json``) is refused, never
replaced. See :mod:`envs.heldout`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from crowdsim.commands._table_args import (
    add_episode_arguments,
    add_tracker_argument,
    episode_objective,
)

SEEDS = 5
"""Held-out sequences per family by default (``--seeds``)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "heldout",
        help="score defaults, tuned parameters and policies on held-out sequences",
        description=__doc__.split("\n\n")[0].replace("``", "").replace("\n", " "),
    )
    add_episode_arguments(p, only_help="with --suite: these sequences")
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="S",
        help=f"held-out sequences per family (default {SEEDS}; a folder of MOT sequences is "
        "scored once on its --heldout-only sequences)",
    )
    p.add_argument(
        "--params",
        nargs="+",
        default=[],
        metavar="[LABEL=]FILE",
        help="best_params.json of crowdsim tune (label default: tuned)",
    )
    p.add_argument(
        "--policy",
        nargs="+",
        default=[],
        metavar="[LABEL=]FILE",
        help="model.zip of crowdsim train, or scene_aware.json of crowdsim train --algo scene "
        "(label default: policy)",
    )
    p.add_argument(
        "--no-defaults", action="store_true", help="leave the paper defaults out of the table"
    )
    add_tracker_argument(p)
    p.add_argument(
        "--metrics",
        choices=("full", "accuracy"),
        default="full",
        help="full: acc@5/15, HOTA, MOTA, IDF1 (default); accuracy: acc@5/15 only (fast)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def _labelled(items: list[str], default: str, flag: str) -> dict[str, str]:
    """``[LABEL=]FILE`` arguments -> ``{label: file}`` (``default``, ``default-2``, ...)."""
    out: dict[str, str] = {}
    for k, item in enumerate(items):
        label, sep, path = item.partition("=")
        if not sep:
            label, path = (default if k == 0 else f"{default}-{k + 1}"), item
        if not label or not path:
            raise ValueError(f"{flag}: expected [LABEL=]FILE, got {item!r}")
        if label in out:
            raise ValueError(f"{flag}: label {label!r} given twice")
        out[label] = path
    return out


def run(args: argparse.Namespace) -> int:
    from envs.heldout import check_heldout_out, evaluate_heldout, heldout_table, write_heldout
    from envs.param_space import load_params
    from envs.training import load_policy, policy_meta

    seeds_given = args.seeds is not None
    if not seeds_given:
        args.seeds = SEEDS
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    out = Path(args.out)
    check_heldout_out(out)  # a user's own heldout.* is never replaced: refused before any work
    objective = episode_objective(args, tracker=args.tracker)
    if objective.folder and objective.heldout_only:
        # a folder's sequences are scored once each, as they are: these had been ignored
        if seeds_given:
            raise ValueError(
                f"--seeds: a folder of MOT sequences cannot be re-seeded; {args.suite} is "
                "scored once on its --heldout-only sequences (drop --seeds)"
            )
        if args.only:
            raise ValueError(
                f"--only: {args.suite}'s held-out sequences are the --heldout-only ones "
                "(drop --only)"
            )
    param_sets = {}
    if not args.no_defaults:
        param_sets["defaults"] = objective.space().base
    for label, path in _labelled(args.params, "tuned", "--params").items():
        if label in param_sets:  # the reference row every other is compared with
            raise ValueError(
                f"--params {label}={path}: the label {label!r} names the paper defaults' row; "
                "choose another label (or pass --no-defaults)"
            )
        name, params = load_params(path)
        if name != args.tracker:
            raise ValueError(
                f"--params {path}: parameters of the {name!r} tracker, but --tracker is "
                f"{args.tracker!r} (add --tracker {name})"
            )
        param_sets[label] = params
    policy_files = _labelled(args.policy, "policy", "--policy")
    clash = sorted(set(param_sets) & set(policy_files))
    if clash:
        what = "the paper defaults' row" if clash[0] == "defaults" else "a --params label"
        raise ValueError(f"--policy: the label {clash[0]!r} is {what}; choose another label")
    policies = {}
    for label, path in policy_files.items():
        name = policy_meta(path)["env_kwargs"].get("tracker", "bqp")
        if name != args.tracker:
            raise ValueError(
                f"--policy {path}: a policy of the {name!r} tracker, but --tracker is "
                f"{args.tracker!r} (add --tracker {name})"
            )
        policies[label] = load_policy(path)  # a damaged policy is refused before any work
    if not param_sets and not policies:
        raise ValueError("nothing to score: give --params or --policy (or drop --no-defaults)")
    objective.episodes(heldout=True)  # validate suite / scenarios / --only before any work
    result = evaluate_heldout(
        objective,
        param_sets,
        args.seeds,
        policies=policies,
        metrics=args.metrics,
        progress=not args.no_progress,
    )
    files = write_heldout(result, out)
    n = len(result["sequences"])
    print(f"{n} held-out sequences ({result['seeds_per_family']} per family), mean ± std:")
    print(heldout_table(result), end="")
    print(f"-> {files['heldout']}, {files['heldout_table']}, {files['heldout_plot']}")
    return 0
