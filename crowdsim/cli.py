"""The ``crowdsim`` console command.

Each sub-command lives in its own module under :mod:`crowdsim.commands` and exposes
``register(subparsers)``; the module adds its parser and sets ``func`` to a callable taking the
parsed arguments and returning an exit code. Heavy imports happen inside ``func`` so that
``crowdsim --help`` stays fast.

User errors (bad flags, bad files, out-of-range parameters) end with exit code 2 and one line
``crowdsim <command>: error: <message>`` on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from crowdsim import __version__

COMMAND_MODULES: tuple[str, ...] = (
    "crowdsim.commands.simulate",
    "crowdsim.commands.track",
    "crowdsim.commands.evaluate",
    "crowdsim.commands.render",
    "crowdsim.commands.generate",
    "crowdsim.commands.bench",
    "crowdsim.commands.demo",
)
"""Modules that register a sub-command, in the order ``--help`` lists them."""


class UsageError(ValueError):
    """A user error found after argument parsing (bad file, bad combination of flags)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="crowdsim",
        description="Dense-crowd tracking testbed: simulate crowds, render synthetic "
        "benchmarks, track and evaluate.",
    )
    parser.add_argument("--version", action="version", version=f"crowdsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"crowdsim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"crowdsim {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
