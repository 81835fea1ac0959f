"""Same as ``crowdsim bench render`` (``python benchmarks/render.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("render"))
