"""Render trajectories into a MOTChallenge sequence folder, atomically.

:func:`write_sequence` renders every frame, writes ``img1/`` JPEGs (and optionally
``video.mp4``), ``gt/gt.txt``, ``gt/agents.csv``, ``seqinfo.ini``, ``meta.json`` and
``checksums.json`` (SHA-256 of every other file) into a temporary sibling folder
``.tmp-<name>-<pid>``, then renames it to its final name. A folder with the final name is
therefore always complete; ``checksums.json`` lets a later run verify it.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from synth_data.mot import write_agents_csv, write_mot, write_seqinfo

CHECKSUMS_FILE = "checksums.json"
TMP_PREFIX = ".tmp-"


def package_versions() -> dict[str, str]:
    """Versions of the packages that shape the output (for ``meta.json``)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for dist in ("crowdsim", "numpy", "scipy", "pymunk", "numba", "opencv-python-headless"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    import cv2

    out["cv2"] = cv2.__version__
    return out


def mot_ids(ids: np.ndarray) -> np.ndarray:
    """MOT ids (>= 1) of trajectory ids: ``id + 1`` when all ids are >= 0, else rank + 1."""
    ids = np.asarray(ids, dtype=np.int64)
    if len(ids) == 0 or ids.min() >= 0:
        return ids + 1
    return np.argsort(np.argsort(ids)) + 1


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def tmp_dir_for(out_dir: Path) -> Path:
    """The temporary folder this process uses while writing ``out_dir``."""
    return out_dir.parent / f"{TMP_PREFIX}{out_dir.name}-{os.getpid()}"


def write_sequence(out_dir: str | os.PathLike[str], traj: Any, *, camera: Any, appearance: Any,
                   seed: int, name: str | None = None, meta: dict[str, Any] | None = None,
                   images: bool = True, video: bool = False, overwrite: bool = False,
                   progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Render ``traj`` through ``camera`` into the sequence folder ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Final sequence folder; its parent is created if needed.
    traj : crowdsim.trajectories.Trajectories
        One row per frame (``traj.dt`` sets the frame rate).
    camera : crowdsim.camera.Camera
    appearance : crowdsim.appearance_model.AppearanceParams
    seed : int
        Seed of the rendering randomness.
    name : str, optional
        Sequence name in seqinfo.ini (default: the folder name).
    meta : dict, optional
        Extra JSON-serialisable content of ``meta.json`` (typically ``{"spec": ...}``).
    images, video : bool
        Write ``img1/*.jpg`` and/or ``video.mp4``; at least one.
    overwrite : bool
        Replace an existing ``out_dir``; otherwise an existing folder raises FileExistsError.
    progress : callable, optional
        Called with ``1`` after each rendered frame.

    Returns
    -------
    dict
        ``{"name", "frames", "files": {relative path: sha256}, "bytes"}``.
    """
    import cv2

    from crowdsim.render import SceneRenderer, encode_jpeg, gt_rows, prepare_agents

    out_dir = Path(out_dir)
    name = name or out_dir.name
    if not (images or video):
        raise ValueError("output: at least one of images or video must be true")
    if out_dir.exists() and not overwrite:
        raise FileExistsError(f"{out_dir} already exists; pass --overwrite to replace it")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_dir_for(out_dir)
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "gt").mkdir(parents=True)
    checksums: dict[str, str] = {}
    total = 0
    try:
        tracks = prepare_agents(traj, camera, appearance, seed)
        renderer = SceneRenderer(camera, appearance, seed=seed, fps=traj.fps)
        n_frames = tracks.n_frames
        frame = np.empty((camera.height, camera.width, 3), np.uint8)
        writer = None
        if video:
            writer = cv2.VideoWriter(str(tmp / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                                     float(traj.fps), (camera.width, camera.height))
            if not writer.isOpened():
                raise RuntimeError("OpenCV cannot write mp4v video on this machine")
        if images:
            (tmp / "img1").mkdir()
        try:
            for t in range(n_frames):
                renderer.render_tracks(tracks, t, out=frame)
                if images:
                    data = encode_jpeg(frame, appearance.jpeg_quality)
                    rel = f"img1/{t + 1:06d}.jpg"
                    with open(tmp / rel, "wb") as fh:
                        fh.write(data)
                    checksums[rel] = hashlib.sha256(data).hexdigest()
                    total += len(data)
                if writer is not None:
                    writer.write(frame)
                if progress is not None:
                    progress(1)
        finally:
            if writer is not None:
                writer.release()
        mids = mot_ids(tracks.ids)
        rows = gt_rows(tracks, camera, appearance.template_px, mids)
        write_mot(tmp / "gt" / "gt.txt", rows)
        seen = np.isin(mids, np.unique(rows[:, 1]).astype(np.int64)) if len(rows) else \
            np.zeros(len(mids), bool)
        attrs = traj.attributes
        write_agents_csv(tmp / "gt" / "agents.csv", {
            "id": mids[seen], "group": attrs["group"][seen], "prominent": tracks.prominent[seen],
            "anomaly": attrs["anomaly"][seen], "appearance": tracks.appearance[seen]})
        write_seqinfo(tmp, name=name, frame_rate=traj.fps, length=n_frames, width=camera.width,
                      height=camera.height, template_size=appearance.template_px)
        meta_out = dict(meta or {})
        meta_out.setdefault("seed", int(seed))
        meta_out["camera"] = {"px_per_m": camera.px_per_m, "width": camera.width,
                              "height": camera.height, "center": list(camera.center),
                              "tilt_deg": camera.tilt_deg, "distance_m": camera.distance_m,
                              "jitter_px": camera.jitter_px, "seed": camera.seed}
        meta_out["appearance"] = appearance.to_dict()
        meta_out["frames"] = n_frames
        meta_out["versions"] = package_versions()
        (tmp / "meta.json").write_text(json.dumps(meta_out, indent=2, sort_keys=True) + "\n")
        for rel in ("gt/gt.txt", "gt/agents.csv", "seqinfo.ini", "meta.json") + \
                (("video.mp4",) if video else ()):
            checksums[rel] = sha256_file(tmp / rel)
            total += (tmp / rel).stat().st_size
        checksums = dict(sorted(checksums.items()))
        (tmp / CHECKSUMS_FILE).write_text(json.dumps(checksums, indent=0) + "\n")
        _fsync_dir(tmp)
        if out_dir.exists():
            old = out_dir.parent / f"{TMP_PREFIX}old-{out_dir.name}-{os.getpid()}"
            os.replace(out_dir, old)
            os.replace(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"name": name, "frames": n_frames, "files": checksums, "bytes": total}


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platform without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def verify_sequence(seq_dir: str | os.PathLike[str]) -> dict[str, str] | None:
    """The checksums of a complete sequence folder, or None if it is incomplete or corrupt."""
    seq_dir = Path(seq_dir)
    listing = seq_dir / CHECKSUMS_FILE
    if not listing.is_file():
        return None
    try:
        checksums = json.loads(listing.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(checksums, dict) or not checksums:
        return None
    for rel, digest in checksums.items():
        p = seq_dir / rel
        if not p.is_file() or sha256_file(p) != digest:
            return None
    return checksums
