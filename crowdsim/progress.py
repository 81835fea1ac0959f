"""One progress bar for every long job (tqdm, with rate and ETA).

On a terminal the bar redraws in place. When the output goes to a file or a pipe
(``make demo > log``, CI, ``nohup``) it does not write thousands of redraws: a bar that has
run for :data:`LOG_EVERY_S` seconds writes one line of its state (count, rate, ETA) every
:data:`LOG_EVERY_S` seconds, and a shorter job writes nothing.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from typing import Any, TextIO

LOG_EVERY_S = 30.0
"""Seconds between the state lines of a bar whose output is not a terminal."""


class _StateLines:
    """A stream for tqdm that keeps each redraw as one line, from ``every`` seconds on."""

    def __init__(self, stream: TextIO, every: float) -> None:
        self.stream = stream
        self.every = every
        self.start = time.monotonic()

    def write(self, text: str) -> None:
        line = text.strip("\r\n ")
        if line and time.monotonic() - self.start >= self.every:
            self.stream.write(line + "\n")
            self.stream.flush()

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
        return tqdm(
            iterable,
            total=total,
            desc=desc,
            unit=unit,
            leave=leave,
            mininterval=0.2,
            dynamic_ncols=True,
        )
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=False,
        file=_StateLines(sys.stderr, LOG_EVERY_S),
        mininterval=LOG_EVERY_S,
        ncols=80,
    )
