"""Validation of numeric parameters with errors that name the field and the value.

>>> require_number("SocialForceParams", "tau", 0.5, lo=0, lo_open=True)
>>> require_number("SocialForceParams", "tau", float("nan"), lo=0, lo_open=True)
Traceback (most recent call last):
...
ValueError: SocialForceParams.tau must be a finite number > 0, got nan
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np


def _bound(x: float) -> str:
    """A bound as people write it: whole numbers in full (1000000, not 1e+06), else ``:g``."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _rule(integer: bool, lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    kind = "an integer" if integer else "a finite number"
    if lo is not None and hi is not None:
        lo_s, hi_s = _bound(lo), _bound(hi)
        return f"{kind} in {'(' if lo_open else '['}{lo_s}, {hi_s}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{kind} {'>' if lo_open else '>='} {_bound(lo)}"
    if hi is not None:
        return f"{kind} {'<' if hi_open else '<='} {_bound(hi)}"
    return kind


def require_number(
    owner: str,
    name: str,
    value: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    integer: bool = False,
) -> None:
    """Raise ``ValueError("<owner>.<name> must be ..., got <value>")`` unless ``value`` is a
    finite real number (a whole one if ``integer``) within the given bounds."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )
    ok = number and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value < hi if hi_open else value <= hi
    if not ok:
        where = f"{owner}.{name}" if owner else name
        raise ValueError(
            f"{where} must be {_rule(integer, lo, hi, lo_open, hi_open)}, got {value!r}"
        )


def whole_numbers(values: Any) -> bool:
    """Whether ``values`` are integers, or finite floats with no fractional part (ids and
    indices given as ``2.0``), never booleans or text.

    >>> whole_numbers([1, 2]), whole_numbers([1.0, 2.0]), whole_numbers([1.5]), whole_numbers(["1"])
    (True, True, False, False)
    """
    v = np.asarray(values)
    if v.dtype.kind in "iu":
        return True
    return v.dtype.kind == "f" and bool(np.isfinite(v).all() and (v == np.round(v)).all())


def checked_ids(name: str, ids: Any) -> np.ndarray:
    """``ids`` as ``(N,)`` int64: a 1-D array of distinct whole numbers within int64, else a
    ``ValueError`` naming ``name`` and the first bad value (truncating id 1.7 to 1, or
    wrapping 1e30, would merge two people's tracks and change every score).

    >>> checked_ids("tr_ids", [1, 2.0]).tolist()
    [1, 2]
    >>> checked_ids("tr_ids", [1.2, 1.7])
    Traceback (most recent call last):
    ...
    ValueError: tr_ids: 1.2 is not a whole number within int64
    """
    raw = np.asarray(ids)
    if raw.size == 0:
        return np.zeros(0, np.int64)
    if raw.ndim != 1 or raw.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a 1-D array of integers, got {raw.dtype} {raw.shape}")
    if raw.dtype.kind in "uf":
        values = raw.astype(np.float64)
        bad = ~np.isfinite(values) | (values != np.round(values)) | (np.abs(values) >= 2.0**63)
        if raw.dtype.kind == "u":
            bad = raw > np.iinfo(np.int64).max
        if bad.any():
            v = raw[np.flatnonzero(bad)[0]]
            raise ValueError(f"{name}: {v.item()!r} is not a whole number within int64")
    out = raw.astype(np.int64)
    values, counts = np.unique(out, return_counts=True)
    if (counts > 1).any():  # one column of points per id: a twice-listed id is two tracks
        raise ValueError(f"{name}: id {values[counts > 1][0].item()!r} appears more than once")
    return out


def path_arg(text: str) -> Path:
    """``type=`` of an argparse flag that names a file or folder: the ``Path``, refusing an
    empty one (``--out ''`` would quietly mean the working folder)."""
    import argparse

    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a file or folder, got {text!r}")
    return Path(text)


def checked_seed(seed: Any) -> int | None:
    """A ``reset`` seed as gymnasium takes it (a Python int, or ``None``): any whole number
    >= 0, numpy's included; a ``ValueError`` naming ``seed`` otherwise (gymnasium's own
    error would not, and it refuses numpy integers)."""
    if seed is None:
        return None
    require_number("reset", "seed", seed, lo=0, integer=True)
    return int(seed)


def require_cpus(flag: str, values: Any, lo: int = 1) -> None:
    """Raise ``ValueError("<flag> must be in [lo, cpus] (os.cpu_count()), got <first bad>")``
    unless every count of ``values`` (an int or a sequence of them) is within the cores.

    >>> require_cpus("--workers", [1, 10**6])
    Traceback (most recent call last):
    ...
    ValueError: --workers must be in [1, ...] (os.cpu_count()), got 1000000
    """
    cpus = os.cpu_count() or 1
    bad = [v for v in np.atleast_1d(values).tolist() if not lo <= v <= cpus]
    if bad:
        raise ValueError(f"{flag} must be in [{lo}, {cpus}] (os.cpu_count()), got {bad[0]}")


MAX_RAY_WORKERS: int = 256
"""Most concurrent Ray tasks one command starts (a cluster's cores are not known here)."""


def require_workers(flag: str, workers: Any, backend: str = "local") -> int:
    """``workers`` as an int: local processes within the cores (:func:`require_cpus`: more
    only queue for them, each holding its own interpreter's memory), Ray tasks in ``[1,``
    :data:`MAX_RAY_WORKERS` ``]``; a ``ValueError`` naming ``flag`` else.

    >>> require_workers("--workers", 10**6, "ray")
    Traceback (most recent call last):
    ...
    ValueError: --workers must be an integer in [1, 256], got 1000000
    """
    require_number("", flag, workers, lo=1, hi=MAX_RAY_WORKERS, integer=True)
    if backend == "local":
        require_cpus(flag, workers)
    return int(workers)


def require_choice(owner: str, name: str, value: Any, choices: tuple[Any, ...]) -> None:
    """Raise ``ValueError`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        where = f"{owner}.{name}" if owner else name
        raise ValueError(f"{where} must be one of {choices}, got {value!r}")


def require_sequences(flag: str, wanted: Any, known: list[str], where: str) -> None:
    """Raise ``ValueError`` naming ``flag``, the first of ``wanted`` that is not one of the
    ``known`` sequence names, ``where`` they were looked for and the names to choose from
    (``--only`` of a suite or a folder, ``--heldout-only``).

    >>> require_sequences("--only", ["seq2", "seq9"], ["seq1", "seq2"], "suite 'mine'")
    Traceback (most recent call last):
    ...
    ValueError: --only: no sequence 'seq9' in suite 'mine'; choose from seq1, seq2
    """
    unknown = [o for o in wanted if o not in known]
    if unknown:
        raise ValueError(
            f"{flag}: no sequence {unknown[0]!r} in {where}; choose from {', '.join(known)}"
        )


MEMORY_LIMIT_BYTES: int = 12 * 2**30
"""Largest working set (bytes) one command may plan to allocate: half of a 24 GiB machine.

Requests whose estimate exceeds it are refused *before* allocating, with the estimate in the
message, instead of dying halfway with a ``MemoryError`` or the kernel's OOM killer."""


class DataNote(UserWarning):
    """A warning about the user's data that does not stop the work (a video whose header
    counts other frames than it holds, ...): library code warns with it, and the ``crowdsim``
    command prints it as one line ``crowdsim <command>: note: <message>``."""


def note_line(command: str, message: object) -> str:
    """The one line a note takes on stderr: ``crowdsim <command>: note: <message>``."""
    return f"crowdsim {command}: note: {message}"


def format_bytes(n: float) -> str:
    """``1536 -> '1.5 KiB'``, ``3 * 2**30 -> '3.0 GiB'`` (binary units).

    >>> format_bytes(3 * 2**30)
    '3.0 GiB'
    >>> format_bytes(12)
    '12 B'
    """
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")  # pragma: no cover


def require_memory(what: str, nbytes: float, limit: float = MEMORY_LIMIT_BYTES) -> None:
    """Raise ``ValueError("<what> needs about <estimate> of memory, more than ...")`` when the
    estimated working set ``nbytes`` of a request exceeds ``limit``.

    >>> require_memory("a (2000000000, 1, 2) float64 array", 32e9)
    Traceback (most recent call last):
    ...
    ValueError: a (2000000000, 1, 2) float64 array needs about 29.8 GiB of memory, more than \
the 12.0 GiB limit
    """
    if not nbytes <= limit:  # also refuses NaN
        raise ValueError(
            f"{what} needs about {format_bytes(nbytes)} of memory, more than the "
            f"{format_bytes(limit)} limit"
        )


def require_output_file(flag: str, path: str | os.PathLike[str]) -> Path:
    """Check, before any work, that a file can be written at ``path``; returns it as a Path.

    Raises ``ValueError`` naming ``flag`` and the path when ``path`` is a folder, when one of
    its ancestors is a regular file (``"--out a/b.npz: a is a file, not a folder"``) or when
    the nearest existing ancestor folder is not writable. The write itself may still fail
    (a full disk); callers write atomically so that no partial file remains.
    """
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{flag} {p}: is a folder, not a file")
    return require_output_dir(flag, p)


def require_output_dir(flag: str, path: str | os.PathLike[str], writable: bool = False) -> Path:
    """Like :func:`require_output_file` for a folder to be created at ``path``: refuses an
    ancestor that is a regular file (``"--out a/seq: a is a file, not a folder"``) and an
    unwritable nearest existing ancestor. ``path`` itself may exist (callers decide); with
    ``writable``, a folder already there must be writable (``"--out X: the folder is not
    writable"``), so a read-only one is refused before any work."""
    p = Path(path)
    if writable and p.is_dir() and not os.access(p, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {p}: the folder is not writable")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{flag} {p}: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise ValueError(f"{flag} {p}: the folder {parent} is not writable")
            break
    return p


def require_apart(
    flag: str,
    path: str | os.PathLike[str],
    inputs: dict[str, str | os.PathLike[str] | None],
) -> None:
    """Refuse an output ``path`` that is one of the ``inputs`` (``{name: path}``, ``None``
    skipped) or lies inside one that is a folder: ``--overwrite`` never lets a command replace
    what it reads.

    >>> import tempfile, pathlib
    >>> seq = pathlib.Path(tempfile.mkdtemp())
    >>> try:
    ...     require_apart("--plot", seq / "gt" / "a.png", {"SEQUENCE": seq})
    ... except ValueError as exc:
    ...     print(str(exc).replace(str(seq), "seq"))
    --plot seq/gt/a.png would overwrite or sit inside the input SEQUENCE seq; choose another \
path
    """
    out = Path(path).resolve()
    for name, given in inputs.items():
        if given is None:
            continue
        inp = Path(given).resolve()
        if out == inp or inp in out.parents:
            raise ValueError(
                f"{flag} {path} would overwrite or sit inside the input {name} {given}; "
                "choose another path"
            )


PATH_FLAGS: tuple[str, ...] = (
    "out", "plot", "video", "json_out", "save_npz", "init", "params", "policy", "study",
    "episode_cache", "weights", "detector_weights", "from_npz", "sequence", "suite",
)  # fmt: skip
"""Flags that name a file or folder: an empty one (``--out ''``) would quietly mean the
working folder, so it is refused, naming the flag."""


def refuse_empty_paths(args: Any) -> None:
    """Refuse (``ValueError`` naming the flag) an empty value of any of :data:`PATH_FLAGS`
    in parsed arguments ``args``; the ``crowdsim`` command and ``crowdsim bench`` call it
    before running a command."""
    for dest in PATH_FLAGS:
        value = getattr(args, dest, None)
        if isinstance(value, str) and not value.strip():
            flag = "--" + dest.replace("_", "-")
            raise ValueError(f"{flag} must name a file or folder, got {value!r}")
