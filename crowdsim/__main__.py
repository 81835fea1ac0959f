"""``python -m crowdsim``: the same as the ``crowdsim`` console command."""

import sys

from crowdsim.cli import main

if __name__ == "__main__":
    sys.exit(main())
