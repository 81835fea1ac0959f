"""How many threads a tracker's compiled kernels and FFTs use.

A tracker runs its numba kernels (``parallel=True``) and SciPy FFTs on the threads set here.
:class:`tracker.base.Tracker` enters :func:`using_threads` around every frame with its
``threads`` attribute; ``None`` leaves numba's current setting alone (all cores in a plain
process, one in :mod:`crowdsim.jobs` pool workers). Frames with fewer than
``Tracker.parallel_min_targets`` targets run on one thread.

Every parallel kernel gives each loop iteration (a target pair, a target, a connected
component of the problem) to one thread and sums in a fixed order, so tracks are the same
bit for bit for any number of threads: only the speed changes.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import numba

from crowdsim.checks import require_number


def max_threads() -> int:
    """The most threads a tracker may use: the cores, and at most numba's thread pool."""
    return max(1, min(os.cpu_count() or 1, int(numba.config.NUMBA_NUM_THREADS)))


def check_threads(value, name: str = "threads") -> int:
    """``value`` as an int in ``[1, max_threads()]``; a ``ValueError`` naming ``name`` else."""
    require_number("", name, value, lo=1, hi=max_threads(), integer=True)
    return int(value)


@contextmanager
def using_threads(threads: int | None) -> Iterator[None]:
    """Run the block with numba (and so the trackers' FFTs) on ``threads`` threads.

    numba's setting is per calling thread; it is restored on exit. ``None`` changes nothing.
    """
    if threads is None:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(check_threads(threads))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def current_threads() -> int:
    """The threads a parallel kernel started now would use (numba's per-thread setting)."""
    return int(numba.get_num_threads())
