"""Result files a command may replace: only the ones it can prove it wrote.

``crowdsim tune`` and ``crowdsim heldout`` write a JSON *record* (``best_params.json``,
``heldout.json``) and files beside it (tables, plots) into a folder the user names. A rerun
into the same folder must not replace a user's own ``heldout.md`` or ``history.png``:

* the record is ours when its content says so (``is_ours(doc)``: the keys only we write);
* every other output is ours when its SHA-256 is the one the record lists for it under
  ``"files"`` (this run's) or ``"previous_files"`` (the run before; see below); a record from
  an older crowdsim that lists no files vouches for the outputs beside it.

:func:`write_outputs` renders every output to a temporary file beside its target first, then
writes the record (listing the new digests under ``"files"`` and the digests of the files it
replaces under ``"previous_files"``), and only then renames the outputs into place: a run
killed at any point leaves every file in the folder provably ours, and none half-written.

>>> import json, tempfile, pathlib
>>> out = pathlib.Path(tempfile.mkdtemp())
>>> record = {"kind": "demo"}
>>> ours = lambda doc: doc.get("kind") == "demo"
>>> _ = write_outputs(out, "r.json", record, {"t.md": lambda p: p.write_text("a\\n")})
>>> check_outputs(out, "r.json", ("t.md",), ours, "a demo")  # a rerun may replace them
>>> (out / "t.md").write_text("my notes\\n")
9
>>> try:
...     check_outputs(out, "r.json", ("t.md",), ours, "a demo")
... except ValueError as exc:
...     print(str(exc).replace(str(out), "OUT").split(";")[0])
--out: OUT/t.md exists and was not written by a demo, or was changed since
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from crowdsim.atomic import (
    atomic_path,
    folder_locked,
    note_checked,
    require_unchanged,
    sha256_file,
    signals_held,
    write_text_atomic,
)
from crowdsim.checks import require_output_dir


def _refuse(path: Path, what: str, flag: str) -> ValueError:
    return ValueError(
        f"{flag}: {path} exists and was not written by {what}, or was changed since; "
        "refusing to replace it "
        f"(move it away or choose another {flag})"
    )


def read_record(path: Path, is_ours: Callable[[Any], bool]) -> dict[str, Any] | None:
    """The record at ``path`` if it is ours, ``None`` if there is none; ``ValueError`` from
    :func:`check_outputs` otherwise (a foreign or unreadable file)."""
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    return doc if isinstance(doc, dict) and is_ours(doc) else {}


def check_outputs(
    out: str | os.PathLike[str],
    record: str,
    owned: Sequence[str],
    is_ours: Callable[[Any], bool],
    what: str,
    flag: str = "--out",
    earlier: Callable[[Path], bool] | None = None,
) -> None:
    """Refuse (``ValueError`` naming ``flag`` and the file) to go on when ``out`` holds
    ``record`` or one of ``owned`` that this program cannot prove it wrote (see the module
    docstring); a folder that cannot be made or written (under a regular file, read-only)
    and a folder where a file is expected are refused too. Reads only; what it vouched for
    holds until :func:`write_outputs` (:func:`crowdsim.atomic.note_checked`): a file put at
    one of those paths while the work runs is kept, and the write refused naming it.

    ``earlier(out)``: where there is no record, whether ``out`` is a folder that a release
    from before the record wrote (its own files then vouch for the outputs beside them, as a
    record that lists no files does)."""
    out = require_output_dir(flag, out, writable=True)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{flag} {out}: is a file, not a folder")
    rec_path = out / record
    if rec_path.is_dir():
        raise ValueError(f"{flag}: {rec_path} is a folder, not a file")
    doc = read_record(rec_path, is_ours)
    if doc == {}:
        raise _refuse(rec_path, what, flag)
    listed: dict[str, set[str]] = {}
    for key in ("files", "previous_files"):
        entries = (doc or {}).get(key) or {}
        if not isinstance(entries, dict):  # damaged: it proves nothing
            raise _refuse(rec_path, what, flag)
        for name, digest in entries.items():
            listed.setdefault(name, set()).add(str(digest))
    legacy = (doc is not None and "files" not in doc) or (
        doc is None and earlier is not None and earlier(out)
    )
    for name in owned:
        p = out / name
        if p.is_dir():
            raise ValueError(f"{flag}: {p} is a folder, not a file")
        if not p.exists() or legacy:
            continue
        if doc is None or sha256_file(p) not in listed.get(name, set()):
            raise _refuse(p, what, flag)
    # what was vouched for holds until the write: a file put there meanwhile is kept
    note_checked(rec_path, *(out / name for name in owned))
    _VOUCHED[rec_path.absolute()] = is_ours


_VOUCHED: dict[Path, Callable[[Any], bool]] = {}
"""The records :func:`check_outputs` checked, with the test that they are ours."""


def _take_back_ours(out: Path, record: str, names: Sequence[str]) -> None:
    """Before :func:`write_outputs` commits: outputs that another run of this command wrote
    since :func:`check_outputs` (two ``compare`` runs sharing ``--out``) are ours, when the
    record, ours still, lists their digests now; they may be replaced as the check let this
    run replace its own. Any other file that appeared or changed stays refused (a user's)."""
    path = out / record
    is_ours = _VOUCHED.get(path.absolute())
    doc = read_record(path, is_ours) if is_ours is not None else None
    if not doc or not isinstance(doc.get("files"), dict):
        return
    note_checked(path)
    for name in names:
        p = out / name
        if p.is_file() and doc["files"].get(name) == sha256_file(p):
            note_checked(p)


def claim_folder(
    out: str | os.PathLike[str], record: str, doc: Mapping[str, Any], owned: Sequence[str]
) -> None:
    """Before a long run's first result: write ``record`` (``doc`` plus the digests of the
    ``owned`` outputs already there) when ``out`` has none.

    :func:`check_outputs` has just vouched for those outputs (a folder a release from before
    the record wrote, recognised by ``earlier``); from now on the record does. Without it, a
    run stopped between its first result (``cells.json``, which ``earlier`` looks for) and
    its record would leave a folder that looks like one from before the record, and the
    next run would replace a user's own ``table.md`` unchecked."""
    out = Path(out)
    path = out / record
    if path.exists():
        return
    out.mkdir(parents=True, exist_ok=True)
    files = {name: sha256_file(out / name) for name in owned if (out / name).is_file()}
    write_text_atomic(path, json.dumps({**doc, "files": files}, indent=2) + "\n")


def _still_listed(path: Path, outputs: Mapping[str, object]) -> dict[str, str]:
    """The earlier record's files that this run does not rewrite and that are still there as
    listed (a run over fewer sequences keeps vouching for the curves of the others)."""
    listed = (read_record(path, lambda doc: True) or {}).get("files") or {}
    if not isinstance(listed, dict):
        return {}
    kept = {}
    for name, digest in listed.items():
        p = path.parent / str(name)
        if name not in outputs and p.is_file() and sha256_file(p) == digest:
            kept[name] = digest
    return kept


def write_outputs(
    out: str | os.PathLike[str],
    record: str,
    doc: Mapping[str, Any],
    outputs: Mapping[str, Callable[[Path], object]],
) -> dict[str, Path]:
    """Write ``outputs`` (``name -> writer(temporary path)``) and the JSON ``record`` (``doc``
    plus the outputs' digests, and those of the earlier record's files that this run leaves
    as they were) into ``out``; ``{name: path}`` of everything written.

    Call :func:`check_outputs` first (before any work): this function replaces what is there.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # runs sharing ``out`` write their outputs and record one after the other, each whole
    with folder_locked(out / record):
        return _write_outputs(out, record, doc, outputs)


def _write_outputs(
    out: Path, record: str, doc: Mapping[str, Any], outputs: Mapping[str, Callable[[Path], object]]
) -> dict[str, Path]:
    _take_back_ours(out, record, list(outputs))
    previous = {name: sha256_file(out / name) for name in outputs if (out / name).is_file()}
    files = _still_listed(out / record, outputs)
    with ExitStack() as held, ExitStack() as stack:
        for name, write in outputs.items():
            tmp = stack.enter_context(atomic_path(out / name))
            write(tmp)
            files[name] = sha256_file(tmp)
        full = {**doc, "files": files, "previous_files": previous}
        # from the record to the last rename, a Ctrl-C or SIGTERM waits: the record is
        # never left without the outputs it lists
        held.enter_context(signals_held())
        require_unchanged(*(out / name for name in outputs))  # before the record commits
        write_text_atomic(out / record, json.dumps(full, indent=2) + "\n")
    # leaving the stack renamed every output into place (the record already lists them)
    return {name: out / name for name in (*outputs, record)}
