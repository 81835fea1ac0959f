"""Every benchmark of crowdsim, importable: ``crowdsim bench NAME`` and ``benchmarks/NAME.py``.

Each benchmark is a module of this package exposing ``add_arguments(parser)`` and
``run(args) -> int``; it prints a table and one JSON object (last line). A benchmark is
imported only when run, so its heavy or optional dependencies (JuPedSim, PySocialForce,
Clarabel, ...) never slow down or break other commands.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable

BENCHMARKS: dict[str, tuple[str, str]] = {
    "sim": ("crowdsim.bench.sim", "simulator speed vs JuPedSim and PySocialForce (corridor)"),
    "fd": ("crowdsim.bench.fd", "fundamental diagram vs Weidmann and counterflow lanes"),
    "solver": (
        "crowdsim.bench.solver",
        "Frank-Wolfe plain/away/SWAP/block iterations and FW-SWAP vs Clarabel (relaxed BQP)",
    ),
    "render": ("crowdsim.bench.render", "renderer frames/s, 1280x720/1k and 1920x1080/10k agents"),
    "track": (
        "crowdsim.bench.track",
        "BQP tracking frames/s at 100/1000 targets, per stage; speed-up vs dense candidates",
    ),
    "envs": ("crowdsim.bench.envs", "environment steps/s (crowd_v0 at 1,000 agents: arrays, dict)"),
}
"""Benchmark name -> (module, one-line help)."""


def bench_parser(name: str) -> tuple[argparse.ArgumentParser, object]:
    module, help_text = BENCHMARKS[name]
    mod = importlib.import_module(module)
    parser = argparse.ArgumentParser(prog=f"crowdsim bench {name}", description=help_text)
    mod.add_arguments(parser)
    return parser, mod


def main(name: str, argv: list[str] | None = None) -> int:
    """Run benchmark ``name`` with command-line ``argv`` (``crowdsim bench NAME`` calls this,
    under the command's process settings and signal handling; so do ``benchmarks/NAME.py``).

    Bad input (``ValueError``) and file errors end with one line on stderr and exit code 2.
    """
    parser, mod = bench_parser(name)
    args = parser.parse_args(argv)
    try:
        from crowdsim.checks import refuse_empty_paths

        refuse_empty_paths(args)
        return int(mod.run(args) or 0)
    except (ValueError, OSError) as exc:
        from crowdsim.atomic import describe_os_error

        text = describe_os_error(exc) if isinstance(exc, OSError) else str(exc)
        print(f"crowdsim bench {name}: error: {text}", file=sys.stderr)
        return 2


def run_script(main: Callable[[], int], name: str) -> int:
    """A standalone ``benchmarks/*.py`` script's entry: ``main()``, or one line and exit 130
    on Ctrl-C (a traceback from wherever the script was had ended it)."""
    try:
        return int(main() or 0)
    except KeyboardInterrupt:
        print(f"{name}: interrupted by SIGINT", file=sys.stderr)
        return 130


def add_suite_arguments(parser: argparse.ArgumentParser, default: str) -> None:
    """``--suite`` (default ``default``) and ``--only SEQ ...``, as the per-suite scripts in
    ``benchmarks/`` take them; :func:`suite_specs_or_exit` reads them."""
    parser.add_argument(
        "--suite", default=default, help=f"built-in suite or folder of spec files ({default})"
    )
    parser.add_argument(
        "--only", nargs="+", default=None, metavar="SEQ", help="only these sequences (all)"
    )


def suite_specs_or_exit(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list:
    """The specs of ``args.suite`` (a built-in name or a suite folder) restricted to
    ``args.only``; an unknown suite or sequence ends with ``parser.error`` naming it."""
    from synth_data.suites import suite_specs

    try:
        return list(suite_specs(args.suite, args.only))
    except (KeyError, FileNotFoundError, ValueError) as exc:
        parser.error(str(exc).strip("'\""))


def cmc_tracker_or_exit(parser: argparse.ArgumentParser, name: str) -> None:
    """Ends with ``parser.error`` unless ``name`` is a registered tracker with camera-motion
    compensation (a ``cmc`` parameter), naming the tracker."""
    from tracker.registry import get

    try:
        if "cmc" not in get(name).field_names():
            parser.error(f"--tracker {name!r} has no camera-motion compensation (cmc)")
    except (KeyError, ValueError) as exc:  # an unknown tracker
        parser.error(str(exc).strip("'\""))
