"""``python -m crowdsim.commands._generate_main ARGS``: ``crowdsim generate ARGS`` without the
rest of the CLI (used by tests that run generation in a subprocess)."""

from __future__ import annotations

import argparse
import sys

from crowdsim.commands import generate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="crowdsim")
    generate.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["generate", *(sys.argv[1:] if argv is None else argv)])
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"crowdsim generate: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        from crowdsim.cli import describe_os_error

        print(f"crowdsim generate: error: {describe_os_error(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
