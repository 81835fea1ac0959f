"""``crowdsim bench NAME``: benchmarks that print a table and one JSON object.

Each benchmark is a module exposing ``add_arguments(parser)`` and ``run(args) -> int``; the
``benchmarks/`` folder holds thin scripts calling the same modules.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS: dict[str, tuple[str, str]] = {
    "sim": ("crowdsim.bench.sim", "simulator speed vs JuPedSim and PySocialForce (corridor)"),
    "fd": ("crowdsim.bench.fd", "fundamental diagram and counterflow lanes vs Weidmann"),
}
"""Benchmark name -> (module, one-line help)."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("bench", help="run a benchmark (prints a table and JSON)",
                            description=__doc__.splitlines()[0])
    bench_sub = parser.add_subparsers(dest="benchmark", metavar="NAME")
    bench_sub.required = True
    for name, (module, help_text) in BENCHMARKS.items():
        p = bench_sub.add_parser(name, help=help_text, description=help_text)
        mod = importlib.import_module(module)
        mod.add_arguments(p)
        p.set_defaults(func=mod.run)
