"""Point tracks <-> MOT text rows.

Point tracks are written as head boxes of the template size centred on the point
(``bb_left = x - s/2``), one MOTChallenge result row per tracked point:
``frame,id,bb_left,bb_top,bb_width,bb_height,conf,-1,-1,-1`` (1-based frames). Reading takes
the box centre back.

Where the starting targets and births come from (ground truth, or the points CSV of
``--init``) is the sequence's business: ``births()`` of :mod:`synth_data.sequence` sources.
"""

from __future__ import annotations

import numpy as np

from crowdsim.checks import checked_ids, require_memory, require_number


def tracks_to_mot_rows(ids: np.ndarray, positions: np.ndarray, template_size: int) -> np.ndarray:
    """``(K, 10)`` MOT result rows for the finite points of ``positions`` ``(T, N, 2)``.

    >>> tracks_to_mot_rows(np.array([7]), np.array([[[10.0, 20.0]]]), 8).tolist()
    [[1.0, 7.0, 6.0, 16.0, 8.0, 8.0, 1.0, -1.0, -1.0, -1.0]]
    """
    positions = np.asarray(positions, dtype=np.float64)
    ids = checked_ids("ids", ids)
    require_number("tracks_to_mot_rows", "template_size", template_size, lo=0, lo_open=True)
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


def mot_rows_to_tracks(
    rows: np.ndarray,
    length: int | None = None,
    source: str = "results",
    head_in_body: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Box centres of MOT rows as ``(ids (N,), positions (T, N, 2))``, NaN where absent.

    ``T = length`` when given (rows beyond it are an error), else the last frame.
    Duplicate ``(frame, id)`` rows are an error. ``head_in_body``: the rows are full-body
    boxes, and the point is the head, this share of the box's height below its top (as a
    MOTChallenge sequence's ground truth is read: :data:`synth_data.mot.HEAD_IN_BODY`).
    """
    if length is not None:
        require_number(source, "length", length, lo=0, integer=True)
    rows = np.asarray(rows, dtype=np.float64)
    if rows.size == 0:
        return np.zeros(0, np.int64), np.full((length or 0, 0, 2), np.nan)
    if rows.ndim != 2 or rows.shape[1] < 6:
        raise ValueError(
            f"{source}: MOT rows need at least 6 columns (frame, id, bb_left, bb_top, bb_width, "
            f"bb_height), got shape {rows.shape}"
        )
    boxes = rows[:, 2:6]
    bad = ~np.isfinite(boxes).all(1) | (boxes[:, 2] <= 0) | (boxes[:, 3] <= 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{source}: row {i + 1}: box {boxes[i].tolist()} is not a finite box of positive size"
        )
    # ids and frames are whole numbers that float64 holds exactly: truncating id 2.5, or
    # reading 2^53 + 1 as 2^53, would merge people; truncating frame 1.5 would move a row
    for col, what, limit, says in (
        (1, "id", 2.0**53, "is not a whole number below 2^53"),
        (0, "frame", 2.0**62, "is not a whole number"),
    ):
        raw = rows[:, col]
        bad = (raw != np.round(raw)) | (np.abs(raw) >= limit)  # NaN too
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{source}: row {i + 1}: {what} {raw[i]:g} {says}")
    frames = rows[:, 0].astype(np.int64)
    ids_all = rows[:, 1].astype(np.int64)
    t_len = int(frames.max()) if length is None else int(length)
    if frames.min() < 1 or frames.max() > t_len:
        bad = frames[(frames < 1) | (frames > t_len)][0]
        raise ValueError(f"{source}: frame {bad} is outside the sequence (1..{t_len})")
    ids, col = np.unique(ids_all, return_inverse=True)
    # a frame number far past the rows (1e12) would ask for terabytes of NaN
    require_memory(
        f"{source}: tracks of {len(ids)} ids over {t_len} frames", 16.0 * t_len * len(ids)
    )
    key = (frames - 1) * len(ids) + col
    uniq, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        k = uniq[counts > 1][0]
        raise ValueError(
            f"{source}: id {ids[k % len(ids)]} appears twice in frame {k // len(ids) + 1}"
        )
    pos = np.full((t_len, len(ids), 2), np.nan)
    pos[frames - 1, col, 0] = rows[:, 2] + rows[:, 4] / 2.0
    below_top = 0.5 if head_in_body is None else float(head_in_body)
    pos[frames - 1, col, 1] = rows[:, 3] + below_top * rows[:, 5]
    return ids, pos
