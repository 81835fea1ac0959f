"""Frank-Wolfe variants vs Clarabel on relaxed BQP frames; same as ``crowdsim bench solver``.

Usage: ``python benchmarks/solver.py [--sizes 100,300,1000] [--from-npz FILE] [--out DIR]``
"""

import sys

from tracker.bench_solver import main

if __name__ == "__main__":
    sys.exit(main())
