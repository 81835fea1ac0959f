"""MOTChallenge sequences on disk: one writer and one reader (SPEC §2).

Layout of a sequence folder ``SEQ``::

    SEQ/seqinfo.ini          [Sequence] name, imDir, frameRate, seqLength, imWidth, imHeight,
                             imExt (imDir and imExt only with img1/), and for crowdsim
                             sequences templateSize and boxType = head
    SEQ/img1/000001.jpg ...  frames (and/or SEQ/video.mp4)
    SEQ/gt/gt.txt            frame,id,bb_left,bb_top,bb_width,bb_height,conf,class,visibility
    SEQ/gt/agents.csv        id,group,prominent,anomaly,appearance (crowdsim sequences only)
    SEQ/meta.json            spec, seed, package versions (crowdsim sequences only)
    SEQ/checksums.json       SHA-256 of every other file (crowdsim sequences only)

Reader API (also reads real MOT17 / MOT20 folders)
---------------------------------------------------
``read_sequence(path) -> MotSequence`` with

* ``name: str``, ``frame_rate: float``, ``width: int``, ``height: int``, ``length: int``;
* ``template_size: int`` pixels: ``templateSize`` from seqinfo.ini when present; otherwise the
  median width of the pedestrian gt boxes (real MOT data), or :data:`DEFAULT_TEMPLATE_SIZE`
  when there is no gt;
* ``gt: (K, 9) float64`` rows of ``gt/gt.txt`` (1-based frames), shape ``(0, 9)`` without gt;
* ``box_type: str``: ``"head"`` (crowdsim: the box is the head template centred on the head)
  or ``"body"`` (MOTChallenge full-body boxes);
* ``frames() -> Iterator[(H, W, 3) uint8 BGR]`` in order, from ``img1/`` or ``video.mp4``;
* ``frame(i)`` for a 1-based frame index ``i``;
* ``gt_points() -> (ids (N,) int64, points (T, N, 2) float64)``: head centres in pixels, NaN
  where absent, ``T = length``. Only rows with ``conf > 0`` and ``class == 1`` count. Head
  boxes give their centre; body boxes give ``(left + w / 2, top + HEAD_IN_BODY * h)``.
* ``agents() -> dict[str, (N,) ndarray]`` from ``gt/agents.csv`` (empty dict without it);
* ``births() -> ((ids0, pts0), {t: (ids, pts)})``: from the points CSV ``init`` when set (see
  :mod:`synth_data.births`), else from the ground truth (each id born at its first frame).

A ``MotSequence`` is a :class:`synth_data.sequence.SequenceSource`.

``write_mot(path, rows)`` and ``read_mot_file(path) -> (K, 9+) float64`` write and read MOT
text files; malformed lines raise :class:`ValueError` as ``file:line: message``.
:func:`mot_ids` and :func:`gt_rows` turn trajectories into MOT ids and ground-truth rows;
:func:`check_checksums` verifies ``checksums.json`` (:data:`CHECKSUMS_FILE`).
"""

from __future__ import annotations

import configparser
import csv
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import atomic_path, sha256_file, write_text_atomic
from synth_data.births import Births, births_from_ground_truth, births_from_init

MOT_COLUMNS: tuple[str, ...] = (
    "frame",
    "id",
    "bb_left",
    "bb_top",
    "bb_width",
    "bb_height",
    "conf",
    "class",
    "visibility",
)
DEFAULT_TEMPLATE_SIZE: int = 12
"""Template size (px) when neither seqinfo.ini nor gt says otherwise."""
HEAD_IN_BODY: float = 0.08
"""Head centre height below the top of a full-body box, as a fraction of the box height."""
AGENT_COLUMNS: tuple[str, ...] = ("id", "group", "prominent", "anomaly", "appearance")
CHECKSUMS_FILE: str = "checksums.json"
"""SHA-256 of every other file of a crowdsim sequence, written last by the writer."""
SUITE_MANIFEST: str = "manifest.json"
"""The manifest of a folder of sequences made by ``crowdsim generate`` (and its lock file
``.manifest.json.lock``)."""


# ---------------------------------------------------------------------------- MOT text files
def write_mot(path: str | os.PathLike[str], rows: np.ndarray) -> Path:
    """Write ``(K, >= 9)`` rows as MOT text (atomically). Frame, id and class are integers."""
    path = Path(path)
    rows = np.asarray(rows, dtype=np.float64)
    if rows.ndim != 2 or (rows.size and rows.shape[1] < 9):
        raise ValueError(f"{path}: MOT rows must have shape (K, >= 9), got {rows.shape}")
    if rows.size and not np.isfinite(rows).all():
        raise ValueError(f"{path}: MOT rows contain NaN or infinite values")
    for col, what in ((0, "frame"), (1, "id"), (7, "class")):
        raw = rows[:, col] if rows.size else rows[:0, 0]
        bad = raw != np.round(raw)
        if bad.any():  # int() would truncate id 2.5 onto id 2 and merge two people
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{path}: MOT row {i + 1}: {what} {raw[i]:g} is not a whole number")
    # one %-format per chunk of rows, not one f-string per row (2.4x faster on 300,000 rows);
    # %d, %.3f and %g give the same text as int(), :.3f and :g
    line = "%d,%d,%.3f,%.3f,%.3f,%.3f,%g,%d,%.4f" + ",%g" * (rows.shape[1] - 9) + "\n"
    chunk = 20_000
    # chunk by chunk into the file: the whole text at once had cost about 100 bytes a row
    # beside the rows (3.2M rows: 0.3 GB)
    with atomic_path(path) as tmp, open(tmp, "w") as fh:
        for i in range(0, len(rows), chunk):
            part = rows[i : i + chunk]
            fh.write((line * len(part)) % tuple(part.ravel().tolist()))
    return path


def _text_lines(path: Path, what: str) -> Iterator[str]:
    """The lines of a UTF-8 text file, streamed (a BOM is dropped); ``ValueError`` naming the
    file when it is binary or not UTF-8, so that no decoder error without a file name reaches
    a user."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            yield from fh
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not {what} (binary, not UTF-8 text: {exc.reason})") from None


def read_mot_file(path: str | os.PathLike[str], min_columns: int = 6) -> np.ndarray:
    """Read a MOT text file (comma or whitespace separated) as ``(K, max(9, C))`` float64.

    Lines with fewer than 9 columns are padded with ``1`` (conf, class, visibility). Errors
    name the file and the line: too few columns, a non-numeric value, a frame that is not a
    positive integer, a negative box size, or a non-finite value.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such MOT file")
    fast = _read_mot_fast(path, min_columns)
    if fast is not None:
        return fast
    rows: list[list[float]] = []
    width = None
    for lineno, line in enumerate(_text_lines(path, "a MOT text file"), 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = [p for p in text.replace(",", " ").split()]
        if len(parts) < min_columns:
            raise ValueError(
                f"{path}:{lineno}: expected at least {min_columns} columns "
                f"(frame,id,bb_left,bb_top,bb_width,bb_height,...), "
                f"got {len(parts)}: {text!r}"
            )
        try:
            values = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not _is_float(p))
            raise ValueError(f"{path}:{lineno}: non-numeric value {bad!r} in {text!r}") from None
        if not all(np.isfinite(values)):
            raise ValueError(f"{path}:{lineno}: non-finite value in {text!r}")
        frame = values[0]
        if frame < 1 or frame != int(frame):
            raise ValueError(
                f"{path}:{lineno}: frame must be a positive integer "
                f"(MOT frames are 1-based), got {parts[0]!r}"
            )
        if values[4] < 0 or values[5] < 0:
            raise ValueError(
                f"{path}:{lineno}: box width/height must be >= 0, got {parts[4]!r}, {parts[5]!r}"
            )
        if width is None:
            width = len(values)
        elif len(values) != width:
            raise ValueError(
                f"{path}:{lineno}: expected {width} columns like the first row, got {len(values)}"
            )
        rows.append(values)
    if not rows:
        return np.zeros((0, 9))
    arr = np.array(rows, dtype=np.float64)
    if arr.shape[1] < 9:
        arr = np.hstack([arr, np.ones((len(arr), 9 - arr.shape[1]))])
    return arr


def _read_mot_fast(path: Path, min_columns: int) -> np.ndarray | None:
    """:func:`read_mot_file`'s array parsed by numpy's compiled reader (a results file of
    thousands of people a frame: about 9 us a row line by line), or ``None`` for anything the
    line-by-line reader must look at: comments, a row it would refuse (it then names the
    line), text that is not UTF-8."""
    import io

    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None
    if "#" in text or not text.strip():
        return None
    try:
        arr = np.loadtxt(io.StringIO(text.replace(",", " ")), dtype=np.float64, ndmin=2)
    except ValueError:  # uneven rows, a word: the line-by-line reader names the line
        return None
    if arr.shape[1] < min_columns or not np.isfinite(arr).all():
        return None
    frame = arr[:, 0]
    if (frame < 1).any() or (frame != np.floor(frame)).any() or (arr[:, 4:6] < 0).any():
        return None
    if arr.shape[1] < 9:
        arr = np.hstack([arr, np.ones((len(arr), 9 - arr.shape[1]))])
    return arr


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------- writer helpers
def write_seqinfo(
    seq_dir: str | os.PathLike[str],
    *,
    name: str,
    frame_rate: float,
    length: int,
    width: int,
    height: int,
    template_size: int | None = None,
    box_type: str = "head",
    im_dir: str | None = "img1",
    im_ext: str = ".jpg",
) -> Path:
    """Write ``seq_dir/seqinfo.ini`` in the MOTChallenge format (plus crowdsim keys).

    ``im_dir=None`` (a sequence whose frames are only in ``video.mp4``) leaves out ``imDir``
    and ``imExt``: there is no image folder for a tool to look in."""
    lines = ["[Sequence]", f"name={name}"]
    if im_dir is not None:
        lines.append(f"imDir={im_dir}")
    lines += [
        # whole rates as MOTChallenge writes them (25), others to the last digit (29.97002997...)
        f"frameRate={frame_rate:g}"
        if float(f"{frame_rate:g}") == frame_rate
        else f"frameRate={float(frame_rate)!r}",
        f"seqLength={int(length)}",
        f"imWidth={int(width)}",
        f"imHeight={int(height)}",
    ]
    if im_dir is not None:
        lines.append(f"imExt={im_ext}")
    if template_size is not None:
        lines.append(f"templateSize={int(template_size)}")
    lines.append(f"boxType={box_type}")
    path = Path(seq_dir) / "seqinfo.ini"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def write_agents_csv(path: str | os.PathLike[str], table: dict[str, np.ndarray]) -> Path:
    """Write ``gt/agents.csv`` with the columns :data:`AGENT_COLUMNS` (all integers)."""
    cols = [np.asarray(table[c]).astype(np.int64) for c in AGENT_COLUMNS]
    lines = [",".join(AGENT_COLUMNS)]
    lines.extend(",".join(str(int(v)) for v in row) for row in zip(*cols, strict=True))
    write_text_atomic(Path(path), "\n".join(lines) + "\n")
    return Path(path)


# ---------------------------------------------------------------------------- ids and gt rows
def mot_ids(ids: np.ndarray) -> np.ndarray:
    """MOT ids (>= 1) of trajectory ids: ``id + 1`` when all ids are >= 0, else rank + 1."""
    ids = np.asarray(ids, dtype=np.int64)
    if len(ids) == 0 or ids.min() >= 0:
        return ids + 1
    return np.argsort(np.argsort(ids)) + 1


GT_ROWS_BLOCK = 1 << 20
"""(frame, agent) cells :func:`gt_rows` turns into rows at a time."""


def gt_rows(
    pixels: np.ndarray,
    camera: Any,
    template_px: int,
    mot_ids: np.ndarray,
    visibility: np.ndarray | None = None,
) -> np.ndarray:
    """MOT ground-truth rows ``(K, 9)``: one head box per agent and frame.

    Parameters
    ----------
    pixels : (T, N, 2) float
        Head centres in pixels (``AgentTracks.pixels``), NaN where absent.
    camera : crowdsim.camera.Camera
        Frame size (a row is written when the head centre lies inside the frame).
    template_px : int
        Box side in pixels, centred on the head.
    mot_ids : (N,) int
        MOT ids of the agents (see :func:`mot_ids`).
    visibility : (T, N) float, optional
        Visible fraction of each head as drawn (``SceneRenderer.render(visibility=...)``:
        occlusion by people in front and clipping by the frame). Without it the column is the
        fraction of the box inside the frame.

    Returns
    -------
    (K, 9) float64
        Columns frame (1-based), id, bb_left, bb_top, bb_width, bb_height, conf (1),
        class (1 = pedestrian), visibility in [0, 1]; sorted by frame, then id.
    """
    pix = np.asarray(pixels, np.float64)
    vis = camera.visible(pix)
    mot_ids = np.asarray(mot_ids, np.int64)
    s = float(template_px)
    if visibility is not None:
        visibility = np.asarray(visibility, np.float64)
        if visibility.shape != pix.shape[:2]:
            raise ValueError(f"visibility must have shape {pix.shape[:2]}, got {visibility.shape}")
    out = np.empty((int(np.count_nonzero(vis)), 9))
    # a block of frames at a time: the index arrays and columns of every row at once had
    # cost about twice the rows themselves on top of them (3.2M rows: 0.49 GB over 0.23)
    step = max(1, GT_ROWS_BLOCK // max(1, pix.shape[1]))
    k0 = 0
    for f0 in range(0, pix.shape[0], step):
        t_idx, n_idx = np.nonzero(vis[f0 : f0 + step])
        t_idx += f0
        order = np.lexsort((mot_ids[n_idx], t_idx))  # frames ascend block after block
        t_idx, n_idx = t_idx[order], n_idx[order]
        centre = pix[t_idx, n_idx]
        left = centre[:, 0] - s / 2.0
        top = centre[:, 1] - s / 2.0
        if visibility is None:
            ix = np.clip(np.minimum(left + s, camera.width) - np.maximum(left, 0.0), 0, s)
            iy = np.clip(np.minimum(top + s, camera.height) - np.maximum(top, 0.0), 0, s)
            column = ix * iy / (s * s)
        else:
            column = np.clip(np.nan_to_num(visibility[t_idx, n_idx]), 0.0, 1.0)
        rows = out[k0 : k0 + len(t_idx)]
        rows[:, 0] = t_idx + 1
        rows[:, 1] = mot_ids[n_idx]
        rows[:, 2] = left
        rows[:, 3] = top
        rows[:, 4:6] = s
        rows[:, 6:8] = 1.0
        rows[:, 8] = column
        k0 += len(t_idx)
    return out


def check_checksums(seq_dir: str | os.PathLike[str]) -> dict[str, str] | None:
    """Verify the files ``checksums.json`` lists; ``None`` when the folder has no listing.

    Every entry must be a relative path inside ``seq_dir`` (no ``..``, no absolute path, no
    link out of the folder) to an existing file whose SHA-256 matches. Raises ``ValueError``
    naming the listing or the file otherwise.
    """
    seq_dir = Path(seq_dir)
    listing = seq_dir / CHECKSUMS_FILE
    if not listing.is_file():
        return None
    try:
        checks = json.loads(listing.read_text())
    except (ValueError, UnicodeDecodeError):
        raise ValueError(f"{listing}: not valid JSON") from None
    if not isinstance(checks, dict) or not checks:
        raise ValueError(f"{listing}: expected a non-empty object of file: sha256")
    root = seq_dir.resolve()
    for rel, digest in sorted(checks.items()):
        p = seq_dir / rel
        if Path(rel).is_absolute() or not p.resolve().is_relative_to(root):
            raise ValueError(f"{listing}: entry {rel!r} points outside the sequence folder")
        if not isinstance(digest, str):
            raise ValueError(f"{listing}: entry {rel!r} has no SHA-256 string")
        if not p.is_file():
            raise ValueError(f"{p}: missing (listed in {listing.name})")
        if sha256_file(p) != digest:
            raise ValueError(f"{p}: damaged (its SHA-256 differs from {listing.name})")
    return checks


def verify_sequence(seq_dir: str | os.PathLike[str]) -> dict[str, str] | None:
    """The checksums of a complete sequence folder, or None if it is incomplete or corrupt."""
    try:
        return check_checksums(seq_dir)
    except (OSError, ValueError):
        return None


TMP_MARKER = ".crowdsim-tmp-owner.json"
"""Marker file written first inside every temporary folder of :mod:`synth_data.writer`;
proves the folder is ours to delete (it is removed once the folder is published)."""


def read_tmp_marker(folder: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The marker of a temporary folder, or None when it has none (not ours) or it is bad."""
    try:
        data = json.loads((Path(folder) / TMP_MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("pid"), int):
        return None
    return data


def require_outside_sequences(flag: str, out: Path, shown: object, itself: bool) -> None:
    """Refuse (``ValueError`` naming ``flag``) an output folder inside a MOT sequence folder
    (one that holds ``seqinfo.ini``), or that is one when ``itself``: a sequence, a manifest or
    a lock written into a sequence makes it no longer plain MOT, nor provably crowdsim's (a
    later ``generate`` refused to replace it). ``shown`` is the path as the user gave it."""
    for folder in (out, *out.absolute().parents)[0 if itself else 1 :]:
        if (folder / "seqinfo.ini").is_file():
            raise ValueError(
                f"{flag} {str(shown)!r} lies in a sequence folder, {str(folder)!r} (it holds "
                "seqinfo.ini); give a folder of its own, beside the sequences"
            )


def not_ours(folder: str | os.PathLike[str]) -> str | None:
    """Why crowdsim cannot prove it wrote everything in ``folder``; ``None`` when it can.

    A sequence folder is crowdsim's when every file below it (hidden ones included) is
    ``checksums.json`` or listed there with its SHA-256; a suite folder when it holds only its
    ``manifest.json`` (a JSON object with a ``sequences`` table, as ``crowdsim generate``
    writes it), the manifest's lock file and such sequence folders. Otherwise the answer names
    the first file that is not (a file a user added to ``gt/`` or ``img1/``, a changed file, a
    hidden file beside the sequences, a folder with no listing); crowdsim's own
    :data:`TMP_MARKER`, left by a writer killed just after it published the folder, counts as
    crowdsim's. What ``--overwrite`` checks
    before it replaces a folder, so that replacing it deletes nothing but crowdsim's own
    output.
    """
    folder = Path(folder)
    if folder.is_symlink():
        return f"{folder} is a link, not a folder crowdsim wrote"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if (folder / SUITE_MANIFEST).is_file() and not (folder / CHECKSUMS_FILE).exists():
        try:
            manifest = json.loads((folder / SUITE_MANIFEST).read_text())
        except (OSError, ValueError):
            manifest = None
        if not (isinstance(manifest, dict) and isinstance(manifest.get("sequences"), dict)):
            return f"{folder / SUITE_MANIFEST} is not a crowdsim manifest (no sequences table)"
        lock = f".{SUITE_MANIFEST}.lock"
        for entry in sorted(folder.iterdir()):
            if entry.name in (SUITE_MANIFEST, lock):
                continue
            why = not_ours(entry) if entry.is_dir() else f"{entry} was not written by crowdsim"
            if why is not None:
                return why
        return None
    try:
        checks = check_checksums(folder)
    except (OSError, ValueError) as exc:
        return str(exc)
    if checks is None:
        return f"{folder} has no {CHECKSUMS_FILE}, so crowdsim cannot tell its files from yours"
    listed = {*checks, CHECKSUMS_FILE}
    folders = {parent.as_posix() for rel in listed for parent in Path(rel).parents}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.is_dir() and not path.is_symlink() and (rel in folders or any(path.iterdir())):
            continue  # a folder of the user's is named by the first file in it
        if rel == TMP_MARKER and read_tmp_marker(folder) is not None:
            continue  # the marker of a writer killed just after it published the folder
        if rel not in listed:
            return f"{path} was not written by crowdsim"
    return None


# ---------------------------------------------------------------------------- reader
@dataclass
class MotSequence:
    """A MOTChallenge sequence folder; see the module docstring for the attributes."""

    path: Path
    name: str
    frame_rate: float
    width: int
    height: int
    length: int
    template_size: int
    gt: np.ndarray
    box_type: str = "body"
    im_dir: str = "img1"
    im_ext: str = ".jpg"
    info: dict[str, str] = field(default_factory=dict)
    init: Path | None = None
    """Points CSV that overrides the ground-truth births (``crowdsim track --init``)."""

    @property
    def video_path(self) -> Path:
        return self.path / "video.mp4"

    def _image_path(self, i: int) -> Path:
        return self.path / self.im_dir / f"{i:06d}{self.im_ext}"

    def _has_images(self) -> bool:
        return self._image_path(1).is_file()

    def frames(self) -> Iterator[np.ndarray]:
        """Yield every frame as ``(H, W, 3)`` uint8 BGR, frame 1 first."""
        import cv2

        if self._has_images():
            for i in range(1, self.length + 1):
                yield self.frame(i)
            return
        if not self.video_path.is_file():
            raise ValueError(
                f"{self.path}: no frames ({self.im_dir}/000001{self.im_ext} or video.mp4)"
            )
        cap = cv2.VideoCapture(str(self.video_path))
        try:
            for i in range(1, self.length + 1):
                ok, img = cap.read()
                if not ok:
                    raise ValueError(f"{self.video_path}: could not read frame {i}")
                yield img
        finally:
            cap.release()

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` (1-based) as ``(H, W, 3)`` uint8 BGR."""
        import cv2

        if not (1 <= i <= self.length):
            raise ValueError(f"frame must be in [1, {self.length}], got {i}")
        p = self._image_path(i)
        if p.is_file():
            img = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{p}: not a readable image")
            if img.shape[:2] != (self.height, self.width):
                raise ValueError(
                    f"{p}: the image is {img.shape[1]}x{img.shape[0]} px, but "
                    f"seqinfo.ini says imWidth={self.width}, "
                    f"imHeight={self.height}"
                )
            return img
        if self.video_path.is_file():
            cap = cv2.VideoCapture(str(self.video_path))
            try:
                cap.set(cv2.CAP_PROP_POS_FRAMES, i - 1)
                ok, img = cap.read()
            finally:
                cap.release()
            if not ok:
                raise ValueError(f"{self.video_path}: could not read frame {i}")
            return img
        raise ValueError(f"{p}: no such frame (and no video.mp4)")

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ids (N,), points (T, N, 2))``: head centres in pixels, NaN where absent."""
        rows = self.gt
        if len(rows):
            rows = rows[(rows[:, 6] > 0) & (rows[:, 7] == 1)]
        ids = np.unique(rows[:, 1]).astype(np.int64) if len(rows) else np.zeros(0, np.int64)
        points = np.full((self.length, len(ids), 2), np.nan)
        if len(rows):
            col = np.searchsorted(ids, rows[:, 1].astype(np.int64))
            t = rows[:, 0].astype(np.int64) - 1
            keep = (t >= 0) & (t < self.length)
            x = rows[:, 2] + rows[:, 4] / 2.0
            if self.box_type == "head":
                y = rows[:, 3] + rows[:, 5] / 2.0
            else:
                y = rows[:, 3] + HEAD_IN_BODY * rows[:, 5]
            points[t[keep], col[keep], 0] = x[keep]
            points[t[keep], col[keep], 1] = y[keep]
        return ids, points

    def births(self) -> Births:
        """``((ids0, pts0), {t (0-based): (ids, pts)})``: from :attr:`init` (ids checked
        against the ground truth) or from the ground truth itself."""
        gt_ids, gt_pts = self.gt_points()
        if self.init is not None:
            return births_from_init(self.init, self.length, gt_ids, where=str(self.path))
        if len(gt_ids) == 0:
            raise ValueError(
                f"{self.path}: no ground truth to start from; pass --init "
                "points.csv (rows frame,id,x,y), or --init detect to start from the heads "
                "the detector finds"
            )
        return births_from_ground_truth(gt_ids, gt_pts, (self.width, self.height))

    def agents(self) -> dict[str, np.ndarray]:
        """Columns of ``gt/agents.csv`` as int64 arrays (empty dict when absent)."""
        path = self.path / "gt" / "agents.csv"
        if not path.is_file():
            return {}
        reader = csv.reader(_text_lines(path, "a CSV file"))
        header = next(reader, None)
        if header is None:
            return {}
        header = [h.strip() for h in header]
        data = []
        for lineno, row in enumerate(reader, 2):
            if not row:
                continue
            if len(row) != len(header):
                raise ValueError(f"{path}:{lineno}: expected {len(header)} columns, got {len(row)}")
            try:
                data.append([int(v) for v in row])
            except ValueError:
                raise ValueError(f"{path}:{lineno}: non-integer value in {row!r}") from None
        arr = np.array(data, dtype=np.int64).reshape(-1, len(header))
        return {h: arr[:, k] for k, h in enumerate(header)}


def _check_gt_rows(gt_path: Path, gt: np.ndarray) -> None:
    """Refuse non-integer or out-of-int64 ids and duplicate ``(frame, id)`` rows by name."""
    if not len(gt):
        return
    ids = gt[:, 1]
    bad = (ids != np.round(ids)) | (np.abs(ids) >= 2.0**53)  # float64 holds them exactly
    if bad.any():
        raise ValueError(f"{gt_path}: id {ids[bad][0]:g} is not a whole number below 2^53")
    key = np.unique(gt[:, :2], axis=0, return_counts=True)
    if (key[1] > 1).any():
        f, i = key[0][key[1] > 1][0]
        raise ValueError(f"{gt_path}: frame {int(f)}, id {int(i)} appears twice")


def read_sequence(path: str | os.PathLike[str]) -> MotSequence:
    """Open a MOTChallenge sequence folder (crowdsim's or a real MOT17/MOT20 one)."""
    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"{path}: no such sequence folder")
    ini = path / "seqinfo.ini"
    if not ini.is_file():
        raise ValueError(f"{path}: missing seqinfo.ini (not a MOTChallenge sequence)")
    parser = configparser.ConfigParser(interpolation=None)
    parser.optionxform = str  # keep the camelCase keys
    try:
        parser.read_string("".join(_text_lines(ini, "a seqinfo.ini file")), source=str(ini))
    except configparser.Error as exc:
        raise ValueError(f"{ini}: malformed ({exc.__class__.__name__})") from None
    if "Sequence" not in parser:
        raise ValueError(f"{ini}: missing [Sequence] section")
    sec = dict(parser["Sequence"])

    def get(key: str, conv, default=None):
        if key not in sec:
            if default is None:
                raise ValueError(f"{ini}: missing key {key!r}")
            return default
        try:
            return conv(sec[key].strip())
        except ValueError:
            raise ValueError(f"{ini}: key {key!r} has a bad value {sec[key]!r}") from None

    gt_path = path / "gt" / "gt.txt"
    gt = read_mot_file(gt_path)[:, :9] if gt_path.is_file() else np.zeros((0, 9))
    _check_gt_rows(gt_path, gt)
    length = get("seqLength", int)
    if length < 1:
        raise ValueError(f"{ini}: key 'seqLength' must be >= 1, got {length}")
    frame_rate = get("frameRate", float)
    width = get("imWidth", int)
    height = get("imHeight", int)
    for key, value in (("frameRate", frame_rate), ("imWidth", width), ("imHeight", height)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{ini}: key {key!r} must be a finite number > 0, got {value}")
    box_type = sec.get("boxType", "body").strip()
    if box_type not in ("head", "body"):
        raise ValueError(f"{ini}: key 'boxType' must be head or body, got {box_type!r}")
    if "templateSize" in sec:
        template = get("templateSize", int)
        if not 2 <= template <= 256:
            raise ValueError(f"{ini}: key 'templateSize' must be in [2, 256] px, got {template}")
    elif len(gt):
        ped = gt[(gt[:, 6] > 0) & (gt[:, 7] == 1)]
        widths = ped[:, 4] if len(ped) else gt[:, 4]
        template = int(np.clip(round(float(np.median(widths))), 4, 64))
    else:
        template = DEFAULT_TEMPLATE_SIZE
    if len(gt) and gt[:, 0].max() > length:
        raise ValueError(
            f"{gt_path}: frame {int(gt[:, 0].max())} is beyond seqLength={length} of {ini}"
        )
    return MotSequence(
        path=path,
        name=sec.get("name", path.name).strip(),
        frame_rate=frame_rate,
        width=width,
        height=height,
        length=length,
        template_size=template,
        gt=gt,
        box_type=box_type,
        im_dir=sec.get("imDir", "img1").strip(),
        im_ext=sec.get("imExt", ".jpg").strip(),
        info=sec,
    )


TALL_BOXES: float = 1.3
"""MOT rows whose median box is this many times taller than wide are body boxes (a person's
box is about 2.5 times; a head box is square): :func:`box_type_note`, and ``evaluate``'s
reading of body-box results."""


def box_aspect(rows: np.ndarray) -> float:
    """Median height / width of the boxes of MOT ``rows`` (NaN rows left out; a box of no
    width counts as very tall, for its own check to name later)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return float(np.nanmedian(rows[:, 5] / np.maximum(rows[:, 4], 1e-9)))


def box_type_note(seq: MotSequence) -> str | None:
    """A warning when ``seq``'s seqinfo.ini gives no ``boxType`` (so its boxes are read as
    MOTChallenge full-body boxes, the head at :data:`HEAD_IN_BODY` of their height) while its
    ground-truth boxes are about square, as head boxes are; ``None`` otherwise."""
    if "boxType" in seq.info or not len(seq.gt):
        return None
    ratio = box_aspect(seq.gt)
    if ratio >= TALL_BOXES:
        return None
    return (
        "seqinfo.ini gives no boxType, so the ground-truth boxes are read as MOTChallenge "
        f"full-body boxes (the head near their top); they are about square (median "
        f"height/width {ratio:.2f}): add boxType=head if they are head boxes"
    )


def verify_frames(seq: MotSequence) -> None:
    """Refuse a damaged sequence, naming the file.

    With ``checksums.json`` (crowdsim sequences) every listed file must exist and match its
    SHA-256 (:func:`check_checksums`). Otherwise every image that ``seqLength`` promises must
    exist, and the first one must have the ``imWidth x imHeight`` of ``seqinfo.ini``. A
    sequence without an image folder (ground truth only, or a video) is not checked further.
    """
    check_checksums(seq.path)
    im_dir = seq.path / seq.im_dir
    if not im_dir.is_dir():
        return
    for i in range(1, seq.length + 1):
        p = im_dir / f"{i:06d}{seq.im_ext}"
        if not p.is_file():
            raise ValueError(
                f"{p}: missing (seqLength={seq.length} promises frames 1..{seq.length})"
            )
    seq.frame(1)  # decodes one image: imWidth/imHeight must match it
