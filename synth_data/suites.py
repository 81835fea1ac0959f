"""Benchmark suites: folders of spec files, shipped inside the package or anywhere (SPEC §4).

Built-in suites (:data:`SUITE_NAMES`):

* ``ucf9``: ``seq1`` … ``seq9``, counterparts of the papers' nine sequences (frames, people,
  template px and scene type from SPEC §4). Each spec keeps its appearance and noise knobs and
  a ``[calibration]`` table with the papers' figures at 15 px for the calibration step: paper
  1's B(NCC) row (``paper_b_ncc_15px``, the default anchor, static camera) and the NCC
  column (``paper_ncc_15px``).
* ``ucf9-shake``: the same nine sequences as calibrated on the NCC column with every knob
  free (camera shake, sensor noise of sigma 8-22, H.264 down to 226 kbit/s): a shaky-camera variant,
  for trackers that compensate camera motion (its ``README.md``).
* ``ucf9-drone``: ``ucf9``'s specs with the camera's drone profile (slow drift, rotation and
  zoom of the whole view: ``drift_px``, ``rotate_deg``, ``zoom``), for camera-motion
  compensation on footage from a hovering drone (its ``README.md``).
* ``galleria``: ``galleria1``, ``galleria2``: 2000-frame medium-density mall sequences.
* ``stress``: ``stress-1k``, ``stress-10k``, ``stress-50k`` agents.

Their spec files live in ``synth_data/suites/<suite>/<sequence>.toml``.

Suite folders
    Wherever a suite is named (``--suite`` of ``generate``, ``compare``, ``ablation``,
    ``difficulty`` and ``calibrate``), a folder path works as well: every spec file in it
    (:data:`SPEC_PATTERNS`: ``*.toml``, ``*.yaml``, ``*.yml``) is one sequence spec;
    ``paper.json`` beside them, when present, holds the papers' figures the tables print (the
    format of ``ucf9/paper.json``). ``crowdsim calibrate
    --out DIR`` writes such a folder. A built-in name wins over a folder of the same name in
    the working directory: write ``./ucf9`` for the folder.
"""

from __future__ import annotations

import json
import math
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any

from crowdsim.checks import require_sequences
from synth_data.spec import SequenceSpec, load_spec

SPEC_PATTERNS: tuple[str, ...] = ("*.toml", "*.yaml", "*.yml")
"""The spec files of a suite folder (:func:`synth_data.spec.load_spec` reads each kind)."""

SUITE_NAMES: tuple[str, ...] = ("ucf9", "ucf9-shake", "ucf9-drone", "galleria", "stress")
PAPER_FILE = "paper.json"
"""The papers' figures of a suite: ``{table: {column: {sequence: %}}}``, keys starting with
``_`` are comments."""


def is_builtin(suite: str | os.PathLike[str]) -> bool:
    """Whether ``suite`` names a built-in suite (rather than a folder)."""
    return isinstance(suite, str) and suite in SUITE_NAMES


def suite_dir(suite: str | os.PathLike[str]) -> Path:
    """Folder holding the suite's spec files: a built-in suite's, or the folder ``suite``.

    Raises ``ValueError`` naming the value for something that is neither a built-in name nor
    an existing folder (nothing is created).
    """
    if is_builtin(suite):
        return Path(str(resources.files("synth_data") / "suites" / str(suite)))
    if not isinstance(suite, (str, os.PathLike)) or not str(suite):
        raise ValueError(
            f"--suite must be one of {', '.join(SUITE_NAMES)} or a suite folder of spec "
            f"files, got {suite!r}"
        )
    path = Path(suite)
    if not path.exists():
        raise ValueError(
            f"--suite must be one of {', '.join(SUITE_NAMES)} or a suite folder of spec "
            f"files, got {str(suite)!r} (no such folder)"
        )
    if not path.is_dir():
        raise ValueError(f"--suite {suite}: is a file, not a suite folder of spec files")
    return path


def is_spec_suite(suite: object) -> bool:
    """Whether ``suite`` is a suite of specs to render (a built-in name, or a folder of
    ``*.toml`` spec files such as ``crowdsim calibrate --out`` writes) rather than a folder of
    MOT sequences on disk. A spec suite can be re-seeded (other crowds of the same scenes,
    for held-out scoring); a folder of sequences cannot.

    >>> is_spec_suite("ucf9"), is_spec_suite(suite_dir("stress")), is_spec_suite("/nonexistent")
    (True, True, False)
    """
    if str(suite) in SUITE_NAMES:
        return True
    if not isinstance(suite, (str, os.PathLike)) or not str(suite):
        return False
    path = Path(suite)
    try:
        return (
            path.is_dir()
            and not (path / "seqinfo.ini").is_file()
            and any(f.is_file() for pattern in SPEC_PATTERNS for f in path.glob(pattern))
        )
    except OSError:
        return False


def suite_label(suite: str | os.PathLike[str]) -> str:
    """How titles and logs name the suite: the built-in name, or the folder as given."""
    return str(suite)


def _natural_key(path: Path) -> list[object]:
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.stem)]


def suite_files(suite: str | os.PathLike[str]) -> list[Path]:
    """The suite's spec files (:data:`SPEC_PATTERNS`) in natural order; at least one.

    >>> [p.name for p in suite_files("stress")]
    ['stress-1k.toml', 'stress-10k.toml', 'stress-50k.toml']
    """
    folder = suite_dir(suite)
    try:
        files = sorted(
            (p for pattern in SPEC_PATTERNS for p in folder.glob(pattern) if p.is_file()),
            key=_natural_key,
        )
    except OSError as exc:
        raise ValueError(f"--suite {suite}: cannot list the folder ({exc.strerror})") from None
    if not files:
        hint = (
            "; a folder of MOT sequences is for tune and heldout"
            if any((p / "seqinfo.ini").is_file() for p in folder.iterdir() if p.is_dir())
            else ""
        )
        kinds = ", ".join(SPEC_PATTERNS)
        raise ValueError(f"--suite {suite}: no spec files ({kinds}) in {folder}{hint}")
    return files


def suite_specs(suite: str | os.PathLike[str], only: list[str] | None = None) -> list[SequenceSpec]:
    """The validated specs of a suite (a built-in name or a folder) in natural order,
    optionally only some sequence names. Two files naming the same sequence are refused."""
    specs = [load_spec(f) for f in suite_files(suite)]
    seen: dict[str, str] = {}
    for s in specs:
        if s.name in seen:
            raise ValueError(
                f"--suite {suite}: {Path(seen[s.name]).name} and {Path(s.source).name} both "
                f"name the sequence {s.name!r}"
            )
        seen[s.name] = s.source
    if only:
        require_sequences("--only", only, [s.name for s in specs], f"suite {str(suite)!r}")
        specs = [s for s in specs if s.name in only]
    return specs


def paper_numbers(suite: str | os.PathLike[str]) -> dict[str, dict[str, dict[str, float]]]:
    """The papers' figures of a suite (``{table: {column: {sequence: %}}}``), ``{}`` without
    a ``paper.json``. A file that is not such a table is refused naming it and the entry."""
    path = suite_dir(suite) / PAPER_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a papers' figures file (broken JSON: {exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: must be a JSON object of tables, got {type(data).__name__}")
    out: dict[str, dict[str, dict[str, float]]] = {}
    for table, columns in data.items():
        if table.startswith("_"):
            continue
        if not isinstance(columns, dict):
            raise ValueError(f"{path}: table {table!r} must be an object of columns")
        out[table] = {}
        for column, cells in columns.items():
            if not isinstance(cells, dict):
                raise ValueError(f"{path}: {table}.{column} must be an object of sequences")
            for seq, value in cells.items():
                if not _percent(value):
                    raise ValueError(
                        f"{path}: {table}.{column}.{seq} must be a percentage in [0, 100], "
                        f"got {value!r}"
                    )
            out[table][column] = dict(cells)  # as written: 33 prints as 33 in table.csv
    return out


def _percent(value: Any) -> bool:
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and math.isfinite(value)
        and 0 <= value <= 100
    )
