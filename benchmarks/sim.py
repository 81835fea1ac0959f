"""Same as ``crowdsim bench sim`` (``python benchmarks/sim.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("sim"))
