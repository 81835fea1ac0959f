"""Who a tracker starts with and who is born later: the papers' initialisation.

Both papers start from hand-marked heads in the first frame and add every later person at the
frame it enters. A :data:`Births` value carries exactly that, whatever the source:

* :func:`births_from_ground_truth` -- each ground-truth id is born at its first present frame,
  at its ground-truth position (synthetic sequences, MOT folders with ``gt.txt``);
* :func:`births_from_init` / :func:`births_from_points` -- a points CSV (``crowdsim track
  --init``): a header line and rows ``frame,id,x,y`` (pixels, 1-based frame) or ``id,x,y`` (all
  at frame 1); rows at the first frame initialise the tracker, later rows are births.

>>> import numpy as np
>>> pts = np.array([[[1.0, 2.0], [np.nan, np.nan]], [[1.5, 2.0], [5.0, 6.0]]])
>>> (ids0, p0), later = births_from_ground_truth(np.array([7, 9]), pts)
>>> ids0.tolist(), p0.tolist(), {t: v[0].tolist() for t, v in later.items()}
([7], [[1.0, 2.0]], {1: [9]})
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

Births = tuple[tuple[np.ndarray, np.ndarray], dict[int, tuple[np.ndarray, np.ndarray]]]
"""``((ids0 (n0,), points0 (n0, 2)), {t (0-based frame): (ids (k,), points (k, 2))})``."""


MAX_EXACT: float = 2.0**53
"""Frames and ids of a points CSV stay below this: every integer up to it is exact as a float
(the file is read as floats), and it fits int64."""


def read_points_csv(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a points CSV: returns ``frames (K,) 1-based, ids (K,), points (K, 2)`` px."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such points file")
    with open(path, newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's BOM is fine
        reader = csv.reader(fh)
        try:
            header = [h.strip().lower() for h in next(reader)]
        except StopIteration:
            raise ValueError(
                f"{path}: empty points file (expected a header frame,id,x,y or id,x,y)"
            ) from None
        except (UnicodeDecodeError, csv.Error) as exc:
            raise ValueError(f"{path}: not a text CSV file ({exc})") from None
        if header not in (["frame", "id", "x", "y"], ["id", "x", "y"]):
            raise ValueError(
                f"{path}:1: header must be 'frame,id,x,y' or 'id,x,y', got {','.join(header)!r}"
            )
        out = []
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise ValueError(f"{path}:{lineno}: expected {len(header)} columns, got {len(row)}")
            try:
                vals = [float(c) for c in row]
            except ValueError:
                raise ValueError(f"{path}:{lineno}: non-numeric value in {row!r}") from None
            if not np.isfinite(vals).all():
                raise ValueError(f"{path}:{lineno}: non-finite value in {row!r}")
            if len(vals) == 3:
                vals = [1.0, *vals]
            if vals[0] < 1 or vals[0] != int(vals[0]) or vals[1] != int(vals[1]):
                raise ValueError(
                    f"{path}:{lineno}: frame must be a positive integer and id an "
                    f"integer, got {row!r}"
                )
            if max(vals[0], abs(vals[1])) >= MAX_EXACT:  # beyond, a float is no exact integer
                raise ValueError(f"{path}:{lineno}: frame and id must be below 2**53, got {row!r}")
            out.append(vals)
    arr = np.asarray(out, dtype=np.float64).reshape(-1, 4)
    ids = arr[:, 1].astype(np.int64)
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"{path}: id {uniq[counts > 1][0]} is listed more than once")
    return arr[:, 0].astype(np.int64), ids, arr[:, 2:4]


def births_from_points(frames: np.ndarray, ids: np.ndarray, points: np.ndarray) -> Births:
    """Split points into the initial targets (frame 1) and births ``{t (0-based): (ids, pts)}``.

    ``frames (K,)`` 1-based, ``ids (K,)``, ``points (K, 2)`` px (as :func:`read_points_csv`).
    """
    init = (ids[frames == 1], points[frames == 1])
    births = {}
    for f in np.unique(frames[frames > 1]):
        sel = frames == f
        births[int(f) - 1] = (ids[sel], points[sel])
    return init, births


def births_from_ground_truth(ids: np.ndarray, points: np.ndarray) -> Births:
    """Initial targets and births from ground-truth tracks ``points (T, N, 2)``, ``ids (N,)``.

    Each id is born at its first present frame, at its ground-truth position there.
    """
    present = np.isfinite(points).all(-1)
    has = present.any(0)
    first = np.where(has, present.argmax(0), -1)
    init_sel = first == 0
    init = (ids[init_sel], points[0, init_sel])
    births = {}
    for t in np.unique(first[first > 0]):
        sel = first == t
        births[int(t)] = (ids[sel], points[t, sel])
    return init, births


def births_from_init(
    init: str | os.PathLike[str],
    length: int | None = None,
    gt_ids: np.ndarray | None = None,
    where: str = "",
) -> Births:
    """Births from a points CSV, checked against the sequence: frames within ``length`` and,
    when the sequence has ground truth, ids that it knows."""
    frames, ids, pts = read_points_csv(init)
    if length is not None and len(frames) and frames.max() > length:
        raise ValueError(
            f"{init}: frame {int(frames.max())} is beyond the {length} frames of {where}"
        )
    if not (frames == 1).any():  # a header alone once tracked nobody and exited 0
        raise ValueError(
            f"{init}: no target in the first frame (rows with frame 1, or id,x,y rows); "
            "the tracker needs at least one person to start from"
        )
    if gt_ids is not None and len(gt_ids) and len(ids):
        unknown = sorted(set(ids.tolist()) - set(np.asarray(gt_ids).tolist()))
        if unknown:
            raise ValueError(
                f"{init}: ids {unknown[:5]} are unknown to the ground truth of {where}"
            )
    return births_from_points(frames, ids, pts)
