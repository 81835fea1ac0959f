"""``crowdsim generate``: spec files or a named suite -> MOTChallenge sequences on disk.

``crowdsim generate (--suite NAME [--only SEQ ...] | --spec FILE ...) --out DIR [--frames N]
[--workers N] [--backend local|ray] [--address ADDR] [--overwrite]``

Writes ``DIR/<sequence name>/`` and ``DIR/manifest.json``; completed sequences are skipped on a
rerun (resume), existing sequences made from another spec are only replaced with
``--overwrite`` (otherwise exit code 2). See :mod:`synth_data.generate`.

Exit codes: 0 done; 1 a worker failed or died (finished sequences are kept: rerun to resume);
2 a user error or a file-system error (full disk, read-only folder...: one line naming the
path, nothing left behind); 130 SIGINT and 143 SIGTERM (the run stops at once, removes its
temporary folders and says so in one line; see :func:`crowdsim.cli.main`).
"""

from __future__ import annotations

import argparse
import os


def register(sub: argparse._SubParsersAction) -> None:
    from crowdsim.commands._table_args import add_jobs_arguments
    from crowdsim.knobs import reference

    p = sub.add_parser(
        "generate",
        help="generate synthetic benchmark sequences (MOT layout)",
        description=__doc__.splitlines()[0].replace("``", ""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="The rendering knobs of a spec file (its [appearance] section and the camera's "
        "shake and drone profile;\na value out of range is refused on load, naming the file, "
        "the field and the value):\n\n" + reference(),
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--suite",
        metavar="NAME|DIR",
        help="built-in suite (ucf9, ucf9-shake, ucf9-drone, galleria, stress) or a suite "
        "folder of spec files",
    )
    src.add_argument(
        "--spec",
        action="append",
        metavar="FILE",
        help="sequence spec file (.toml/.yaml); repeat for several",
    )
    p.add_argument("--only", nargs="+", metavar="SEQ", help="with --suite: only these sequences")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument(
        "--frames",
        type=int,
        metavar="N",
        help="truncate every sequence to N frames: the crowd's first N frames, with the camera "
        "framed on them (a spec without camera width, height and center gets another frame "
        "size or centre than the whole sequence's)",
    )
    add_jobs_arguments(
        p, "parallel sequences (default: CPU count, at most the sequence count)", None
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace existing sequences that do not match their spec",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from crowdsim.jobs import Interrupted
    from synth_data.generate import GenerationError, clean_stale_tmp, generate
    from synth_data.spec import load_spec
    from synth_data.suites import suite_specs

    if args.only and not args.suite:
        raise ValueError("--only needs --suite")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if args.address and args.backend != "ray":
        raise ValueError(f"--address needs --backend ray, got --address {args.address!r}")
    for f in args.spec or ():
        if Path(f).is_dir():  # a folder of spec files is a suite
            raise ValueError(f"--spec {f}: is a folder; a folder of spec files is --suite {f}")
    specs = suite_specs(args.suite, args.only) if args.suite else [load_spec(f) for f in args.spec]
    specs = [s.truncated(args.frames) for s in specs]
    workers = args.workers if args.workers is not None else min(os.cpu_count() or 1, len(specs))
    try:  # crowdsim.cli.main turns SIGINT and SIGTERM into Interrupted while this runs
        manifest = generate(
            specs,
            args.out,
            workers=workers,
            backend=args.backend,
            address=args.address,
            overwrite=args.overwrite,
            progress=not args.no_progress,
        )
    except GenerationError as exc:
        print(f"crowdsim generate: error: {exc}", file=sys.stderr)
        return 1
    except Interrupted as exc:
        if getattr(exc, "removed", None) is None and os.path.isdir(args.out):
            clean_stale_tmp(args.out)  # stopped before any job ran
        exc.detail = _kept(args.out)
        raise
    seqs = manifest["sequences"]
    total = sum(e["bytes"] for e in seqs.values())
    print(
        f"{len(seqs)} sequence(s) complete in {args.out} ({total / 1e6:.1f} MB); "
        f"manifest: {os.path.join(args.out, 'manifest.json')}"
    )
    return 0


def _kept(out: str) -> str:
    """What an interrupted run leaves, in words that are true: the finished sequences the
    manifest lists (this run's and earlier runs'), or that nothing was finished."""
    from synth_data.generate import MANIFEST_SECTION, read_manifest_of

    if not os.path.isdir(out):  # the folder this run made is gone again
        return f"nothing was finished; {out} was removed again"
    n = len(read_manifest_of(out)[MANIFEST_SECTION])
    if n == 0:
        return (
            "workers stopped, this run's temporary folders removed; nothing was finished, "
            "rerun the same command to start again"
        )
    return (
        f"workers stopped, this run's temporary folders removed; {n} finished sequence(s) "
        f"are kept in {out}, rerun the same command to resume"
    )
