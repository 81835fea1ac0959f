"""Overlay video: ground truth in green, tracks in yellow, as in the papers' figures.

Each point is drawn as its head box (template size) with a short tail of its last positions.
Written with ``cv2.VideoWriter`` (MPEG-4 part 2, ``mp4v``) to a temporary file, then renamed,
so that an interrupted run never leaves a truncated video that looks complete.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from crowdsim.atomic import atomic_path, require_whole_video

GREEN = (0, 255, 0)
YELLOW = (0, 255, 255)
TAIL = 8
"""Frames of trajectory drawn behind each point."""


def draw_points(
    frame: np.ndarray, points: np.ndarray, t: int, size: int, colour, tail: int = TAIL
) -> None:
    """Draw, in place on ``frame`` (H, W, 3) uint8 BGR, a ``size`` px box around each point of
    frame ``t`` of ``points`` (T, N, 2) px (NaN = absent) and its last ``tail`` frames."""
    cur = points[t]
    ok = np.isfinite(cur).all(1)
    half = size / 2.0
    for i in np.flatnonzero(ok):
        x, y = cur[i]
        cv2.rectangle(
            frame,
            (int(round(x - half)), int(round(y - half))),
            (int(round(x + half)), int(round(y + half))),
            colour,
            1,
        )
    if tail > 1 and t > 0:
        seg = points[max(0, t - tail) : t + 1]
        good = np.isfinite(seg).all(-1)
        for i in np.flatnonzero(ok):
            pts = seg[good[:, i], i]
            if len(pts) > 1:
                cv2.polylines(frame, [np.rint(pts).astype(np.int32)], False, colour, 1)


def write_overlay(
    path: str | os.PathLike[str],
    frames: Iterable[np.ndarray],
    template_size: int,
    tracks: np.ndarray | None = None,
    ground_truth: np.ndarray | None = None,
    fps: float = 25.0,
    tail: int = TAIL,
) -> Path:
    """Write ``frames`` with ground truth (green) and tracks (yellow) drawn on top.

    Parameters
    ----------
    path : output ``.mp4``
    frames : iterable of (H, W, 3) uint8 BGR
    template_size : int
        Side of the drawn head boxes, px.
    tracks, ground_truth : (T, N, 2) float, optional
        Pixel positions, NaN where absent (frames beyond their length are drawn bare).
    fps : float
        Frame rate of the video.
    """
    path = Path(path)
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    writer = None
    with atomic_path(path, suffix=path.suffix or ".mp4") as tmp:
        try:
            for t, frame in enumerate(frames):
                if writer is None:
                    h, w = frame.shape[:2]
                    writer = cv2.VideoWriter(
                        os.fspath(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h)
                    )
                    if not writer.isOpened():
                        raise ValueError(f"{path}: OpenCV cannot write an MP4 video here")
                img = np.ascontiguousarray(frame).copy()
                if ground_truth is not None and t < len(ground_truth):
                    draw_points(img, ground_truth, t, template_size, GREEN, tail)
                if tracks is not None and t < len(tracks):
                    draw_points(img, tracks, t, template_size, YELLOW, tail)
                writer.write(img)
        finally:
            if writer is not None:
                writer.release()
        if writer is None:
            raise ValueError(f"{path}: no frames to write")
        require_whole_video(tmp, t + 1, path)
    return path
