"""``crowdsim bench NAME [ARGS]``: benchmarks that print a table and one JSON object.

Each benchmark is a module exposing ``add_arguments(parser)`` and ``run(args) -> int``. It is
imported only when run, so a benchmark's heavy or optional dependencies (JuPedSim,
PySocialForce, Clarabel, ...) never slow down or break other commands. The ``benchmarks/``
folder holds thin scripts calling the same modules.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS: dict[str, tuple[str, str]] = {
    "sim": ("crowdsim.bench.sim", "simulator speed vs JuPedSim and PySocialForce (corridor)"),
    "fd": ("crowdsim.bench.fd", "fundamental diagram vs Weidmann and counterflow lanes"),
    "solver": ("tracker.bench_solver",
               "Frank-Wolfe plain/away/SWAP iterations and FW-SWAP vs Clarabel (relaxed BQP)"),
    "render": ("crowdsim.bench.render", "renderer frames/s, 1280x720/1k and 1920x1080/10k agents"),
    "track": ("tracker.bench_track",
              "BQP tracking frames/s at 100/1000 targets, per stage; speed-up vs dense candidates"),
}
"""Benchmark name -> (module, one-line help)."""


def register(sub: argparse._SubParsersAction) -> None:
    listing = "\n".join(f"  {name:<8} {help_text}" for name, (_, help_text) in BENCHMARKS.items())
    parser = sub.add_parser(
        "bench", help="run a benchmark (prints a table and JSON)",
        description=f"{__doc__.splitlines()[0]}\n\nbenchmarks:\n{listing}\n\n"
        "`crowdsim bench NAME --help` lists a benchmark's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("benchmark", metavar="NAME", choices=sorted(BENCHMARKS),
                        help="benchmark to run: " + ", ".join(BENCHMARKS))
    parser.add_argument("bench_args", nargs=argparse.REMAINDER, metavar="ARGS",
                        help="options of the benchmark")
    parser.set_defaults(func=run)


def bench_parser(name: str) -> tuple[argparse.ArgumentParser, object]:
    module, help_text = BENCHMARKS[name]
    mod = importlib.import_module(module)
    parser = argparse.ArgumentParser(prog=f"crowdsim bench {name}", description=help_text)
    mod.add_arguments(parser)
    return parser, mod


def main(name: str, argv: list[str] | None = None) -> int:
    """Run benchmark ``name`` with command-line ``argv`` (the ``benchmarks/`` scripts)."""
    parser, mod = bench_parser(name)
    return int(mod.run(parser.parse_args(argv)) or 0)


def run(args: argparse.Namespace) -> int:
    return main(args.benchmark, args.bench_args)
