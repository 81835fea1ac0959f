"""One progress bar for every long job (tqdm, with rate and ETA).

On a terminal the bar redraws in place. When the output goes to a file or a pipe
(``make demo > log``, CI, ``nohup``) it does not write thousands of redraws: a bar that has
run for :data:`LOG_EVERY_S` seconds writes one line of its state (count, rate, ETA) every
:data:`LOG_EVERY_S` seconds, and a shorter job writes nothing.

A bar also redraws while nothing advances (every :data:`TICK_S` seconds on a terminal,
every :data:`LOG_EVERY_S` in a log): a first run compiles its numba kernels for half a
minute before the first step ends, and a bar frozen at 0 looked like a hang.
"""

from __future__ import annotations

import sys
import threading
import time
import weakref
from collections.abc import Iterable
from typing import Any, TextIO

LOG_EVERY_S = 30.0
"""Seconds between the state lines of a bar whose output is not a terminal."""
TICK_S = 1.0
"""Seconds after which a bar on a terminal that did not advance redraws (its clock)."""


class _StateLines:
    """A stream for tqdm that keeps each redraw as one line, from ``every`` seconds on."""

    def __init__(self, stream: TextIO, every: float) -> None:
        self.stream = stream
        self.every = every
        self.start = self.last = time.monotonic()

    def write(self, text: str) -> None:
        line = text.strip("\r\n ")
        now = time.monotonic()
        # at most one line per `every` seconds, whatever redraws (a postfix, a tick) ask for
        if line and now - self.last >= self.every:
            self.stream.write(line + "\n")
            self.stream.flush()
            self.last = now

    def flush(self) -> None:
        self.stream.flush()


def _is_terminal(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool = True,
    leave: bool = False,
) -> Any:
    """A tqdm bar on ``iterable`` (or a manual one with ``total``) on stderr.

    ``enabled=False`` turns it off everywhere. Otherwise it redraws on a terminal, and when
    stderr is not one it writes a line of its state every :data:`LOG_EVERY_S` seconds once
    it has run that long (module docstring).
    """
    from tqdm import tqdm

    if not enabled:
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=True)
    if _is_terminal(sys.stderr):
        bar = tqdm(
            iterable,
            total=total,
            desc=desc,
            unit=unit,
            leave=leave,
            mininterval=0.2,
            dynamic_ncols=True,
        )
        return _keep_ticking(bar, TICK_S)
    bar = tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=False,
        file=_StateLines(sys.stderr, LOG_EVERY_S),
        mininterval=LOG_EVERY_S,
        ncols=80,
    )
    return _keep_ticking(bar, LOG_EVERY_S)


def _keep_ticking(bar: Any, every: float) -> Any:
    """Redraw ``bar`` whenever it has not drawn for ``every`` seconds, until it closes (a
    daemon thread holding only a weak reference; tqdm's lock keeps the redraws whole)."""
    ref = weakref.ref(bar)

    def tick() -> None:
        while True:
            time.sleep(min(every, 1.0))
            b = ref()
            if b is None or b.disable:  # closed (tqdm disables a bar when it closes)
                return
            with b._lock:  # close() disables the bar before it takes the lock to clear it
                if b.disable:
                    return
                if b._time() - b.last_print_t >= every:
                    b.refresh(nolock=True)
            del b

    threading.Thread(target=tick, name="progress-tick", daemon=True).start()
    return bar
