"""Atomic file writes: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and a crash leaves the previous file (or none)
in place. Files get the usual permissions (``0o666`` less the umask), not ``mkstemp``'s
owner-only ``0o600``.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()


@contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on normal exit rename it over ``path``.

    ``suffix`` defaults to ``path``'s own, so writers that choose a format by extension
    (numpy, matplotlib, OpenCV) still work. On an exception the temporary file is removed.

    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("done")
    >>> target.read_text()
    'done'
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, name = tempfile.mkstemp(
            dir=path.parent,
            prefix=f".{path.stem}.",
            suffix=path.suffix if suffix is None else suffix,
        )
    except OSError as exc:
        raise _retarget(exc, None, path) from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, _MODE)
        os.replace(tmp, path)
    except OSError as exc:
        raise _retarget(exc, tmp, path) from None
    finally:
        tmp.unlink(missing_ok=True)


def _retarget(exc: OSError, tmp: Path | None, path: Path) -> OSError:
    """``exc`` naming the user's ``path`` instead of our hidden temporary file (or nothing)."""
    if exc.filename is not None and (tmp is None or os.fspath(exc.filename) != str(tmp)):
        if tmp is not None or Path(os.fspath(exc.filename)).parent != path.parent:
            return exc
    try:
        return type(exc)(exc.errno, exc.strerror or str(exc), str(path))
    except TypeError:  # pragma: no cover - an OSError subclass with its own constructor
        return exc


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)
