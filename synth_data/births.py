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
from collections.abc import Callable, Mapping
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
        if header[:2] == ["frame", "detection"]:
            raise ValueError(
                f"{path}: per-frame detections (crowdsim detect --frames N or --all), not the "
                "people to start from: give --init the points of frame 1 (crowdsim detect "
                "without --frames), or --init detect"
            )
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


def births_from_ground_truth(
    ids: np.ndarray, points: np.ndarray, size: tuple[int, int] | None = None
) -> Births:
    """Initial targets and births from ground-truth tracks ``points (T, N, 2)``, ``ids (N,)``.

    Each id is born at its first present frame, at its ground-truth position there. With
    ``size`` (the frames' width and height), at its first frame inside the image: a real MOT
    file annotates people partly outside it (a body box past the left edge puts its head
    point at x < 0), and a tracker refuses a target that starts outside the image, so such a
    person is born when the point enters (never, if it stays outside).
    """
    present = np.isfinite(points).all(-1)
    if size is not None:
        w, h = size
        with np.errstate(invalid="ignore"):
            present &= (
                (points[..., 0] >= 0)
                & (points[..., 0] <= w - 1)
                & (points[..., 1] >= 0)
                & (points[..., 1] <= h - 1)
            )
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
                f"{init}: ids {unknown[:5]} are unknown to the ground truth of {where} (a "
                "sequence with ground truth takes its ids; --init detect gives the detector's "
                "heads the ids of the people they find)"
            )
    return births_from_points(frames, ids, pts)


def births_from_detections(points: np.ndarray, first_id: int = 1) -> Births:
    """Initial targets from the heads a detector found in the first frame: ids
    ``first_id, first_id + 1, ...`` in the detector's order, no later births."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return (np.arange(first_id, first_id + len(pts), dtype=np.int64), pts), {}


class DetectionBirths:
    """Births found by a head detector while tracking (``crowdsim track --births detect``).

    Every ``every`` frames the detector runs on the frame; each head farther than ``radius``
    px from every current target starts a new track with a fresh id. Scheduled births (a
    points CSV, the ground truth) are kept and added at their own frames. Called by
    :meth:`tracker.base.Tracker.track` with the targets' positions in the previous frame.

    Parameters
    ----------
    detect_points : callable
        ``detect_points(frame) -> (points (m, 2) px, scores (m,))``, e.g.
        :meth:`tracker.detect.HeadDetector.detect_points`.
    every : int
        Frames between detections (``>= 1``).
    radius : float
        A head within this distance (px) of a target is that target, not a newcomer.
    first_id : int
        The first id given to a newcomer (above every id the sequence already uses).
    scheduled : mapping, optional
        ``{t: (ids, points)}`` births known in advance.

    >>> found = lambda frame: (np.array([[10.0, 10.0], [40.0, 12.0]]), np.ones(2))
    >>> births = DetectionBirths(found, every=2, radius=6.0, first_id=100)
    >>> frame = np.zeros((32, 64, 3), np.uint8)
    >>> births(1, frame, np.array([1]), np.array([[11.0, 9.0]])) is None
    True
    >>> ids, pts = births(2, frame, np.array([1]), np.array([[11.0, 9.0]]))
    >>> ids.tolist(), pts.tolist(), births.born
    ([100], [[40.0, 12.0]], 1)
    """

    def __init__(
        self,
        detect_points: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
        *,
        every: int = 10,
        radius: float,
        first_id: int,
        scheduled: Mapping[int, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        if not isinstance(every, (int, np.integer)) or isinstance(every, bool) or every < 1:
            raise ValueError(f"detection births: every must be a whole number >= 1, got {every!r}")
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"detection births: radius must be > 0 px, got {radius!r}")
        self.detect_points = detect_points
        self.every = int(every)
        self.radius = float(radius)
        self.next_id = int(first_id)
        self.scheduled = dict(scheduled or {})
        self.born = 0

    def __call__(
        self, t: int, frame: np.ndarray, ids: np.ndarray, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        known = self.scheduled.get(t)
        if t % self.every:
            return known
        found, _ = self.detect_points(frame)
        found = np.asarray(found, dtype=np.float64).reshape(-1, 2)
        current = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if known is not None:
            current = np.concatenate([current, np.asarray(known[1], np.float64).reshape(-1, 2)])
        current = current[np.isfinite(current).all(1)]
        if len(found) and len(current):
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(current).query(found, distance_upper_bound=self.radius)
            found = found[~np.isfinite(dist)]
        if not len(found):
            return known
        new_ids = np.arange(self.next_id, self.next_id + len(found), dtype=np.int64)
        self.next_id += len(found)
        self.born += len(found)
        if known is None:
            return new_ids, found
        return (
            np.concatenate([np.asarray(known[0], np.int64), new_ids]),
            np.concatenate([np.asarray(known[1], np.float64).reshape(-1, 2), found]),
        )
