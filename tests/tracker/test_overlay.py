"""``tracker.overlay.write_overlay``: OpenCV's video writer reports no I/O error, so a video
that did not reach the disk whole must be caught by reading it back, never renamed into place."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tracker import overlay


def _noise(n: int, h: int = 240, w: int = 320) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def test_a_whole_video_reads_back_with_every_frame(tmp_path):
    path = overlay.write_overlay(tmp_path / "v.mp4", _noise(5, 48, 64), 8, fps=25.0)
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    cap.release()


def test_a_writer_that_drops_frames_silently_is_caught(tmp_path, dropping_video_writer):
    with pytest.raises(OSError) as caught:
        overlay.write_overlay(tmp_path / "v.mp4", _noise(3, 32, 32), 8, fps=25.0)
    from crowdsim.atomic import describe_os_error

    assert describe_os_error(caught.value) == (
        f"{tmp_path / 'v.mp4'}: the video was not written whole (it reads back with 0 of 3 "
        "frames); is the disk full?"
    )
    assert os.listdir(tmp_path) == []  # neither the video nor its temporary file


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.geteuid() != 0 or not shutil.which("mount"),
    reason="mounts a tmpfs (Linux, root)",
)
def test_a_disk_that_fills_during_the_video_leaves_no_video(tmp_path):
    """A real 64 KiB tmpfs with 16 KiB left: the writer opens, the frames do not fit."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)])
    if mounted.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        free = shutil.disk_usage(disk).free
        (disk / "filler").write_bytes(b"\0" * (free - 16 * 1024))
        with pytest.raises((OSError, ValueError), match="v.mp4"):
            overlay.write_overlay(disk / "v.mp4", _noise(10), 12, fps=25.0)
        assert sorted(os.listdir(disk)) == ["filler"]
    finally:
        with contextlib.suppress(OSError):
            subprocess.run(["umount", "-l", str(disk)], check=False)


def _read_all(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


def _coloured(region: np.ndarray, bgr) -> int:
    """Pixels of ``region`` within 100 grey levels of ``bgr`` in every channel (MPEG-4's
    halved chroma smears thin coloured text)."""
    return int((np.abs(region.astype(int) - np.array(bgr)) < 100).all(-1).sum())


def test_the_overlay_carries_its_frame_number_and_legend(tmp_path):
    """Without a caption a viewer cannot tell which colour is the ground truth nor which
    frame of the results file is shown: each frame names its number and the colours drawn."""
    n, h, w = 3, 120, 320
    frames = [np.full((h, w, 3), 90, np.uint8) for _ in range(n)]
    pts = np.full((n, 1, 2), [250.0, 90.0])  # far from the caption
    path = overlay.write_overlay(
        tmp_path / "v.mp4", frames, 12, tracks=pts, ground_truth=pts + 20, fps=25.0
    )
    got = _read_all(path)
    assert len(got) == n
    strip = [f[:14] for f in got]
    assert _coloured(strip[0], overlay.GREEN) > 10  # "ground truth" in green
    assert _coloured(strip[0], overlay.YELLOW) > 10  # "tracks" in yellow
    assert _coloured(strip[0], overlay.WHITE) > 10  # "frame 1"
    # the counter moves: the frame numbers differ where the legend does not
    assert np.abs(strip[0].astype(int) - strip[1]).max() > 60
    # only what is drawn is in the legend; caption=False leaves the frame bare
    bare = overlay.write_overlay(tmp_path / "t.mp4", frames, 12, tracks=pts, fps=25.0)
    assert _coloured(_read_all(bare)[0][:14], overlay.GREEN) == 0
    off = overlay.write_overlay(tmp_path / "o.mp4", frames, 12, fps=25.0, caption=False)
    assert np.abs(_read_all(off)[0][:14].astype(int) - 90).max() < 20


def test_overlay_boxes_sit_on_the_points_of_the_results(tmp_path):
    """The drawn box is centred on the tracked point (the MOT row's box centre)."""
    frames = [np.zeros((100, 160, 3), np.uint8)]
    pts = np.array([[[80.0, 60.0]]])
    path = overlay.write_overlay(tmp_path / "v.mp4", frames, 12, tracks=pts, fps=25.0)
    frame = _read_all(path)[0]
    yellow = (frame[20:, :, 1] > 150) & (frame[20:, :, 2] > 150)
    rows, cols = np.nonzero(yellow)
    assert abs((cols.min() + cols.max()) / 2 - 80) <= 0.5
    assert abs((rows.min() + rows.max()) / 2 + 20 - 60) <= 0.5


def test_an_odd_sized_frame_keeps_its_last_column_and_row(tmp_path):
    """MPEG-4 frames have even sides: OpenCV cut a 161x121 overlay to 160x120 in silence,
    with whatever was drawn on the last column and row; they are kept, a black one added."""
    frames = [np.full((121, 161, 3), 90, np.uint8) for _ in range(2)]
    pts = np.full((2, 1, 2), [155.0, 115.0])  # its box's right, bottom edges: x 160, y 120
    path = overlay.write_overlay(tmp_path / "v.mp4", frames, 10, tracks=pts, fps=25.0)
    got = _read_all(path)
    assert len(got) == 2 and got[0].shape == (122, 162, 3)
    yellow = (got[0][:, :, 1] > 150) & (got[0][:, :, 2] > 150) & (got[0][:, :, 0] < 120)
    assert yellow[110:121, 160].sum() >= 8 and yellow[120, 150:161].sum() >= 8
    assert np.abs(got[0][20:110, 10:150].astype(int) - 90).max() < 20  # the frame itself


def test_a_tail_is_not_joined_across_frames_its_target_missed():
    """A target absent for a frame and back 80 px on: its tail starts again where it came
    back (a line was drawn across the frames it missed, as if it had walked there)."""
    pts = np.full((6, 1, 2), np.nan)
    pts[:3, 0] = [[20.0, 50.0], [22.0, 50.0], [24.0, 50.0]]
    pts[4:, 0] = [[100.0, 50.0], [102.0, 50.0]]
    img = np.zeros((100, 160, 3), np.uint8)
    overlay.draw_points(img, pts, 5, 6, overlay.YELLOW)
    drawn = img.any(-1)
    assert not drawn[:, 30:95].any()  # nothing between where it left and where it came back
    assert drawn[50, 100:103].all()  # its tail since it came back
    whole = pts.copy()
    whole[3, 0] = [60.0, 50.0]  # present throughout: the whole tail is drawn
    img[:] = 0
    overlay.draw_points(img, whole, 5, 6, overlay.YELLOW)
    assert img[50, 30:95].any(-1).all()


def test_track_ids_are_drawn_beside_their_boxes(tmp_path):
    """``track_ids`` writes each track's id at its box's top right corner; without them
    nothing is drawn there. A count that does not match the tracks is refused by name."""
    pts = np.array([[[40.0, 50.0]]])
    bare = np.zeros((100, 160, 3), np.uint8)
    overlay.draw_points(bare, pts, 0, 12, overlay.YELLOW)
    named = bare.copy()
    overlay.draw_points(named, pts, 0, 12, overlay.YELLOW, ids=np.array([47]))
    beside = np.s_[36:50, 47:70]  # right of the box's top edge (x 46, y 44)
    assert not bare[beside].any() and named[beside].any(-1).sum() > 10
    assert np.array_equal(named[:, :46], bare[:, :46])  # the box itself is the same
    frames = [np.zeros((100, 160, 3), np.uint8)]
    with pytest.raises(ValueError, match="track_ids: 2 ids for 1 tracks"):
        overlay.write_overlay(tmp_path / "v.mp4", frames, 12, tracks=pts, track_ids=[1, 2])
    assert not (tmp_path / "v.mp4").exists()
