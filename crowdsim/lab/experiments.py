"""The papers' tables on a suite: tracker comparison and term ablation, resumable and parallel.

:func:`run_table` runs rows over every sequence of a suite: ``crowdsim compare`` the rows of
:data:`COMPARE_ROWS` (NCC, mean-shift, PNMC, BQP with KCF and with NCC appearance, ByteTrack and
OC-SORT at two simulated detector miss rates and on the trained head detector), ``crowdsim
ablation`` paper 1's Table 3 rows
(:func:`ablation_rows`, from :mod:`tracker.bqp.ablation`). Both:

1. generate the suite's sequences into ``OUT/sequences`` (:func:`synth_data.generate.generate`,
   resumable, checksummed; ``frames`` truncates every spec) -- or, with ``sequences``
   (``--sequences DIR``), read the user's own MOT sequence folders where they are, never
   writing into them (:func:`user_sequences`; no papers' figures for those);
2. run one *cell* (row x sequence) per job on :func:`crowdsim.jobs.run_jobs` (local pool or
   Ray), recording each finished cell in ``OUT/cells.json`` -- a killed run loses no finished
   cell and a rerun resumes. Each cell is stored with a SHA-256 of its key and figures
   (:func:`seal_cell`): a cell edited by hand or damaged is refused, naming it, before any work
   (:func:`read_cells`), so a table never prints a figure no tracker measured. A cell also
   holds the digest of the code that measured it (:func:`code_digest`); the table says how
   many of its cells an earlier run measured with other code (a resume across releases);
3. write ``table.md`` and ``table.csv`` (our figures beside the papers' where they report
   one), one accuracy-versus-threshold PNG per sequence, and return the table text. The
   files' digests go to ``OUT/outputs.json`` (:data:`OUTPUTS_FILE`), and a run refuses,
   before any work, to replace a file of those names that it cannot prove a table run wrote.

A cell tracks with :func:`tracker.runner.run_tracker` and scores with every metric
(acc@15, acc@5, MOTA, IDF1, HOTA) plus frames/s.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from synth_data.detections import DetectionParams
from tracker.detect.inference import DetectorParams


@dataclass(frozen=True)
class Row:
    """One method of a table: a registered tracker with parameter overrides.

    ``overrides`` are the tracker's own parameters. ``detections`` is the detector that feeds
    a tracking-by-detection tracker: simulated from the ground truth (``DetectionParams``,
    :func:`synth_data.detections.attach_detections`) or the trained head detector run on the
    frames (``DetectorParams``, :class:`tracker.detect.HeadDetector`: what a user gets on
    footage). Detection settings belong to the source, not to the tracker; ``None`` for
    trackers that take no detections (a detection tracker then gets ``DetectionParams()``).
    ``paper`` names the column of the papers' tables it corresponds to (``None``: none).
    """

    label: str
    tracker: str
    overrides: dict[str, Any] = field(default_factory=dict)
    paper: str | None = None
    detections: DetectionParams | DetectorParams | None = None


COMPARE_ROWS: tuple[Row, ...] = (
    Row("NCC", "ncc", paper="NCC"),
    Row("mean-shift", "meanshift", paper="MS"),
    Row("PNMC", "pnmc", paper="PNMC"),
    Row("BQP (KCF)", "bqp", paper="BQP"),
    Row("BQP (NCC)", "bqp-ncc"),
    Row("ByteTrack miss 0.1", "bytetrack", detections=DetectionParams(miss_rate=0.1)),
    Row("ByteTrack miss 0.3", "bytetrack", detections=DetectionParams(miss_rate=0.3)),
    Row("OC-SORT miss 0.1", "ocsort", detections=DetectionParams(miss_rate=0.1)),
    Row("OC-SORT miss 0.3", "ocsort", detections=DetectionParams(miss_rate=0.3)),
    Row("ByteTrack (head detector)", "bytetrack", detections=DetectorParams()),
    Row("OC-SORT (head detector)", "ocsort", detections=DetectorParams()),
)
"""Rows of ``crowdsim compare``: the papers' methods we have, and detection-based references."""
ELEVEN: frozenset[str] = frozenset({"NCC", "MS"})
"""Paper columns that come from reference [11]'s implementations, not from the papers' own."""
ELEVEN_NOTE = (
    "The NCC and MS figures in brackets are [11]'s implementations, as both papers report "
    "them (paper 1 puts its own template baseline, B(NCC), about 30 points higher); our NCC "
    "and mean-shift trackers are independent implementations."
)

NO_PAPER_NOTE = (
    "No figures in brackets: these are your own sequences (--sequences), on which the papers "
    "report nothing; every figure here is ours."
)
"""The note of a table on the user's sequences, in place of the papers' one."""

METRICS: tuple[tuple[str, str, str], ...] = (
    ("acc@15", "acc@15", "%"),
    ("acc@5", "acc@5", "%"),
    ("mota", "MOTA", "%"),
    ("idf1", "IDF1", "%"),
    ("hota", "HOTA", "%"),
    ("fps", "frames/s", ""),
)
"""``(key, heading, unit)`` of every table section."""


def with_params(
    rows: Sequence[Row], params: dict[str, Any], flag: str = "--set"
) -> tuple[Row, ...]:
    """``rows`` with ``params`` added to the overrides of every row whose tracker has them:
    ``compare --set fw_variant=block`` runs both BQP rows with the block solver and leaves the
    other rows alone. A name no row's tracker has, or one a row sets itself (the table's
    design: the ablation's term weights, a ``+ CMC`` row's ``cmc``), is refused by name. A
    cell's key holds every parameter, so cells run with other settings are never reused.

    >>> rows = with_params(COMPARE_ROWS, {"fw_variant": "block"})
    >>> sorted({r.label for r in rows if r.overrides.get("fw_variant") == "block"})
    ['BQP (KCF)', 'BQP (NCC)']
    """
    from tracker.registry import get

    def has(row: Row, name: str) -> bool:
        return name in get(row.tracker).field_names()

    for name in params:
        having = [r for r in rows if has(r, name)]
        if not having:
            trackers = ", ".join(sorted({r.tracker for r in rows}))
            raise ValueError(f"{flag} {name}: no row's tracker has that parameter ({trackers})")
        own = [r.label for r in having if name in r.overrides]
        if own:
            raise ValueError(f"{flag} {name}: row {own[0]!r} sets {name} itself")
    return tuple(
        replace(r, overrides={**r.overrides, **{k: v for k, v in params.items() if has(r, k)}})
        for r in rows
    )


def with_cmc(rows: Sequence[Row]) -> tuple[Row, ...]:
    """``rows``, each followed by the same row with camera-motion compensation on
    (``<label> + CMC``, ``cmc=True``) where its tracker has the parameter (the detection-free
    trackers; the detection-based references have no camera to compensate)."""
    from tracker.registry import get

    out: list[Row] = []
    for row in rows:
        out.append(row)
        if "cmc" in get(row.tracker).field_names():
            out.append(
                Row(
                    f"{row.label} + CMC",
                    row.tracker,
                    {**row.overrides, "cmc": True},
                    detections=row.detections,
                )
            )
    return tuple(out)


def ablation_rows() -> tuple[Row, ...]:
    """Paper 1's Table 3: every term combination with NCC and with KCF appearance."""
    from tracker.bqp.ablation import ablation_rows as rows

    return tuple(Row(label, "bqp", over, paper=label) for label, over in rows())


def paper_numbers(suite: Any) -> dict[str, dict[str, dict[str, float]]]:
    """The papers' figures for ``suite`` (``{table: {column: {sequence: %}}}``): its
    ``paper.json`` (:func:`synth_data.suites.paper_numbers`), ``{}`` without one or for a
    list of specs."""
    from synth_data.suites import paper_numbers as numbers

    if not isinstance(suite, (str, os.PathLike)):
        return {}
    return numbers(suite)


_WARMED: set[str] = set()
"""Trackers (with their overrides) this process has run once: their kernels are compiled."""


def run_cell(
    seq_dir: str,
    tracker: str,
    overrides: dict[str, Any],
    frames: int | None,
    detections: DetectionParams | DetectorParams | None = None,
) -> dict[str, Any]:
    """Track one sequence with one row; JSON-ready figures and the accuracy curve.

    ``detections``: the detector of a tracking-by-detection row (:class:`Row`). The first
    cell of a detection-free tracker in a process tracks a few frames first, untimed, so
    that its frames/s never counts the kernels' compilation.
    """
    from synth_data.detections import attach_detections
    from synth_data.sequence import open_sequence
    from tracker.registry import make_tracker
    from tracker.runner import run_tracker

    def prepare(trk: Any, source: Any) -> None:
        if isinstance(detections, DetectorParams):
            if hasattr(trk, "use_detections"):
                from tracker.detect import HeadDetector

                trk.use_detections(HeadDetector(detections, template_size=source.template_size))
        else:
            attach_detections(trk, source, detections)

    source = open_sequence(seq_dir)
    key = json.dumps([tracker, overrides], sort_keys=True, default=str)
    if key not in _WARMED and not takes_detections(tracker):
        # a first run compiles the numba kernels (about 30 s on a fresh clone), which the
        # cell's frames/s must not count: a few frames of the same sequence compile them
        run_tracker(
            make_tracker(tracker, **overrides), source, frames=min(3, source.length), metrics="none"
        )
        _WARMED.add(key)
    run = run_tracker(make_tracker(tracker, **overrides), source, frames=frames, prepare=prepare)
    out = run.summary()
    out["curve"] = [c["acc"] for c in run.report.get("curve", [])]
    return out


CELLS_FILE = "cells.json"
"""The manifest of finished cells in a table's output folder (section ``cells``)."""
OUTPUTS_FILE = "outputs.json"
"""The record of the tables, CSVs and plots a table run wrote into its output folder, with
their digests (:mod:`envs.outputs`): a rerun replaces only files it can prove it wrote, never
a user's own ``table.md``."""
_WRITER = "crowdsim tables"


def _ours(doc: Any) -> bool:
    return doc.get("written_by") == _WRITER


def check_table_outputs(out: Path, names: Sequence[str]) -> None:
    """Refuse (``ValueError`` naming ``--out`` and the file) to run a table into ``out`` when
    one of the output files ``names`` is there and this program cannot prove it wrote it.
    A folder from before :data:`OUTPUTS_FILE` (a ``cells.json`` and no record) vouches for
    the outputs beside its cells."""
    from envs.outputs import check_outputs

    what = "a crowdsim table run (compare, ablation or difficulty)"
    check_outputs(out, OUTPUTS_FILE, names, _ours, what, earlier=_has_cells)


def _has_cells(folder: Path) -> bool:
    return (folder / CELLS_FILE).is_file()


CHECKSUM = "sha256"
"""The field of a stored cell holding :func:`cell_checksum`."""

CODE = "code"
"""The field of a stored cell holding the :func:`code_digest` of the run that measured it."""


def code_roots() -> dict[str, Path]:
    """The packages a cell's figures come from, name -> folder: the trackers and their
    metrics, and how a cell runs and scores them (the frames are the sequence's, keyed by its
    spec)."""
    import tracker

    return {"tracker": Path(tracker.__file__).parent, "crowdsim.lab": Path(__file__).parent}


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 (12 hex digits) of every Python file of :func:`code_roots`, path and content:
    another release's trackers, or an edited one, give another digest.

    A cell's key holds the tracker's parameters, not its code, so that a rerun resumes the
    cells of an earlier one; this digest, stored in each cell, lets the table say when some of
    them were measured by other code (:func:`stale_note`).
    """
    import hashlib

    from crowdsim.atomic import hash_sources

    h = hashlib.sha256()
    hash_sources(h, code_roots(), recursive=True)
    return h.hexdigest()[:12]


def stale_note(cells: Sequence[dict[str, Any]]) -> str | None:
    """The table's note on ``cells`` measured by other code than this run's (resumed from an
    earlier run, :func:`code_digest`); ``None`` when every one is this code's."""
    now = code_digest()
    stale = sum(1 for c in cells if c.get(CODE) != now)
    if not stale:
        return None
    return (
        f"Note: {stale} of {len(cells)} cells were measured by an earlier run with other "
        f"tracker code than this run's ({now}), and resumed from cells.json: delete their "
        "entries there (or the file) to measure them again with this code."
    )


def cell_checksum(key: str, cell: dict[str, Any]) -> str:
    """SHA-256 of a cell's key and figures (its own checksum field left out).

    The key is part of it, so a cell moved under another key fails as well as an edited one.

    >>> c = seal_cell("seq1|ncc", {"acc@15": 85.4})
    >>> c["sha256"] == cell_checksum("seq1|ncc", c), c["sha256"] == cell_checksum("seq2|ncc", c)
    (True, False)
    """
    import hashlib

    body = {k: v for k, v in cell.items() if k != CHECKSUM}
    text = json.dumps({"key": key, "cell": body}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def seal_cell(key: str, cell: dict[str, Any]) -> dict[str, Any]:
    """The cell with its checksum (:func:`cell_checksum`), as ``cells.json`` stores it."""
    return {**cell, CHECKSUM: cell_checksum(key, cell)}


def read_cells(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """The finished cells recorded in ``path`` (``{}`` when it does not exist), every one
    checked against its checksum.

    Raises ``ValueError`` naming the file (and the cell) for a file that is not a cells
    manifest (foreign, damaged, binary) and for a cell whose figures or key were changed
    after it was recorded: the table would otherwise print them as measured.
    """
    path = Path(path)
    if not path.exists():
        return {}
    hint = "move it away or choose another --out"
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a cells file; {hint}")
    try:
        data = json.loads(path.read_bytes())
    except ValueError as exc:
        raise ValueError(
            f"{path}: not a crowdsim cells file (damaged: {str(exc).splitlines()[0]}); {hint}"
        ) from None
    if not isinstance(data, dict) or not isinstance(data.get("cells"), dict):
        raise ValueError(f"{path}: not a crowdsim cells file (no 'cells' object); {hint}")
    from crowdsim.jobs import MANIFEST_FORMAT

    if data.get("format") != MANIFEST_FORMAT:  # else refused only after the sequences
        raise ValueError(
            f"{path}: a cells file of format {data.get('format')!r}, not crowdsim's "
            f"{MANIFEST_FORMAT} (another version's?); {hint}"
        )
    for key, cell in data["cells"].items():
        if not isinstance(cell, dict) or cell.get(CHECKSUM) != cell_checksum(key, cell):
            raise ValueError(
                f"{path}: cell {key!r} does not match its checksum (edited by hand or "
                "damaged); delete that entry, or the whole file, to compute it again"
            )
        for name, _, _ in METRICS:  # sealed, but not figures (another version's cell)
            v = cell.get(name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ValueError(
                    f"{path}: cell {key!r} holds {name} = {v!r}, not a number; delete that "
                    "entry, or the whole file, to compute it again"
                )
    return data["cells"]


def run_sealed_cell(
    key: str,
    seq_dir: str,
    tracker: str,
    overrides: dict[str, Any],
    frames: int | None,
    detections: DetectionParams | DetectorParams | None = None,
) -> dict[str, Any]:
    """One job of :func:`run_table`: :func:`run_cell` with this code's :func:`code_digest`,
    sealed under ``key``."""
    cell = run_cell(seq_dir, tracker, overrides, frames, detections)
    return seal_cell(key, {**cell, CODE: code_digest()})


def takes_detections(tracker: str) -> bool:
    """Whether the registered tracker ``tracker`` is fed detections (``use_detections``)."""
    from tracker.registry import get

    return hasattr(get(tracker).tracker_class(), "use_detections")


def cut_spec(spec: Any, frames: int | None) -> Any:
    """``spec`` as a table runs it with ``--frames``: :meth:`~synth_data.spec.SequenceSpec.
    truncated`, as ``generate --frames`` cuts it."""
    return spec.truncated(frames)


@dataclass(frozen=True)
class UserSequence:
    """A MOT sequence folder of the user's (``--sequences``), as a table runs it.

    ``name`` is the folder's name (its row of the table, its curve's file name), ``frames``
    the frames its cells track (its length, or ``--frames`` when shorter), ``content``
    :func:`sequence_digest` of the folder and ``length`` its whole length. It has what
    :func:`cell_key` reads of a spec (``name``, ``digest()``), so an edited or replaced
    sequence is another cell.
    """

    name: str
    path: Path
    frames: int
    content: str
    length: int

    def digest(self) -> str:
        return self.content


def sequence_digest(seq: Any) -> str:
    """SHA-256 of what identifies a MOT sequence folder's content, without decoding a frame.

    It covers the bytes of ``seqinfo.ini`` (name, size, length, frame rate, box type,
    template size), of ``gt/gt.txt`` and, where there is one, of ``checksums.json`` (a
    crowdsim sequence: the SHA-256 of every frame); then the frames by their files: the
    sorted names, sizes and modification times (ns) of the files of the image folder
    (``img1/``), and the size, modification time and first 64 KiB (the container's header)
    of ``video.mp4``. An edited ground truth, a frame added, removed, re-encoded or copied
    over with another (a new modification time), or a replaced video is another digest, so
    :func:`run_table` never reuses a cell of the old sequence for it. The price: a copy that
    does not keep modification times (``cp`` without ``-p``) is computed again.

    Parameters
    ----------
    seq : synth_data.mot.MotSequence
        The sequence, as :func:`synth_data.mot.read_sequence` read it.
    """
    import hashlib

    h = hashlib.sha256()

    def add(tag: str, data: bytes) -> None:
        h.update(f"{tag}:{len(data)}:".encode())
        h.update(data)

    from synth_data.mot import CHECKSUMS_FILE

    folder = Path(seq.path)
    add("seqinfo.ini", (folder / "seqinfo.ini").read_bytes())
    add("gt.txt", (folder / "gt" / "gt.txt").read_bytes())
    if (folder / CHECKSUMS_FILE).is_file():
        add(CHECKSUMS_FILE, (folder / CHECKSUMS_FILE).read_bytes())
    im_dir = folder / seq.im_dir
    if im_dir.is_dir():
        listing = []
        for p in im_dir.iterdir():
            if p.is_file():
                st = p.stat()
                listing.append((p.name, st.st_size, st.st_mtime_ns))
        add("frames", json.dumps(sorted(listing)).encode())
    video = seq.video_path
    if video.is_file():
        st = video.stat()
        with open(video, "rb") as fh:
            head = fh.read(64 * 1024)
        add("video", json.dumps([st.st_size, st.st_mtime_ns]).encode() + head)
    return h.hexdigest()


def user_sequences(
    folder: str | os.PathLike[str],
    only: list[str] | None,
    frames: int | None,
    out: str | os.PathLike[str],
    log: Callable[[str], None] = print,
) -> list[UserSequence]:
    """The MOT sequence folders of ``folder`` (``--sequences``: a folder of them, or one
    itself), each checked before any work, as ``crowdsim track`` checks its input.

    Read with the readers ``track`` and ``evaluate`` use (:func:`synth_data.sequence.
    open_sequence`, :func:`envs.episodes.verify_folder`): head or body boxes, image folders or
    ``video.mp4``, births from the ground truth. Raises ``ValueError`` naming the path for a
    folder that is missing or holds no sequence, a sequence without ground truth, a
    missing, damaged or unreadable frame, an ``--only`` name it does not hold, and an
    ``out`` inside ``folder`` (a table run never writes into the user's sequences).
    A ground truth of about square boxes that ``seqinfo.ini`` does not call head boxes is
    logged as a note (:func:`synth_data.mot.box_type_note`), once every sequence passed.
    """
    from envs.episodes import mot_folders, verify_folder
    from synth_data.mot import box_type_note
    from synth_data.sequence import open_sequence

    root = Path(folder)
    if not root.exists():
        raise ValueError(f"--sequences {root}: no such folder")
    if not root.is_dir():
        raise ValueError(f"--sequences {root}: is a file, not a folder of MOT sequences")
    target = Path(out).resolve()
    if target == root.resolve() or target.is_relative_to(root.resolve()):
        raise ValueError(
            f"--out {out}: inside --sequences {root}; a table run never writes into your "
            "sequences: choose an --out outside it"
        )
    folders = mot_folders(root, only)
    for path in folders:  # a sequence linked in from elsewhere is never written into either
        if target.is_relative_to(path.resolve()):
            raise ValueError(
                f"--out {out}: inside sequence {path} (-> {path.resolve()}); a table run "
                "never writes into your sequences: choose an --out outside it"
            )
    seqs, notes = [], []
    for path in folders:
        seq = open_sequence(path)  # names a bad seqinfo.ini or gt.txt
        gt = path / "gt" / "gt.txt"
        if not gt.is_file():
            raise ValueError(f"{path}: no ground truth ({gt.relative_to(path)}) to score")
        ids, _ = seq.gt_points()
        if not len(ids):
            raise ValueError(f"{gt}: no ground truth to score (no row with conf > 0, class 1)")
        verify_folder(seq)  # a missing, truncated or damaged image is named, not tracked
        if not (path / seq.im_dir).is_dir():
            seq.frame(1)  # a video (or no frames at all): its first frame must decode
        square = box_type_note(seq)
        if square:
            notes.append(f"note: {path}: {square}")
        n = seq.length if frames is None else min(frames, seq.length)
        seqs.append(UserSequence(path.name, path, n, sequence_digest(seq), seq.length))
    for note in notes:  # once every sequence passed: a refusal is one line
        log(note)
    return seqs


def params_digest(tracker: str, overrides: Any = (), detections: Any = None) -> str:
    """SHA-256 (12 hex digits) of tracker ``tracker``'s complete parameters with
    ``overrides`` and, for a tracker fed detections, its complete detector (``detections``,
    default :class:`synth_data.detections.DetectionParams`; a trained detector with its
    weights' digest): what :func:`cell_key` and the calibration's study key
    (:func:`crowdsim.lab.calibration.tracker_digest`) hold, so a changed default is another
    key."""
    import dataclasses
    import hashlib

    from tracker.registry import get

    params: dict[str, Any] = dataclasses.asdict(get(tracker).make_params(**dict(overrides)))
    if takes_detections(tracker):
        detector = detections if detections is not None else DetectionParams()
        params = {"tracker": params, "detections": dataclasses.asdict(detector)}
        if isinstance(detector, DetectorParams):  # new weights are a new detector
            from tracker.detect.inference import weights_digest

            params["detections"] = {
                "trained": params["detections"],
                "weights": weights_digest(detector),
            }
    return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:12]


def key_frames(frames: int | None, whole: Any) -> int | None:
    """The frame count a cell's key holds for ``--frames`` ``frames`` on sequence ``whole``
    (a spec before :func:`cut_spec`, or a :class:`UserSequence`): ``None`` (all) where
    ``frames`` does not cut it, so that ``--frames`` at or past a sequence's length finds
    the cells of a run without it, the same work."""
    length = getattr(whole, "length", None) or getattr(whole, "frames", None)
    if frames is not None and isinstance(length, int) and frames >= length:
        return None
    return frames


def cell_key(seq: Any, row: Row, frames: int | None) -> str:
    """The manifest key of a cell: sequence, tracker, its complete parameters and, for a
    tracker fed detections, its complete detector (a digest, so that a changed default is not
    mistaken for a finished cell) and the frame count. ``seq`` is the sequence's spec (its
    name and the digest of what it renders: another suite's ``seq8``, or an edited spec, is
    another cell), a :class:`UserSequence` (its name and :func:`sequence_digest`: an edited
    or replaced sequence is another cell) or, for a caller without one, its name."""
    digest = params_digest(row.tracker, row.overrides, row.detections)
    name = seq if isinstance(seq, str) else f"{seq.name}@{seq.digest()[:12]}"
    return f"{name}|{row.tracker}|params={digest}|frames={frames or 'all'}"


def run_table(
    rows: Sequence[Row],
    suite: str | Sequence[Any] | None,
    out: str | os.PathLike[str],
    *,
    sequences: str | os.PathLike[str] | None = None,
    only: list[str] | None = None,
    frames: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    title: str = "comparison",
    paper_table: str = "acc@15",
    log: Callable[[str], None] = print,
    more_outputs: Sequence[str] = (),
    mean: bool = True,
    finish: Callable[[dict[str, dict[str, Any]]], dict[str, Callable[[Path], object]]]
    | None = None,
) -> str:
    """Generate the suite, run every row on every sequence, write the table; returns its text.

    Parameters
    ----------
    rows : sequence of Row
    suite : str, path or list of SequenceSpec, or None
        A suite name (:data:`synth_data.suites.SUITE_NAMES`), a suite folder of spec files
        (its ``paper.json`` gives the papers' figures), or the specs themselves; ``None``
        with ``sequences``.
    out : path
        Output folder: ``sequences/`` (not with ``sequences``), ``cells.json``, ``table.md``,
        ``table.csv``, ``curves/<sequence>.png`` and :data:`OUTPUTS_FILE`.
    sequences : path, optional
        Instead of a suite: a folder of the user's MOT sequence folders, or one itself
        (:func:`user_sequences`), tracked where they are (nothing is generated or written
        there). The papers report nothing on them: the table says so, and its CSV has no
        papers' columns.
    only : list of str, optional
        Sequence names to run.
    frames : int, optional
        Truncate every sequence to its first ``frames`` frames (quick runs).
    workers, backend, address
        The jobs runner (:func:`crowdsim.jobs.run_jobs`); ``address`` only with
        ``backend="ray"``.
    paper_table : str
        The section of the suite's ``paper.json`` holding the 15 px figures of these rows.
    mean : bool
        Give each metric a column of the mean over the sequences (not for ``difficulty``,
        whose columns are variants of the same sequence).
    more_outputs, finish
        Further files the caller writes into ``out`` (checked with the table's own before any
        work) and, called with the finished cells (:func:`read_cells`), their writers
        ``{name: write(temporary path)}``; they are recorded in :data:`OUTPUTS_FILE` with the
        table's.
    """
    from crowdsim.checks import require_number, require_workers
    from crowdsim.jobs import Job, check_ray_address, run_jobs
    from synth_data.generate import generate
    from synth_data.suites import suite_specs
    from tracker.registry import get

    if frames is not None:
        require_number("", "--frames", frames, lo=2, integer=True)
    require_workers("--workers", workers, backend)
    if address is not None and backend != "ray":
        raise ValueError(f"--address needs --backend ray, got --address {address!r}")
    check_ray_address(address)  # before --out is made: a refused address leaves nothing
    for row in rows:
        get(row.tracker).make_params(**row.overrides)  # unknown names fail before any work
        if row.detections is not None and not takes_detections(row.tracker):
            raise ValueError(
                f"{title}: row {row.label!r} gives a detector, but tracker {row.tracker!r} "
                "takes no detections"
            )
    out = Path(out)
    if (suite is None) == (sequences is None):
        raise ValueError("give either a suite or sequences (--suite or --sequences)")
    if sequences is not None:
        specs = user_sequences(sequences, only, frames, out, log)
        suite, paper = str(sequences), None
    elif isinstance(suite, (str, os.PathLike)):
        specs = suite_specs(suite, only)
        paper = paper_numbers(suite)
    else:
        specs = list(suite)
        unknown = [o for o in only or () if o not in {sp.name for sp in specs}]
        if unknown:
            raise ValueError(f"--only: no sequence {unknown[0]!r} among the specs")
        specs = [sp for sp in specs if not only or sp.name in only]
        suite, paper = "specs", {}
    whole = list(specs)
    if sequences is None:
        specs = [cut_spec(s, frames) for s in specs]
    if frames is not None:  # never beside the papers' whole-sequence figures unsaid
        title += f", first {frames} frames of each sequence"
    labels = [r.label for r in rows]
    if len(set(labels)) != len(labels):
        raise ValueError(f"{title}: two rows share the label {_first_dup(labels)!r}")
    keys = {
        (s.name, r.label): cell_key(s, r, key_frames(frames, w))
        for s, w in zip(specs, whole, strict=True)
        for r in rows
    }
    if len(set(keys.values())) != len(keys):
        dup = _first_dup(list(keys.values()))
        same = [label for (_, label), key in keys.items() if key == dup]
        raise ValueError(
            f"{title}: rows {same[0]!r} and {same[1]!r} run the same tracker with the same "
            "parameters"
        )
    read_cells(out / CELLS_FILE)  # an edited or foreign cells.json fails before any work
    curve_names = [f"curves/{s.name}.png" for s in specs]
    owned = ["table.md", "table.csv", *curve_names, *more_outputs]
    check_table_outputs(out, owned)
    seq_root = out / "sequences"
    folders = {s.name: s.path if sequences is not None else seq_root / s.name for s in specs}
    try:
        if sequences is None:
            generate(
                specs,
                seq_root,
                workers=workers,
                backend=backend,
                address=address,
                progress=progress,
                log=log,
            )
    except FileExistsError as exc:  # a sequence folder made from another spec
        why = str(exc).split("; pass --overwrite")[0].split("; move it away")[0]
        raise ValueError(
            f"{why}; a table run never replaces a sequence: remove that folder, or choose "
            "another --out"
        ) from None
    log(f"{title}: {len(rows)} rows x {len(specs)} sequences of {suite} -> {out}")
    from envs.outputs import claim_folder

    claim_folder(out, OUTPUTS_FILE, {"written_by": _WRITER, "title": title}, owned)
    jobs = [
        Job(
            keys[(s.name, r.label)],
            run_sealed_cell,
            (
                keys[(s.name, r.label)],
                str(folders[s.name]),
                r.tracker,
                dict(r.overrides),
                frames,
                r.detections,
            ),
            size=s.frames,
        )
        for s in specs
        for r in rows
    ]
    run_jobs(
        jobs,
        out / CELLS_FILE,
        workers=workers,
        backend=backend,
        address=address,
        progress=progress,
        desc=title,
        unit="frame",
        section="cells",
    )
    done = read_cells(out / CELLS_FILE)
    cells = {cell: done[key] for cell, key in keys.items()}
    names = [s.name for s in specs]
    text = format_table(rows, names, cells, paper, paper_table, title, mean=mean)
    note = stale_note(list(cells.values()))
    if note is not None:
        text += f"\n{note}\n"
    csv_text = table_csv(rows, names, cells, paper, paper_table)
    outputs: dict[str, Callable[[Path], object]] = {
        "table.md": lambda p: p.write_text(text),
        "table.csv": lambda p: p.write_text(csv_text),
        **_curve_writers(rows, names, cells, title),
    }
    if finish is not None:
        outputs.update(finish(done))
    from envs.outputs import write_outputs

    write_outputs(out, OUTPUTS_FILE, {"written_by": _WRITER, "title": title}, outputs)
    return text


def _first_dup(items: list[str]) -> str:
    return next(x for i, x in enumerate(items) if x in items[:i])


def _paper(paper: dict | None, table: str, row: Row, seq: str) -> float | None:
    if row.paper is None or paper is None:
        return None
    return paper.get(table, {}).get(row.paper, {}).get(seq)


def format_table(
    rows: Sequence[Row],
    seqs: Sequence[str],
    cells: dict,
    paper: dict | None,
    paper_table: str = "acc@15",
    title: str = "comparison",
    mean: bool = True,
) -> str:
    """Markdown: one section per metric, rows = methods, columns = sequences and (``mean``)
    their mean.

    Accuracy cells read ``ours (paper)`` where the papers report the figure. ``paper=None``:
    the user's own sequences (``--sequences``), on which the papers report nothing; the
    table says so in place of the papers' note.
    """
    lines = [f"# {title}", ""]
    bracketed = False
    for key, heading, unit in METRICS:
        lines += [
            f"## {heading}",
            "",
            "| method | " + " | ".join(seqs) + (" | mean |" if mean else " |"),
            "|---" * (len(seqs) + 1 + mean) + "|",
        ]
        for row in rows:
            vals, texts = [], []
            for s in seqs:
                v = cells[(s, row.label)].get(key)
                vals.append(v)
                table = paper_table if key == "acc@15" else ("acc@5" if key == "acc@5" else "")
                ref = _paper(paper, table, row, s) if table else None
                t = "n/a" if v is None else f"{v:.1f}{unit}"
                texts.append(t if ref is None else f"{t} ({ref:g})")
                bracketed |= ref is not None
            good = [v for v in vals if v is not None]
            avg = f"{sum(good) / len(good):.1f}{unit}" if good else "n/a"
            lines.append(
                f"| {row.label} | " + " | ".join(texts) + (f" | {avg} |" if mean else " |")
            )
        lines.append("")
    if paper is None:
        lines.append(NO_PAPER_NOTE)
        return "\n".join(lines) + "\n"
    if not bracketed:  # a suite without paper.json (stress, galleria, a folder of specs)
        lines.append("No figures in brackets: the papers report none for these sequences.")
        return "\n".join(lines) + "\n"
    lines.append("Figures in brackets: the papers' (paper 1 Tables 1-3, paper 2 Table 1).")
    if any(r.paper in ELEVEN for r in rows):
        lines.append(ELEVEN_NOTE)
    return "\n".join(lines) + "\n"


def table_csv(
    rows: Sequence[Row],
    seqs: Sequence[str],
    cells: dict,
    paper: dict | None,
    paper_table: str = "acc@15",
) -> str:
    """Long format: one line per method and sequence, ours and the papers' figures (an empty
    papers' field: they report none for that method and sequence). ``paper=None``, the user's
    own sequences: no papers' columns at all, as there is no papers' figure to miss."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = [k for k, _, _ in METRICS]
    papers = [] if paper is None else ["paper_acc@15", "paper_acc@5"]
    w.writerow(["method", "tracker", "sequence", *keys, *papers])
    for row in rows:
        for s in seqs:
            c = cells[(s, row.label)]
            p15 = _paper(paper, paper_table, row, s)
            p5 = _paper(paper, "acc@5", row, s)
            w.writerow(
                [
                    row.label,
                    row.tracker,
                    s,
                    *[("" if c.get(k) is None else f"{c[k]:.3f}") for k in keys],
                    *(
                        []
                        if paper is None
                        else ["" if p15 is None else p15, "" if p5 is None else p5]
                    ),
                ]
            )
    return buf.getvalue()


def _curve_writers(
    rows: Sequence[Row], seqs: Sequence[str], cells: dict, run: str = ""
) -> dict[str, Callable[[Path], object]]:
    """``{"curves/<sequence>.png": write(path)}``: each sequence's accuracy curves, titled
    with the run's title (its settings and frames: a curve of another run in the same folder
    says which)."""
    from tracker.metrics import plot_accuracy

    writers: dict[str, Callable[[Path], object]] = {}
    for s in seqs:
        curves = {
            r.label: cells[(s, r.label)]["curve"] for r in rows if cells[(s, r.label)].get("curve")
        }
        if curves:
            title = f"{s}: accuracy vs threshold" + (f"\n{run}" if run else "")
            writers[f"curves/{s}.png"] = lambda p, c=curves, t=title: plot_accuracy(c, p, title=t)
    return writers
