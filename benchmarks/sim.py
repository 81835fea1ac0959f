"""Same as ``crowdsim bench sim`` (see ``python benchmarks/sim.py --help``)."""

import sys

from crowdsim.commands.bench import main

if __name__ == "__main__":
    sys.exit(main("sim"))
