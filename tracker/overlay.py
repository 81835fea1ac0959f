"""Overlay video: ground truth in green, tracks in yellow, as in the papers' figures.

Each point is drawn as its head box (template size) with a short tail of its last positions
(not joined across frames it was absent from), tracks optionally with their ids; a caption
at the top left gives the frame number (1-based, as the MOT files count frames) and the
colour legend.
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
WHITE = (255, 255, 255)
TAIL = 8
"""Frames of trajectory drawn behind each point."""


def draw_points(
    frame: np.ndarray,
    points: np.ndarray,
    t: int,
    size: int,
    colour,
    tail: int = TAIL,
    ids: np.ndarray | None = None,
) -> None:
    """Draw, in place on ``frame`` (H, W, 3) uint8 BGR, a ``size`` px box around each point of
    frame ``t`` of ``points`` (T, N, 2) px (NaN = absent) and its last ``tail`` frames, and,
    with ``ids`` ((N,) ints), each point's id at its box's top right corner.

    A tail is the point's last frames without a gap: a target that was absent is not joined
    across the frames it missed (its tail starts again where it came back)."""
    cur = points[t]
    ok = np.isfinite(cur).all(1)
    half = size / 2.0
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.3
    for i in np.flatnonzero(ok):
        x, y = cur[i]
        cv2.rectangle(
            frame,
            (int(round(x - half)), int(round(y - half))),
            (int(round(x + half)), int(round(y + half))),
            colour,
            1,
        )
        if ids is not None:
            at = (int(round(x + half)) + 1, int(round(y - half)) + 3)
            cv2.putText(frame, str(int(ids[i])), at, font, scale, colour, 1, cv2.LINE_AA)
    if tail > 1 and t > 0:
        seg = points[max(0, t - tail) : t + 1]
        good = np.isfinite(seg).all(-1)
        # each point's frames present without a break up to t (the last row)
        back = good[::-1]
        run = np.where(back.all(0), len(seg), np.argmin(back, axis=0))
        for i in np.flatnonzero(ok & (run > 1)):
            pts = seg[len(seg) - run[i] :, i]
            cv2.polylines(frame, [np.rint(pts).astype(np.int32)], False, colour, 1)


def draw_caption(frame: np.ndarray, t: int, legend: Iterable[tuple[str, tuple]]) -> None:
    """Draw, in place on ``frame``, ``frame {t + 1}`` and each ``(label, colour)`` of
    ``legend`` in its colour, on a darkened strip at the top left."""
    font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1
    parts = [(f"frame {t + 1}", WHITE), *legend]
    sizes = [cv2.getTextSize(text, font, scale, thick)[0] for text, _ in parts]
    gap = 8
    h = min(frame.shape[0], max(s[1] for s in sizes) + 8)
    w = min(frame.shape[1], sum(s[0] for s in sizes) + gap * (len(parts) - 1) + 6)
    frame[:h, :w] //= 3  # darkened, not hidden: the people under it stay visible
    x = 3
    for (text, colour), (tw, _) in zip(parts, sizes, strict=True):
        cv2.putText(frame, text, (x, h - 4), font, scale, colour, thick, cv2.LINE_AA)
        x += tw + gap


def write_overlay(
    path: str | os.PathLike[str],
    frames: Iterable[np.ndarray],
    template_size: int,
    tracks: np.ndarray | None = None,
    ground_truth: np.ndarray | None = None,
    fps: float = 25.0,
    tail: int = TAIL,
    caption: bool = True,
    track_ids: np.ndarray | None = None,
) -> Path:
    """Write ``frames`` with ground truth (green) and tracks (yellow) drawn on top.

    Parameters
    ----------
    path : output ``.mp4``, of the frames' size (an odd side gets a black column or row more:
        MPEG-4 needs even sides)
    frames : iterable of (H, W, 3) uint8 BGR
    template_size : int
        Side of the drawn head boxes, px.
    tracks, ground_truth : (T, N, 2) float, optional
        Pixel positions, NaN where absent (frames beyond their length are drawn bare).
    fps : float
        Frame rate of the video.
    caption : bool
        Draw the frame number and the legend (``ground truth`` green, ``tracks`` yellow, each
        where given) at the top left.
    track_ids : (N,) int, optional
        The tracks' ids (the MOT file's), drawn beside their boxes.
    """
    path = Path(path)
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    if track_ids is not None and (tracks is None or len(track_ids) != tracks.shape[1]):
        got = "no tracks" if tracks is None else f"{tracks.shape[1]} tracks"
        raise ValueError(f"track_ids: {len(track_ids)} ids for {got}")
    legend = [
        (label, colour)
        for label, colour, points in (
            ("ground truth", GREEN, ground_truth),
            ("tracks", YELLOW, tracks),
        )
        if points is not None
    ]
    writer = None
    with atomic_path(path, suffix=path.suffix or ".mp4") as tmp:
        try:
            for t, frame in enumerate(frames):
                h, w = frame.shape[:2]
                if writer is None:
                    # MPEG-4 frames have even sides: an odd last column or row would be cut
                    # off in silence, so it is kept and a black one added beside it
                    size = (w + w % 2, h + h % 2)
                    writer = cv2.VideoWriter(
                        os.fspath(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size
                    )
                    if not writer.isOpened():
                        raise ValueError(f"{path}: OpenCV cannot write an MP4 video here")
                img = np.ascontiguousarray(frame).copy()
                if (w, h) != size and (w + w % 2, h + h % 2) == size:
                    img = cv2.copyMakeBorder(
                        img, 0, size[1] - h, 0, size[0] - w, cv2.BORDER_CONSTANT
                    )
                if ground_truth is not None and t < len(ground_truth):
                    draw_points(img, ground_truth, t, template_size, GREEN, tail)
                if tracks is not None and t < len(tracks):
                    draw_points(img, tracks, t, template_size, YELLOW, tail, track_ids)
                if caption:
                    draw_caption(img, t, legend)
                writer.write(img)
        finally:
            if writer is not None:
                writer.release()
        if writer is None:
            raise ValueError(f"{path}: no frames to write")
        require_whole_video(tmp, t + 1, path)
    return path
