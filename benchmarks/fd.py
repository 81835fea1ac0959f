"""Same as ``crowdsim bench fd`` (see ``python benchmarks/fd.py --help``)."""

import sys

from crowdsim.commands.bench import main

if __name__ == "__main__":
    sys.exit(main("fd"))
