"""Renderer frames per second; same as ``crowdsim bench render``.

Usage: ``python benchmarks/render.py [--cases 1280x720:1000 1920x1080:10000] [--frames 100]``
"""

import argparse
import sys

from crowdsim.bench import render


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=render.__doc__.splitlines()[0])
    render.add_arguments(parser)
    return render.run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
