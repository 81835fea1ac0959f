"""Atomic file writes: write to a temporary file beside the target, then rename.

A reader never sees a half-written file, and a crash leaves the previous file (or none)
in place. Files get the usual permissions (``0o666`` less the umask), not ``mkstemp``'s
owner-only ``0o600``.

A file the user names (``crowdsim track --out res.txt``) is replaced only when crowdsim can
prove it wrote it, or when the user says ``--overwrite``: :func:`require_replaceable` checks
before any work, and :func:`record_written` notes each file's SHA-256 after writing it in a
small ledger beside it (:data:`LEDGER`, a hidden JSON file in the same folder). A file that is
not listed there with its present digest (a user's own, or one edited since) is refused.

>>> import tempfile, pathlib
>>> out = pathlib.Path(tempfile.mkdtemp()) / "res.txt"
>>> _ = out.write_text("my notes")  # the user's file
>>> try:
...     require_replaceable("--out", out)
... except ValueError as exc:
...     print(str(exc).replace(str(out), "res.txt"))
--out res.txt: the file exists and crowdsim cannot prove it wrote it; refusing to replace \
it (pass --overwrite to replace it, or choose another path)
>>> _ = write_text_atomic(out, "1,1,10,10")  # with --overwrite: the command writes ...
>>> record_written(out)  # ... and vouches for what it wrote
>>> require_replaceable("--out", out) == out  # so a rerun may replace it
True
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import sys
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any


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
    tmp: Path | None = None
    try:
        # held: a signal between the file's creation and ``tmp`` would leave the file behind
        with signals_held():
            fd, name = tempfile.mkstemp(
                dir=path.parent,
                prefix=f".{path.stem}.",
                suffix=path.suffix if suffix is None else suffix,
            )
            os.close(fd)
            tmp = Path(name)
        yield tmp
        os.chmod(tmp, _MODE)
        _require_unchanged_since_checked(path)
        _replace_noted(tmp, path)
    except OSError as exc:
        raise _retarget(exc, tmp, path) from None
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


_CHECKED: dict[Path, tuple[int, int, int] | None] = {}
"""The outputs :func:`require_replaceable` let this process write, with their state then
(``None``: no file); :func:`atomic_path` replaces one only while it is still so."""


def _require_unchanged_since_checked(path: Path) -> None:
    """Refuse (``FileExistsError`` naming ``path``) to replace a checked output whose file
    appeared or changed since :func:`require_replaceable` allowed it: a file the user put
    there while the work ran is theirs, and is kept."""
    key = path.absolute()
    if not _as_checked(key) and _stamp(key) is not None:  # a file gone leaves none to keep
        raise FileExistsError(  # no errno: the message is whole (describe_os_error)
            f"{path}: a file appeared there (or changed) while crowdsim ran; it is kept and "
            "this output is not written (choose another path, or move that file and run again)"
        )


def _as_checked(path: Path) -> bool:
    """Whether ``path`` is as the check (or this process's last write there) left it, or was
    never checked: a file that is not is not this process's, to replace or to note."""
    key = path.absolute()
    return key not in _CHECKED or _stamp(key) == _CHECKED[key]


def note_checked(*paths: str | os.PathLike[str]) -> None:
    """Note that a check before the work let this process replace ``paths`` as they are now
    (:func:`envs.outputs.check_outputs` does, for a folder's outputs): :func:`atomic_path`
    then refuses to replace one whose file appeared or changed meanwhile."""
    for path in paths:
        key = Path(path).absolute()
        _CHECKED[key] = _stamp(key)


def require_unchanged(*paths: str | os.PathLike[str]) -> None:
    """Refuse (``FileExistsError`` naming the path) when one of ``paths`` was checked and a
    file appeared there or changed since: for a writer that must know before it commits
    (:func:`envs.outputs.write_outputs` writes its record before its renames)."""
    for path in paths:
        _require_unchanged_since_checked(Path(path))


def _replace_noted(tmp: Path, path: Path) -> None:
    """Rename ``tmp`` over ``path``; at a checked output, the file renamed in is the state the
    next write (and :func:`recorded`) takes for this process's. It is noted before the rename
    (a rename keeps the inode, time and size), so a Ctrl-C just after it still finds it ours;
    a rename that did not happen puts the note back."""
    key = path.absolute()
    if key not in _CHECKED:
        os.replace(tmp, path)
        return
    before = _CHECKED[key]
    _CHECKED[key] = _stamp(tmp)
    try:
        os.replace(tmp, path)
    except BaseException:
        if _stamp(key) != _CHECKED[key]:  # not renamed in
            _CHECKED[key] = before
        raise


def _retarget(exc: OSError, tmp: Path | None, path: Path) -> OSError:
    """``exc`` naming the user's ``path`` instead of our hidden temporary file (or nothing).
    An error of our own (no errno: its message names the file already) is left alone."""
    if exc.errno is None:
        return exc
    if exc.filename is not None and (tmp is None or os.fspath(exc.filename) != str(tmp)):
        if tmp is not None or Path(os.fspath(exc.filename)).parent != path.parent:
            return exc
    try:
        return type(exc)(exc.errno, exc.strerror or str(exc), str(path))
    except TypeError:  # pragma: no cover - an OSError subclass with its own constructor
        return exc


def holds_only_leftovers(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder`` holds nothing but files named as :func:`atomic_path`'s temporary
    files are (``.<stem>.<8 random characters><suffix>``): what a command killed mid-write
    leaves. Such a folder counts as empty when a command asks for a new one; the files are
    never deleted (their name proves nothing)."""
    import re

    leftover = re.compile(r"\..+\.[a-z0-9_]{8}(\.[^.]+)?")
    return all(p.is_file() and leftover.fullmatch(p.name) for p in Path(folder).iterdir())


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def require_whole_video(path: str | os.PathLike[str], frames: int, shown: object = None) -> None:
    """Read back a video OpenCV's ``cv2.VideoWriter`` has just released at ``path``: it must
    open and hold ``frames`` frames, or an ``OSError`` names ``shown`` (default ``path``).

    The writer reports no I/O error: on a full disk it leaves a few KB without the MP4's
    index and returns as if all went well, so without this check a broken video would be
    renamed into place. Reading the index back costs about a millisecond."""
    import cv2

    cap = cv2.VideoCapture(os.fspath(path))
    try:
        found = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
    finally:
        cap.release()
    if found != frames:
        raise OSError(
            f"{shown if shown is not None else path}: the video was not written whole (it "
            f"reads back with {found} of {frames} frames); is the disk full?"
        )


def torch_save(obj: object, path: str | os.PathLike[str], shown: object = None) -> None:
    """``torch.save(obj, path)``, its write failures as an ``OSError`` naming ``shown``
    (default ``path``): torch reports a full disk as a ``RuntimeError`` of its zip writer."""
    import torch

    try:
        torch.save(obj, path)
    except RuntimeError as exc:
        first = (str(exc).splitlines() or ["write failed"])[0]
        raise OSError(
            f"{shown if shown is not None else path}: could not be written ({first}); "
            "is the disk full?"
        ) from None


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of the file at ``path``, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def hash_sources(h: Any, packages: Mapping[str, Path], recursive: bool = False) -> None:
    """Feed the hashlib object ``h`` every Python file of ``packages`` (name -> folder), its
    path and its content, in a fixed order; ``recursive`` takes the sub-packages' files too.
    It ties work to the code that did it (the episode cache's keys, a table's cells)."""
    for name, root in packages.items():
        for path in sorted(root.rglob("*.py") if recursive else root.glob("*.py")):
            h.update(f"{name}/{path.relative_to(root).as_posix()}\0".encode())
            h.update(path.read_bytes())


OVERWRITE_HELP: str = (
    "replace the output file(s) even when crowdsim cannot prove it wrote them (files it wrote "
    "itself, unchanged since, are replaced without it)"
)
"""The ``--overwrite`` flag's help, for every command that writes a file the user names."""

LEDGER: str = ".crowdsim-files.json"
"""The hidden ledger, in an output's folder, of the files crowdsim wrote there:
``{"written_by": "crowdsim", "files": {name: sha256}}``."""


def _ledger(folder: Path) -> dict[str, str] | None:
    """The ledger's ``files`` in ``folder`` (``{}`` when there is none); ``None`` when a file
    of that name is there that crowdsim did not write (it is then never replaced)."""
    path = folder / LEDGER
    if not path.exists():
        return {}
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != "crowdsim":
        return None
    files = doc.get("files")
    if not isinstance(files, dict):
        return {}
    return {str(k): str(v) for k, v in files.items()}


def require_replaceable(flag: str, path: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Check, before any work, that the file the user named with ``flag`` may be written:
    it can be written (:func:`crowdsim.checks.require_output_file`), and it is new, or
    crowdsim wrote it (its digest is in the folder's :data:`LEDGER`), or ``overwrite``.
    Raises ``ValueError`` naming ``flag`` and the path otherwise; returns the path.

    Without ``overwrite`` the check holds until the write: :func:`atomic_path` refuses to
    replace the file if one appeared there, or it changed, while the work ran (the user's,
    then, and kept)."""
    from crowdsim.checks import require_output_file

    p = require_output_file(flag, path)
    if overwrite:
        _CHECKED.pop(p.absolute(), None)
        return p
    if not os.path.lexists(p):
        _CHECKED[p.absolute()] = None
        return p
    ledger = _ledger(p.parent)
    if p.is_file():
        listed = (ledger or {}).get(p.name)
        if listed is not None and listed == sha256_file(p):
            _CHECKED[p.absolute()] = _stamp(p)
            return p
    why = "" if ledger is not None else f" ({p.parent / LEDGER} is damaged or not crowdsim's)"
    raise ValueError(
        f"{flag} {p}: the file exists and crowdsim cannot prove it wrote it{why}; refusing to "
        f"replace it (pass --overwrite to replace it, or choose another path)"
    )


def record_written(*paths: str | os.PathLike[str]) -> None:
    """Note, in each folder's :data:`LEDGER`, the digests of ``paths`` that crowdsim has just
    written, so a later run may replace them (:func:`require_replaceable`). Entries of files
    no longer there are dropped. A ledger that cannot be written costs only that proof: one
    line on stderr, and the next run asks for ``--overwrite``.

    The ledger is read, merged and written holding a lock on its folder: runs writing into one
    folder at once (two ``track --out`` into a shared results folder) keep each other's notes."""
    by_folder: dict[Path, list[Path]] = {}
    for path in paths:
        p = Path(path).absolute()
        by_folder.setdefault(p.parent, []).append(p)
    for folder, files in by_folder.items():
        with folder_locked(folder / LEDGER):
            listed = _ledger(folder)
            if listed is None:  # a foreign file has the ledger's name: leave it alone
                print(
                    f"crowdsim: {folder / LEDGER} is damaged or not crowdsim's, so the written "
                    "files are not noted there; a rerun will ask for --overwrite",
                    file=sys.stderr,
                )
                continue
            listed = {name: d for name, d in listed.items() if (folder / name).is_file()}
            listed.update({p.name: sha256_file(p) for p in files if p.is_file()})
            doc = {"written_by": "crowdsim", "files": dict(sorted(listed.items()))}
            try:
                write_text_atomic(folder / LEDGER, json.dumps(doc, indent=1) + "\n")
            except OSError as exc:
                print(
                    f"crowdsim: could not note the written files in {folder / LEDGER} "
                    f"({exc}); a rerun will ask for --overwrite",
                    file=sys.stderr,
                )


@contextmanager
def output_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Make the folder ``path`` (and its parents) for the block's outputs; when the block
    fails and leaves the folder it made empty, remove it again (a failed run leaves nothing
    behind; a folder that was there, or holds a file, is kept)."""
    path = Path(path)
    made = [p for p in (path, *path.parents) if not (p.exists() or p.is_symlink())]
    path.mkdir(parents=True, exist_ok=True)
    try:
        yield path
    except BaseException:
        for p in made:  # the deepest first; stops at the first that is not empty
            try:
                p.rmdir()
            except OSError:
                break
        raise


@contextmanager
def new_study_files(url: str | None) -> Iterator[None]:
    """Open or create an Optuna study in the block: when it fails (a full disk while the
    tables are made), the SQLite files of ``url`` (``sqlite:///path``: the database and its
    journals) that were not there before are removed, so a half-made database of this run
    is never left to be refused as foreign by the next. Other storages are left alone.

    Two runs opening one new SQLite study at once (two ``tune --study`` sharing a file) take
    turns, holding a lock on the database's folder: else both made its tables (one failed on
    the other's, "UNIQUE constraint failed"), and the one that failed removed the database
    the other was using."""
    files: list[Path] = []
    if url is not None and url.startswith("sqlite:///"):
        db = url[len("sqlite:///") :]
        files = [Path(db + end) for end in ("", "-journal", "-wal", "-shm")]
    with folder_locked(files[0] if files else None):
        new = [p for p in files if not os.path.lexists(p)]
        try:
            yield
        except BaseException:
            for p in new:
                try:
                    p.unlink()
                except OSError:
                    pass
            raise


@contextmanager
def folder_locked(path: str | os.PathLike[str] | None) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the folder of ``path`` (its nearest existing one) in the
    block; no file is made for it. Nothing is held for ``None``, where fcntl is missing or
    where the folder cannot be opened. Not reentrant: a second hold of one folder in one
    process waits for ever."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        path = None
    if path is None:
        yield
        return
    folder = next(p for p in Path(path).absolute().parents if p.is_dir())
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # a folder that cannot be read (mode -wx): as before the lock
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a file system without locks (some NFS): as before the lock
            pass
        yield
    finally:
        os.close(fd)  # closing releases the lock


def _study_failure(exc: BaseException) -> str | None:
    """The deepest message of a study storage's failure (Optuna's ``StorageInternalError``
    over SQLAlchemy over ``sqlite3``: "database or disk is full"), or ``None`` when ``exc``
    is not one."""
    chain: list[BaseException] = []
    e: BaseException | None = exc
    while e is not None and e not in chain:
        chain.append(e)
        e = e.__cause__ or e.__context__
    kinds = {(type(x).__module__.split(".")[0], type(x).__name__) for x in chain}
    if not any(mod in ("sqlalchemy", "sqlite3") or name == "StorageInternalError"
               for mod, name in kinds):  # fmt: skip
        return None
    deepest = chain[-1]
    return (str(getattr(deepest, "orig", None) or deepest).splitlines() or [""])[0]


class StudyStorageError(OSError):
    """An Optuna study's storage failed mid-run (:func:`study_storage`)."""


@contextmanager
def study_storage(url: str | None) -> Iterator[None]:
    """Run trials on an Optuna study in the block: a storage that fails mid-run (a full disk,
    a database locked or gone) ends as one :class:`StudyStorageError` (an ``OSError``) naming
    the storage and the cause, not as Optuna's and SQLAlchemy's traceback. The study keeps
    the trials it finished."""
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - only storage failures are turned into OSError
        cause = _study_failure(exc)
        if cause is None:
            raise
        where = url[len("sqlite:///") :] if url and url.startswith("sqlite:///") else url
        raise StudyStorageError(f"{where}: the study storage failed: {cause}") from None


def _stamp(path: Path) -> tuple[int, int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


@contextmanager
def recorded(*paths: str | os.PathLike[str]) -> Iterator[None]:
    """Write (some of) the files ``paths`` in the block; at its end, however it ends, note
    the ones it wrote (:func:`record_written`): each path whose file changed (a new inode,
    size or time; the atomic writers rename a new file into place) or appeared.

    So a Ctrl-C, SIGTERM or error after one output was renamed into place (before the next
    was written) never leaves a file crowdsim wrote but cannot prove it wrote; the outputs
    were checked with :func:`require_replaceable` before the work, so whatever changed there
    is this run's, but for a file that appeared there (or changed) since the check and
    that this run did not write: a user's, never noted. The notes are taken with the
    signals held (:func:`signals_held`).

    A checked output that appeared or changed since the check is refused on entry
    (:func:`require_unchanged`), before any is written: else a second run with other
    settings into the same files (checked while the first rewrote them) replaced the first
    output and was refused at the second, leaving one run's trajectories beside the other's
    plot."""
    files = [Path(p) for p in paths]
    require_unchanged(*files)
    before = [_stamp(p) for p in files]
    try:
        yield
    finally:

        def note() -> None:
            changed = [
                p
                for p, b in zip(files, before, strict=True)
                if _stamp(p) not in (None, b) and _as_checked(p)
            ]
            if changed:
                record_written(*changed)

        try:
            with signals_held():
                note()
        except KeyboardInterrupt:  # landed before the signals were held: note them all the same
            with signals_held():
                note()
            raise


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back until the block ends, then deliver them.

    Python runs signal handlers in the main thread only (elsewhere nothing can interrupt the
    block), and a signal mask would hold them in this thread alone (another thread, such as
    a progress bar's, would take the signal): so the handlers themselves are swapped for one
    that notes the signal, which is sent again, to the handler it was meant for, at the end.
    SIGKILL cannot be held."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    held = [s for s, handler in before.items() if handler is not None]  # None: not from Python

    def note(signum: int, frame: object) -> None:
        caught.append(signum)

    try:
        for s in held:
            signal.signal(s, note)
    except KeyboardInterrupt as exc:  # one landed while they were swapped: held as well
        name = getattr(exc, "signal_name", "SIGINT")
        caught.append(getattr(signal.Signals, name, signal.SIGINT))
        for s in held:
            signal.signal(s, note)
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, before[s])
        if caught:
            os.kill(os.getpid(), caught[0])


def _first_file_ancestor(path: Path) -> Path | None:
    """The nearest of ``path`` and its ancestors that exists and is not a folder, if any."""
    for p in (path, *path.parents):
        try:
            if p.exists() or p.is_symlink():
                return None if p.is_dir() else p
        except OSError:  # pragma: no cover - unreadable ancestor
            return None
    return None


_CAUSES: dict[int, str] = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOENT: "no such file or folder",
    errno.EISDIR: "is a folder, not a file",
    errno.ENAMETOOLONG: "file name too long",
    errno.ELOOP: "too many levels of symbolic links",
    errno.EMFILE: "too many open files",
    errno.EFBIG: "file too large",
    errno.EIO: "input/output error",
}


def describe_os_error(exc: OSError) -> str:
    """One line naming the path and the cause of a failed file operation.

    ``NotADirectoryError`` and ``FileExistsError`` on a path under a regular file read
    ``"<path>: <parent> is a file, not a folder"``; errors raised by our own code with a full
    message (no errno) are passed through.
    """
    if exc.errno is None or exc.filename is None or isinstance(exc.filename, int):
        text = exc.strerror if exc.errno is not None and exc.strerror else str(exc)
        return (
            text
            if exc.filename is None or isinstance(exc.filename, int)
            else f"{os.fsdecode(exc.filename)}: {text}"
        )
    name = os.fsdecode(exc.filename)
    path = Path(name)
    code = exc.errno
    if code in (errno.ENOTDIR, errno.EEXIST):
        blocker = _first_file_ancestor(path)
        if blocker is not None and blocker != path:
            return f"{name}: {blocker} is a file, not a folder"
        if blocker == path:
            return f"{name}: is a file, not a folder"
        if code == errno.EEXIST:
            return f"{name}: already exists"
        return f"{name}: not a folder"
    if code == errno.EXDEV and exc.filename2 is not None:
        return f"{name}: cannot move to {os.fsdecode(exc.filename2)} (another file system)"
    cause = _CAUSES.get(code) or (exc.strerror or str(exc)).lower()
    if code in (errno.EACCES, errno.EPERM, errno.EROFS) and not path.exists():
        cause += f" (cannot create files in {path.parent})"
    return f"{name}: {cause}"
