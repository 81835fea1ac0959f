"""Validation of numeric parameters with errors that name the field and the value.

>>> require_number("SocialForceParams", "tau", 0.5, lo=0, lo_open=True)
>>> require_number("SocialForceParams", "tau", float("nan"), lo=0, lo_open=True)
Traceback (most recent call last):
...
ValueError: SocialForceParams.tau must be a finite number > 0, got nan
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _rule(integer: bool, lo: float | None, hi: float | None, lo_open: bool,
          hi_open: bool) -> str:
    kind = "an integer" if integer else "a finite number"
    if lo is not None and hi is not None:
        return f"{kind} in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{kind} {'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{kind} {'<' if hi_open else '<='} {hi:g}"
    return kind


def require_number(owner: str, name: str, value: Any, *, lo: float | None = None,
                   hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
                   integer: bool = False) -> None:
    """Raise ``ValueError("<owner>.<name> must be ..., got <value>")`` unless ``value`` is a
    finite real number (a whole one if ``integer``) within the given bounds."""
    number = (isinstance(value, (int, float, np.integer, np.floating))
              and not isinstance(value, (bool, np.bool_)))
    ok = number and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value < hi if hi_open else value <= hi
    if not ok:
        where = f"{owner}.{name}" if owner else name
        raise ValueError(f"{where} must be {_rule(integer, lo, hi, lo_open, hi_open)}, "
                         f"got {value!r}")


def require_choice(owner: str, name: str, value: Any, choices: tuple[Any, ...]) -> None:
    """Raise ``ValueError`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        where = f"{owner}.{name}" if owner else name
        raise ValueError(f"{where} must be one of {choices}, got {value!r}")
