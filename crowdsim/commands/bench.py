"""``crowdsim bench NAME [ARGS]``: benchmarks that print a table and one JSON object.

The benchmarks live in :mod:`crowdsim.bench`; ``benchmarks/NAME.py`` runs the same ones.
"""

from __future__ import annotations

import argparse

from crowdsim.bench import BENCHMARKS, main


def register(sub: argparse._SubParsersAction) -> None:
    listing = "\n".join(f"  {name:<8} {help_text}" for name, (_, help_text) in BENCHMARKS.items())
    parser = sub.add_parser(
        "bench",
        help="run a benchmark (prints a table and JSON)",
        description=f"{__doc__.splitlines()[0]}\n\nbenchmarks:\n{listing}\n\n"
        "`crowdsim bench NAME --help` lists a benchmark's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "benchmark",
        metavar="NAME",
        nargs="?",  # missing: named below, not "required: NAME, ARGS" (ARGS are optional)
        choices=sorted(BENCHMARKS),
        help="benchmark to run: " + ", ".join(BENCHMARKS),
    )
    parser.add_argument(
        "bench_args", nargs=argparse.REMAINDER, metavar="ARGS", help="options of the benchmark"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.benchmark is None:
        raise ValueError(f"name a benchmark: {', '.join(BENCHMARKS)}")
    return main(args.benchmark, args.bench_args)
