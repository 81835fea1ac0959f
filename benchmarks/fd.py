"""Same as ``crowdsim bench fd`` (``python benchmarks/fd.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("fd"))
