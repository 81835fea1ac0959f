"""Same as ``crowdsim bench render`` (``python benchmarks/render.py --help`` lists its options)."""

import sys
from pathlib import Path

# Python puts this folder first on sys.path, where envs.py would shadow the envs package
here = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != here]

from crowdsim.cli import main  # noqa: E402

if __name__ == "__main__":
    # through the command itself: its process settings (OMP_WAIT_POLICY, malloc), its
    # one-line errors and its Ctrl-C handling (exit 130), exactly as `crowdsim bench render`
    sys.exit(main(["bench", "render", *sys.argv[1:]]))
