"""One progress bar for every long job (tqdm, with rate and ETA).

On a terminal the bar redraws in place; when output goes to a file or a pipe
(``make demo > log``, CI) it is silent instead of writing thousands of redraws.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool = True,
    leave: bool = False,
) -> Any:
    """A tqdm bar on ``iterable`` (or a manual one with ``total``); off when not a terminal.

    ``enabled=False`` turns it off everywhere; otherwise tqdm's ``disable=None`` turns it off
    when the output stream is not a TTY.
    """
    from tqdm import tqdm

    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        leave=leave,
        disable=None if enabled else True,
        mininterval=0.2,
        dynamic_ncols=True,
    )
