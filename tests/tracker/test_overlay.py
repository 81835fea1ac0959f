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
