"""Fixtures shared across the test folders."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_SLOW_JPEG = """\
import time

import crowdsim.render as _render

_encode = _render.encode_jpeg


def _slow_encode(*args, **kwargs):
    time.sleep({delay})
    return _encode(*args, **kwargs)


_render.encode_jpeg = _slow_encode
"""


@pytest.fixture()
def slow_jpeg_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """An environment for subprocesses in which every JPEG takes 30 ms more to encode.

    A ``sitecustomize`` module on ``PYTHONPATH`` slows :func:`crowdsim.render.encode_jpeg` in
    every Python process started with it, spawned pool workers included. Tests that stop a
    render or a generation mid-sequence use it, so they catch the writers mid-way by design
    instead of by winning a race against a fast machine (unthrottled, a 600-frame sequence took
    1.5 s on CI and finished before the test saw it).
    """
    site = tmp_path_factory.mktemp("slow-jpeg-site")  # outside the test's tmp_path
    (site / "sitecustomize.py").write_text(_SLOW_JPEG.format(delay=0.03))
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(ROOT)]))


@pytest.fixture()
def run_benchmark():
    """``run(name, *args)``: ``benchmarks/<name>`` run with ``args`` in a fresh interpreter,
    the ``subprocess.CompletedProcess`` with text output."""

    def run(name: str, *args: str) -> subprocess.CompletedProcess[str]:
        script = ROOT / "benchmarks" / name
        return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True)

    return run


class _DroppingVideoWriter:
    """What ``cv2.VideoWriter`` does on a full disk: it opens, and ``write()`` and
    ``release()`` report nothing while the frames never reach the file."""

    def __init__(self, path, *args):
        with open(path, "wb") as fh:
            fh.write(b"\0" * 4096)

    def isOpened(self):
        return True

    def write(self, img):
        pass

    def release(self):
        pass


@pytest.fixture()
def dropping_video_writer(monkeypatch):
    """``cv2.VideoWriter`` replaced by one that silently drops every frame (a full disk)."""
    import cv2

    monkeypatch.setattr(cv2, "VideoWriter", _DroppingVideoWriter)


def _study_disk_full() -> None:
    import sqlite3

    import optuna
    import sqlalchemy.exc

    try:
        try:
            raise sqlite3.OperationalError("database or disk is full")
        except sqlite3.OperationalError as low:
            raise sqlalchemy.exc.OperationalError("UPDATE trials ...", {}, low) from low
    except sqlalchemy.exc.OperationalError as mid:
        raise optuna.exceptions.StorageInternalError(
            "An exception is raised during the commit."
        ) from mid


@pytest.fixture()
def study_disk_full():
    """A function raising what an Optuna study's commit raises on a full disk (Optuna's
    ``StorageInternalError`` over SQLAlchemy over ``sqlite3``), as seen on a filled tmpfs."""
    return _study_disk_full


def _write_scene_folder(scene, folder: Path) -> Path:
    import cv2

    from synth_data.mot import write_mot, write_seqinfo
    from tracker.mot_io import tracks_to_mot_rows

    (folder / "img1").mkdir(parents=True)
    (folder / "gt").mkdir()
    for i, f in enumerate(scene.frames, start=1):
        cv2.imwrite(str(folder / "img1" / f"{i:06d}.png"), f)
    h, w = scene.frames[0].shape[:2]
    write_seqinfo(
        folder,
        name="tiny",
        frame_rate=25,
        length=len(scene.frames),
        width=w,
        height=h,
        template_size=scene.template_size,
        im_ext=".png",
    )
    rows = tracks_to_mot_rows(scene.ids, scene.points, scene.template_size)
    rows[:, 7] = 1  # class: pedestrian
    rows[:, 8] = 1  # visibility
    write_mot(folder / "gt" / "gt.txt", rows[:, :9])
    return folder


@pytest.fixture()
def scene_folder():
    """``write(scene, folder) -> folder``: a hand-built scene (:func:`tracker.testing.
    make_scene`) as a MOT sequence folder named ``tiny``: PNG frames, its ground truth."""
    return _write_scene_folder
