"""How many threads a tracker's compiled kernels and FFTs use.

A tracker runs its numba kernels (``parallel=True``) and SciPy FFTs on the threads set here.
:class:`tracker.base.Tracker` enters :func:`using_threads` around every frame with its
``threads`` attribute; ``None`` leaves numba's current setting alone (all cores in a plain
process, one in :mod:`crowdsim.jobs` pool workers). Frames with fewer than
``Tracker.parallel_min_targets`` targets run on one thread.

OpenCV calls made once per target (NCC template matching) release the GIL; they run in
contiguous chunks of targets on a shared thread pool (:func:`in_chunks`), each target's
result written to its own row, so they too are the same for any number of threads.

Every parallel kernel gives each loop iteration (a target pair, a target, a connected
component of the problem) to one thread and sums in a fixed order, so tracks are the same
bit for bit for any number of threads: only the speed changes.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numba

from crowdsim.checks import require_number

_CORES = os.cpu_count() or 1
"""The machine's cores, read once (``os.cpu_count`` took 30 us, and trackers check their
threads every frame)."""


def max_threads() -> int:
    """The most threads a tracker may use: the cores, and at most numba's thread pool."""
    return max(1, min(_CORES, int(numba.config.NUMBA_NUM_THREADS)))


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


_POOL: tuple[int, ThreadPoolExecutor] | None = None  # (pid that made it, pool)
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The process's pool (a forked child makes its own: its parent's threads are gone)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL[0] != os.getpid():
            _POOL = (os.getpid(), ThreadPoolExecutor(max_threads(), thread_name_prefix="tracker"))
        return _POOL[1]


def in_chunks(n: int, work: Callable[[int, int], None], min_per_thread: int = 32) -> None:
    """Call ``work(lo, hi)`` over ``[0, n)`` cut into one contiguous chunk per thread
    (:func:`current_threads`, fewer where a chunk would hold under ``min_per_thread``
    items), on a shared thread pool; in the calling thread when that leaves one chunk.
    ``work`` must release the GIL to gain (OpenCV does) and write only its own items."""
    chunks = max(1, min(current_threads(), n // max(1, min_per_thread)))
    if chunks == 1:
        work(0, n)
        return
    bounds = [n * c // chunks for c in range(chunks + 1)]
    futures = [_pool().submit(work, lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]
    for f in futures:
        f.result()  # re-raises a chunk's exception here
