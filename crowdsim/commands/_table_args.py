"""Flags shared by the commands that fan work out (one place, one wording).

:func:`add_jobs_arguments`: ``--workers``, ``--backend``, ``--address`` of the jobs runner
(:mod:`crowdsim.jobs`), for ``generate`` and the table commands;
:func:`add_table_arguments`: everything ``compare``, ``ablation`` and ``difficulty`` take;
:func:`add_episode_arguments` / :func:`episode_objective`: the sequences ``tune``,
``heldout`` and ``headroom`` score on; :func:`add_tracker_argument`: their ``--tracker``
(and ``train``'s); :func:`add_episode_cache_arguments` / :func:`episode_cache_kwargs`: the
episode cache of ``train``.
"""

from __future__ import annotations

import argparse
import sys


def add_jobs_arguments(p: argparse.ArgumentParser, workers_help: str, workers: int | None) -> None:
    """``--workers N``, ``--backend local|ray``, ``--address ADDR`` (see :mod:`crowdsim.jobs`)."""
    p.add_argument("--workers", type=int, default=workers, metavar="N", help=workers_help)
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local process pool (default) or Ray tasks",
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="Ray cluster address (default: start a local Ray instance)",
    )


DEFAULT_SUITE = "ucf9"
"""The suite of ``compare``, ``ablation`` and ``difficulty`` without ``--suite``."""


def add_table_arguments(
    p: argparse.ArgumentParser, writes: str = "", sequences: bool = False
) -> None:
    """``--suite NAME|DIR``, ``--only``, ``--frames``, the jobs flags, ``--out``,
    ``--no-progress`` of ``compare``, ``ablation`` and ``difficulty`` (``writes``: what the
    command writes into ``--out`` beside the tables, for its help); with ``sequences``,
    ``--sequences DIR`` instead of ``--suite`` (``compare`` and ``ablation``: the user's
    own MOT sequences; ``difficulty`` changes specs, so it has none)."""
    src = p.add_mutually_exclusive_group() if sequences else p
    src.add_argument(
        "--suite",
        # None beside --sequences: argparse tells a given value from the default by identity,
        # so a default "ucf9" would let "--suite ucf9 --sequences DIR" through
        default=None if sequences else DEFAULT_SUITE,
        metavar="NAME|DIR",
        help="built-in suite (ucf9, ucf9-shake, ucf9-drone, galleria, stress) or a suite "
        "folder of spec files, e.g. one written by crowdsim calibrate --out (default ucf9)",
    )
    if sequences:
        src.add_argument(
            "--sequences",
            metavar="DIR",
            help="instead of a suite: your own sequences in the MOT layout (a folder of "
            "sequence folders with seqinfo.ini, gt/gt.txt and img1/ or video.mp4, as "
            "crowdsim generate writes them, or one such folder), tracked where they are and "
            "never written into; no papers' figures",
        )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="only these sequences")
    p.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="truncate every sequence to its first N frames (quick runs; a suite's camera is "
        "framed on those frames' crowd, as generate --frames does)",
    )
    add_jobs_arguments(p, "parallel cells (local processes or Ray tasks; default 1)", 1)
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder: sequences/ (generated"
        + ("; not with --sequences" if sequences else "")
        + "), cells.json (resume), table.md, table.csv, "
        f"curves/*.png{writes} and outputs.json (their digests: a rerun replaces only those)",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")


def table_run_kwargs(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`crowdsim.lab.experiments.run_table` (and of what runs on it)
    from :func:`add_table_arguments`' flags, with a log to stderr."""

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    if args.address is not None and args.backend != "ray":  # the wording of generate's
        raise ValueError(f"--address needs --backend ray, got --address {args.address!r}")
    return {
        "only": args.only,
        "frames": args.frames,
        "workers": args.workers,
        "backend": args.backend,
        "address": args.address,
        "progress": not args.no_progress,
        "log": log,
    }


def add_set_argument(p: argparse.ArgumentParser) -> None:
    """``--set NAME=VALUE`` of ``compare`` and ``ablation``: a tracker parameter for every row
    whose tracker has it (:func:`crowdsim.lab.experiments.with_params`)."""
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="tracker parameter for every row whose tracker has it, e.g. --set fw_variant=block "
        "(repeatable; a parameter a row sets itself is refused)",
    )


def table_source(args: argparse.Namespace) -> str:
    """How a table's title names what it ran on: ``--sequences DIR`` or ``--suite``."""
    sequences = getattr(args, "sequences", None)
    return str(sequences if sequences is not None else args.suite or DEFAULT_SUITE)


def run_table_command(args: argparse.Namespace, rows, title: str, paper_table: str) -> int:
    """Run :func:`crowdsim.lab.experiments.run_table` from the flags; print the table.

    With ``--set`` (:func:`add_set_argument`), every row whose tracker has the parameter runs
    with it, and the title names the settings."""
    from crowdsim.commands.simulate import parse_assignments
    from crowdsim.lab.experiments import run_table, with_params

    settings = parse_assignments(getattr(args, "set", None), "--set")
    if settings:
        rows = with_params(rows, settings)
        title += " with " + ", ".join(f"{k}={v}" for k, v in settings.items())
    kwargs = table_run_kwargs(args)  # flags checked before any work
    sequences = getattr(args, "sequences", None)
    suite = None if sequences is not None else args.suite or DEFAULT_SUITE
    text = run_table(
        rows,
        suite,
        args.out,
        sequences=sequences,
        title=title,
        paper_table=paper_table,
        **kwargs,
    )
    print(text)
    print(
        f"table -> {args.out}/table.md, {args.out}/table.csv; curves -> {args.out}/curves/",
        file=sys.stderr,
    )
    return 0


def add_tracker_argument(p: argparse.ArgumentParser) -> None:
    """``--tracker NAME``: a tracker with a row of tunables (``tune``, ``train``, ``heldout``,
    ``headroom``); checked by :func:`envs.param_space.require_tunable` when the work starts."""
    from envs.param_space import tunable_trackers  # the TUNABLES table, so a new row shows

    p.add_argument(
        "--tracker",
        default="bqp",
        help=f"tunable tracker from the registry ({', '.join(tunable_trackers(plugins=False))}; "
        "or a plug-in built on one's parameters; default bqp)",
    )


def add_episode_arguments(p: argparse.ArgumentParser, only_help: str) -> None:
    """``--suite NAME | --scenarios DIST``, ``--only``, ``--heldout-only``, ``--frames``."""
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--suite",
        metavar="NAME",
        help="built-in suite (ucf9, ucf9-shake, ucf9-drone, galleria, stress), a folder of "
        "spec files (such as calibrate --out writes) or a folder of MOT sequences",
    )
    src.add_argument(
        "--scenarios",
        metavar="DIST",
        help="scenario distribution: 'all', 'nonstationary' (one lighting, noise, shake, "
        "stop or surge event per episode; families by event), a comma list "
        "(marathon,crossing) or a JSON/TOML file of ScenarioDistribution fields",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help=only_help)
    p.add_argument(
        "--heldout-only",
        nargs="+",
        metavar="SEQ",
        help="with a folder of MOT sequences: score on these (built-in suites, spec folders "
        "and scenarios use other seeds)",
    )
    p.add_argument("--frames", type=int, metavar="N", help="frames per sequence")


def episode_objective(args: argparse.Namespace, **fields: object) -> object:
    """The :class:`envs.tuners.Objective` of :func:`add_episode_arguments`' flags (checked)."""
    from envs.tuners import Objective
    from synth_data.suites import is_spec_suite

    if args.only and not args.suite:
        raise ValueError("--only needs --suite (name scenarios in --scenarios)")
    if args.heldout_only and (not args.suite or is_spec_suite(args.suite)):
        raise ValueError(
            "--heldout-only names sequences of a folder of MOT sequences; built-in suites, "
            "spec folders and --scenarios are scored on other seeds of the same sequences "
            "(drop it)"
        )
    if args.frames is not None and args.frames < 2:
        raise ValueError(f"--frames must be >= 2, got {args.frames}")
    return Objective(
        suite=args.suite,
        scenarios=args.scenarios,
        only=args.only or (),
        heldout_only=args.heldout_only or (),
        frames=args.frames,
        **fields,
    )


DEFAULT_POOL = 64
"""Distinct episodes of a scenario distribution kept in an episode cache (``--pool``)."""


def add_episode_cache_arguments(p: argparse.ArgumentParser) -> None:
    """``--episode-cache DIR`` and ``--pool N`` (:class:`envs.episodes.EpisodeCache`)."""
    p.add_argument(
        "--episode-cache",
        metavar="DIR",
        help="keep rendered episodes in DIR: each is simulated, rendered and encoded once "
        "(checksummed, read back by every reset, epoch and process; reused by later runs)",
    )
    p.add_argument(
        "--pool",
        type=int,
        metavar="N",
        help="with --scenarios and --episode-cache: distinct episodes drawn and reused "
        f"(default {DEFAULT_POOL})",
    )


def episode_cache_kwargs(args: argparse.Namespace) -> dict:
    """``episode_cache`` / ``pool`` keyword arguments of ``TrackerTuning-v0`` from
    :func:`add_episode_cache_arguments`' flags (checked)."""
    from pathlib import Path

    from crowdsim.checks import require_number

    if args.episode_cache is None:
        if args.pool is not None:
            raise ValueError("--pool needs --episode-cache DIR")
        return {}
    out: dict = {"episode_cache": str(Path(args.episode_cache).absolute())}
    if getattr(args, "suite", None) is not None:
        from synth_data.suites import is_spec_suite

        if not is_spec_suite(args.suite):  # it had been ignored in silence
            raise ValueError(
                f"--episode-cache: {args.suite} holds MOT sequences, read from disk as they "
                "are; nothing is rendered to keep (drop --episode-cache)"
            )
        if args.pool is not None:
            raise ValueError("--pool draws from --scenarios; a --suite has its own sequences")
        return out
    pool = DEFAULT_POOL if args.pool is None else args.pool
    require_number("", "--pool", pool, lo=1, integer=True)
    out["pool"] = pool
    return out
