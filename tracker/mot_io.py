"""Point tracks <-> MOT text rows, and the points CSV that initialises real-video tracking.

Point tracks are written as head boxes of the template size centred on the point
(``bb_left = x - s/2``), one MOTChallenge result row per tracked point:
``frame,id,bb_left,bb_top,bb_width,bb_height,conf,-1,-1,-1`` (1-based frames). Reading takes
the box centre back.

Points CSV (``--init``): a header line and rows ``frame,id,x,y`` (pixels, 1-based frame) or
``id,x,y`` (all at frame 1). Rows at the first frame initialise the tracker; later rows are
births, as the papers initialise people entering the scene.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np


def tracks_to_mot_rows(ids: np.ndarray, positions: np.ndarray,
                       template_size: int) -> np.ndarray:
    """``(K, 10)`` MOT result rows for the finite points of ``positions`` ``(T, N, 2)``.

    >>> tracks_to_mot_rows(np.array([7]), np.array([[[10.0, 20.0]]]), 8).tolist()
    [[1.0, 7.0, 6.0, 16.0, 8.0, 8.0, 1.0, -1.0, -1.0, -1.0]]
    """
    positions = np.asarray(positions, dtype=np.float64)
    ids = np.asarray(ids, dtype=np.int64)
    if positions.ndim != 3 or positions.shape[1:] != (len(ids), 2):
        raise ValueError(f"positions must have shape (T, {len(ids)}, 2), got {positions.shape}")
    t, n = np.nonzero(np.isfinite(positions).all(-1))
    s = float(template_size)
    rows = np.empty((len(t), 10))
    rows[:, 0] = t + 1
    rows[:, 1] = ids[n]
    rows[:, 2:4] = positions[t, n] - s / 2.0
    rows[:, 4:6] = s
    rows[:, 6] = 1.0
    rows[:, 7:] = -1.0
    return rows


def mot_rows_to_tracks(rows: np.ndarray, length: int | None = None,
                       source: str = "results") -> tuple[np.ndarray, np.ndarray]:
    """Box centres of MOT rows as ``(ids (N,), positions (T, N, 2))``, NaN where absent.

    ``T = length`` when given (rows beyond it are an error), else the last frame.
    Duplicate ``(frame, id)`` rows are an error.
    """
    rows = np.asarray(rows, dtype=np.float64)
    if rows.size == 0:
        return np.zeros(0, np.int64), np.full((length or 0, 0, 2), np.nan)
    frames = rows[:, 0].astype(np.int64)
    ids_all = rows[:, 1].astype(np.int64)
    t_len = int(frames.max()) if length is None else int(length)
    if frames.min() < 1 or frames.max() > t_len:
        bad = frames[(frames < 1) | (frames > t_len)][0]
        raise ValueError(f"{source}: frame {bad} is outside the sequence (1..{t_len})")
    ids, col = np.unique(ids_all, return_inverse=True)
    key = (frames - 1) * len(ids) + col
    uniq, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        k = uniq[counts > 1][0]
        raise ValueError(f"{source}: id {ids[k % len(ids)]} appears twice in frame "
                         f"{k // len(ids) + 1}")
    pos = np.full((t_len, len(ids), 2), np.nan)
    pos[frames - 1, col, 0] = rows[:, 2] + rows[:, 4] / 2.0
    pos[frames - 1, col, 1] = rows[:, 3] + rows[:, 5] / 2.0
    return ids, pos


def read_points_csv(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray,
                                                           np.ndarray]:
    """Read a points CSV: returns ``frames (K,) 1-based, ids (K,), points (K, 2)`` px."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such points file")
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip().lower() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{path}: empty points file (expected a header frame,id,x,y "
                             "or id,x,y)") from None
        if header not in (["frame", "id", "x", "y"], ["id", "x", "y"]):
            raise ValueError(f"{path}:1: header must be 'frame,id,x,y' or 'id,x,y', got "
                             f"{','.join(header)!r}")
        out = []
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise ValueError(f"{path}:{lineno}: expected {len(header)} columns, got "
                                 f"{len(row)}")
            try:
                vals = [float(c) for c in row]
            except ValueError:
                raise ValueError(f"{path}:{lineno}: non-numeric value in {row!r}") from None
            if not np.isfinite(vals).all():
                raise ValueError(f"{path}:{lineno}: non-finite value in {row!r}")
            if len(vals) == 3:
                vals = [1.0, *vals]
            if vals[0] < 1 or vals[0] != int(vals[0]) or vals[1] != int(vals[1]):
                raise ValueError(f"{path}:{lineno}: frame must be a positive integer and id an "
                                 f"integer, got {row!r}")
            out.append(vals)
    arr = np.asarray(out, dtype=np.float64).reshape(-1, 4)
    ids = arr[:, 1].astype(np.int64)
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"{path}: id {uniq[counts > 1][0]} is listed more than once")
    return arr[:, 0].astype(np.int64), ids, arr[:, 2:4]


def births_from_points(frames: np.ndarray, ids: np.ndarray, points: np.ndarray):
    """Split points into the initial targets (frame 1) and births ``{t (0-based): (ids, pts)}``."""
    init = (ids[frames == 1], points[frames == 1])
    births = {}
    for f in np.unique(frames[frames > 1]):
        sel = frames == f
        births[int(f) - 1] = (ids[sel], points[sel])
    return init, births


def births_from_ground_truth(ids: np.ndarray, points: np.ndarray):
    """Initial targets and births from ground-truth tracks ``(T, N, 2)`` (synthetic data).

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
