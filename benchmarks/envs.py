"""Same as ``crowdsim bench envs`` (``python benchmarks/envs.py --help`` lists its options)."""

import sys

from crowdsim.bench import main

if __name__ == "__main__":
    sys.exit(main("envs"))
