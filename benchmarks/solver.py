"""Same as ``crowdsim bench solver`` (``python benchmarks/solver.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("solver"))
