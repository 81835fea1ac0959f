"""BQP tracking speed and speed-up sampling; same as ``crowdsim bench track``.

Usage: ``python benchmarks/track.py [--targets 100 1000] [--frames 30] [--sampling-targets 300]``
"""

import argparse
import sys

from tracker import bench_track


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=bench_track.__doc__.splitlines()[0])
    bench_track.add_arguments(parser)
    return bench_track.run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
