"""Same as ``crowdsim bench track`` (``python benchmarks/track.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("track"))
