"""Render trajectories into a MOTChallenge sequence folder, atomically.

:func:`write_sequence` renders every frame, writes ``img1/`` JPEGs (and optionally
``video.mp4``), ``gt/gt.txt`` (rows built by :func:`synth_data.mot.gt_rows`, with the
visibility column measured from the drawing), ``gt/agents.csv``, ``seqinfo.ini``, ``meta.json`` and
``checksums.json`` (SHA-256 of every other file) into a temporary sibling folder
``.crowdsim-tmp-<name>-<pid>-<token>``, then renames it to its final name. A folder with the
final name is therefore always complete; ``checksums.json`` lets a later run verify it.

Video: with ``appearance.video_kbps > 0`` the frames first go through a video codec at that bit
rate (:mod:`synth_data.video`: H.264 or MPEG-4 part 2 through PyAV) into ``video.mp4``; the
``img1/`` JPEGs are then made from the *decoded* frames, so a tracker reading either carries
the codec's artefacts (``video.mp4`` is dropped again when ``video`` is false). With
``video_kbps == 0`` the JPEGs come straight from the renderer and ``video=True`` writes an
OpenCV ``mp4v`` file at OpenCV's default quality, as before.

Temporary folders are unmistakably the project's own: the name carries the
:data:`TMP_PREFIX`, and the first thing written inside is the marker :data:`TMP_MARKER`
(JSON: pid, host, target, creation time). :func:`clean_stale_tmp` deletes only folders that
carry a readable marker of this host whose process is dead; a user folder that merely looks
similar (``.tmp-notes-2024``) is never touched.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import require_whole_video, signals_held
from synth_data.mot import (
    CHECKSUMS_FILE,
    TMP_MARKER,
    gt_rows,
    mot_ids,
    not_ours,
    read_tmp_marker,
    sha256_file,
    write_agents_csv,
    write_mot,
    write_seqinfo,
)

TMP_PREFIX = ".crowdsim-tmp-"
"""Name prefix of the folders a write in progress uses (then ``<name>-<pid>-<token>``)."""
OLD_PREFIX = ".crowdsim-old-"
"""Name prefix of a replaced sequence while ``--overwrite`` swaps in the new one."""


def package_versions() -> dict[str, str]:
    """Versions of the packages that shape the output (for ``meta.json``)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for dist in ("crowdsim", "numpy", "scipy", "pymunk", "numba", "opencv-python-headless", "av"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    import cv2

    out["cv2"] = cv2.__version__
    return out


def tmp_dir_for(out_dir: Path) -> Path:
    """A fresh temporary folder name for writing ``out_dir``: a sibling
    ``.crowdsim-tmp-<name>-<pid>-<token>`` (``token``: 8 random hex digits)."""
    import secrets

    out_dir = Path(out_dir)
    return out_dir.parent / f"{TMP_PREFIX}{out_dir.name}-{os.getpid()}-{secrets.token_hex(4)}"


def make_tmp_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Create the temporary folder for ``out_dir`` and write its marker first; returns it."""
    import socket
    import time

    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_dir_for(out_dir)
    tmp.mkdir()
    try:
        marker = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "target": out_dir.name,
            "created": time.time(),
        }
        with open(tmp / TMP_MARKER, "w") as fh:
            fh.write(json.dumps(marker) + "\n")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


def _pid_alive(pid: int, since: float | None = None) -> bool:
    """Whether process ``pid`` runs (a zombie does not; on Linux, a process started after
    ``since`` (epoch seconds) is another one that reuses the pid)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        pass
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        fields = text[text.rindex(")") + 2 :].split()
        if fields[0] in ("Z", "X"):
            return False
        if since is not None:
            boot = next(
                float(line.split()[1])
                for line in Path("/proc/stat").read_text().splitlines()
                if line.startswith("btime")
            )
            started = boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
            if started > since + 2.0:  # btime has 1 s resolution
                return False
    except (OSError, ValueError, IndexError, StopIteration):  # not Linux: trust kill(0)
        pass
    return True


def clean_stale_tmp(parent: str | os.PathLike[str]) -> list[Path]:
    """Delete the leftover temporary folders of dead processes directly under ``parent``.

    A folder is deleted only when its name starts with :data:`TMP_PREFIX`, it holds a
    readable :data:`TMP_MARKER` written on this host, and the marker's process is no longer
    running. A sequence a dead ``--overwrite`` had renamed aside (:data:`OLD_PREFIX`, still
    provably crowdsim's) gets its name back when nothing took it (killed between the two
    renames of :func:`publish_tmp_dir`), and is deleted otherwise. Anything else (live
    writers, other hosts on a shared file system, user folders) is left alone. Returns the
    deleted folders.
    """
    import socket

    parent = Path(parent)
    removed: list[Path] = []
    try:
        candidates = sorted(parent.glob(f"{TMP_PREFIX}*"))
    except OSError:
        return removed
    host = socket.gethostname()
    for p in candidates:
        if not p.is_dir() or p.is_symlink():
            continue
        marker = read_tmp_marker(p)
        if marker is None:
            continue
        created = marker.get("created")
        since = float(created) if isinstance(created, (int, float)) else None
        if marker.get("host") != host or _pid_alive(marker["pid"], since):
            continue
        shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    for p in _stale_old(parent):
        back = parent / p.name[len(OLD_PREFIX) :].rsplit("-", 2)[0]
        if not (back.exists() or back.is_symlink()):  # killed between the two renames
            try:
                os.replace(p, back)  # the name gets back the sequence it had
            except OSError:  # a read-only folder, say: left as it is
                pass
        else:
            shutil.rmtree(p, ignore_errors=True)
            if not p.exists():
                removed.append(p)
    return removed


def _stale_old(parent: Path) -> list[Path]:
    """The replaced sequences (:data:`OLD_PREFIX` ``<name>-<pid>-<8 hex>``) under ``parent``
    whose writer has died, and which are still provably crowdsim's."""
    import re

    pattern = re.compile(re.escape(OLD_PREFIX) + r".+-(\d+)-[0-9a-f]{8}")
    try:
        candidates = sorted(parent.glob(f"{OLD_PREFIX}*"))
    except OSError:
        return []
    out = []
    for p in candidates:
        match = pattern.fullmatch(p.name)
        if match is None or not p.is_dir() or p.is_symlink():
            continue
        if _pid_alive(int(match.group(1))) or not_ours(p) is not None:
            continue
        out.append(p)
    return out


def require_ours(out_dir: Path) -> None:
    """Refuse (``ValueError``) to replace a folder crowdsim cannot prove it wrote."""
    why = not_ours(out_dir)
    if why is not None:
        raise ValueError(f"refusing to replace {out_dir} with --overwrite: {why}")


def publish_tmp_dir(tmp: Path, out_dir: Path, overwrite: bool = False) -> None:
    """Rename the complete ``tmp`` to ``out_dir``, then drop the marker: until the rename the
    folder is a cleanable leftover, afterwards a sequence.

    An existing ``out_dir`` is replaced only with ``overwrite``, and only when it is still
    provably crowdsim's (:func:`synth_data.mot.not_ours`, checked again now: a user may have
    added a file while the frames were rendered, or made the folder meanwhile); it is renamed
    aside (:data:`OLD_PREFIX`) before the new one takes its name, so the name never points at a
    half-made folder.
    """
    old = None
    if out_dir.exists() or out_dir.is_symlink():
        if not overwrite:
            raise FileExistsError(f"{out_dir} already exists; pass --overwrite to replace it")
        require_ours(out_dir)
        import secrets

        old = out_dir.parent / f"{OLD_PREFIX}{out_dir.name}-{os.getpid()}-{secrets.token_hex(4)}"
    # Ctrl-C or SIGTERM waits until the name holds a whole sequence (SIGKILL cannot be held:
    # clean_stale_tmp puts back what it leaves)
    published = False
    try:
        with signals_held():
            if old is not None:
                os.replace(out_dir, old)
                try:
                    os.replace(tmp, out_dir)
                except BaseException:
                    os.replace(old, out_dir)  # the name keeps the sequence it had
                    raise
            else:
                os.replace(tmp, out_dir)
            (out_dir / TMP_MARKER).unlink(missing_ok=True)
            published = True
    finally:  # the held signal is raised as the block ends: the old sequence goes all the same
        if published and old is not None:
            shutil.rmtree(old, ignore_errors=True)  # a kill here: clean_stale_tmp removes the rest


def write_sequence(
    out_dir: str | os.PathLike[str],
    traj: Any,
    *,
    camera: Any,
    appearance: Any,
    seed: int,
    events: Any = (),
    name: str | None = None,
    meta: dict[str, Any] | None = None,
    images: bool = True,
    video: bool = False,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    tracks: Any = None,
) -> dict[str, Any]:
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
    events : sequence of crowdsim.events.Event
        The spec's events; lighting and noise are drawn here (shake bursts are in ``camera``).
    name : str, optional
        Sequence name in seqinfo.ini (default: the folder name).
    meta : dict, optional
        Extra JSON-serialisable content of ``meta.json`` (typically ``{"spec": ...}``).
    images, video : bool
        Write ``img1/*.jpg`` and/or ``video.mp4``; at least one.
    overwrite : bool
        Replace an existing ``out_dir``, only when it is provably a sequence crowdsim wrote
        (:func:`synth_data.mot.not_ours`: else ``ValueError`` naming the first file that is
        not), checked before rendering and again just before the swap; without it an existing
        folder raises ``FileExistsError``.
    progress : callable, optional
        Called with ``1`` after each rendered frame.
    tracks : crowdsim.render.AgentTracks, optional
        ``prepare_agents(traj, camera, appearance, seed)`` when the caller holds it already
        (:attr:`synth_data.scene.Scene.tracks`): a second copy of its ``(T, N)`` arrays is not
        built beside it.

    Returns
    -------
    dict
        ``{"name", "frames", "files": {relative path: sha256}, "bytes"}``.
    """
    from crowdsim.camera import DRONE_FIELDS
    from crowdsim.render import SceneRenderer, prepare_agents

    out_dir = Path(out_dir)
    name = name or out_dir.name
    if not (images or video):
        raise ValueError("output: at least one of images or video must be true")
    if out_dir.exists() or out_dir.is_symlink():
        if not overwrite:
            raise FileExistsError(f"{out_dir} already exists; pass --overwrite to replace it")
        require_ours(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = make_tmp_dir(out_dir)
    (tmp / "gt").mkdir()
    checksums: dict[str, str] = {}
    total = 0
    try:
        if tracks is None:
            tracks = prepare_agents(traj, camera, appearance, seed)
        renderer = SceneRenderer(camera, appearance, seed=seed, fps=traj.fps, events=events)
        n_frames = tracks.n_frames
        visibility = np.full(tracks.pixels.shape[:2], np.nan)
        if images:
            (tmp / "img1").mkdir()
        frames = _render_frames(renderer, tracks, visibility, progress)
        total += _write_frames(tmp, frames, traj.fps, appearance.encoding, images, video, checksums)
        mids = mot_ids(tracks.ids)
        rows = gt_rows(tracks.pixels, camera, appearance.template_px, mids, visibility)
        write_mot(tmp / "gt" / "gt.txt", rows)
        seen = (
            np.isin(mids, np.unique(rows[:, 1]).astype(np.int64))
            if len(rows)
            else np.zeros(len(mids), bool)
        )
        attrs = traj.attributes
        write_agents_csv(
            tmp / "gt" / "agents.csv",
            {
                "id": mids[seen],
                "group": attrs["group"][seen],
                "prominent": tracks.prominent[seen],
                "anomaly": attrs["anomaly"][seen],
                "appearance": tracks.appearance[seen],
            },
        )
        write_seqinfo(
            tmp,
            name=name,
            frame_rate=traj.fps,
            length=n_frames,
            width=camera.width,
            height=camera.height,
            template_size=appearance.template_px,
            im_dir="img1" if images else None,
        )
        meta_out = dict(meta or {})
        meta_out.setdefault("seed", int(seed))
        meta_out["camera"] = {
            "px_per_m": camera.px_per_m,
            "width": camera.width,
            "height": camera.height,
            "center": list(camera.center),
            "tilt_deg": camera.tilt_deg,
            "distance_m": camera.distance_m,
            "jitter_px": camera.jitter_px,
            "seed": camera.seed,
            "jitter_frames": camera.jitter_frames,
        }
        if camera.drone_on:  # recorded only when on: drone-free folders stay byte-identical
            meta_out["camera"].update({n: getattr(camera, n) for n in DRONE_FIELDS})
        if camera.ground_margin_px:  # recorded only when set, as the drone profile
            meta_out["camera"]["ground_margin_px"] = camera.ground_margin_px
        if camera.shake_events:
            meta_out["camera"]["shake_events"] = [e.to_dict() for e in camera.shake_events]
        meta_out["appearance"] = appearance.to_dict()
        meta_out["frames"] = n_frames
        meta_out["versions"] = package_versions()
        (tmp / "meta.json").write_text(json.dumps(meta_out, indent=2, sort_keys=True) + "\n")
        for rel in ("gt/gt.txt", "gt/agents.csv", "seqinfo.ini", "meta.json") + (
            ("video.mp4",) if video else ()
        ):
            checksums[rel] = sha256_file(tmp / rel)
            total += (tmp / rel).stat().st_size
        checksums = dict(sorted(checksums.items()))
        (tmp / CHECKSUMS_FILE).write_text(json.dumps(checksums, indent=0) + "\n")
        _fsync_dir(tmp)
        publish_tmp_dir(tmp, out_dir, overwrite)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise _named_in(exc, tmp, out_dir) from None
        raise
    return {"name": name, "frames": n_frames, "files": checksums, "bytes": total}


def _named_in(exc: OSError, tmp: Path, out_dir: Path) -> OSError:
    """``exc`` naming the file's place in ``out_dir`` instead of in the hidden (and by now
    removed) temporary folder ``tmp``."""
    inside = str(tmp)
    if exc.errno is None:  # our own message: it names the file in its text
        return type(exc)(str(exc).replace(inside, str(out_dir)))
    name = os.fsdecode(exc.filename) if isinstance(exc.filename, (str, bytes)) else None
    if name is None or not (name == inside or name.startswith(inside + os.sep)):
        return exc
    try:
        return type(exc)(exc.errno, exc.strerror, str(out_dir) + name[len(inside) :])
    except TypeError:  # pragma: no cover - an OSError subclass with its own constructor
        return exc


def _render_frames(
    renderer: Any, tracks: Any, visibility: np.ndarray, progress: Callable[[int], None] | None
) -> Iterator[np.ndarray]:
    """Yield every frame (one reused buffer), filling ``visibility[t]`` as it goes."""
    cam = renderer.camera
    frame = np.empty((cam.height, cam.width, 3), np.uint8)
    for t in range(tracks.n_frames):
        renderer.render_tracks(tracks, t, out=frame, visibility=visibility[t])
        yield frame
        if progress is not None:
            progress(1)


def _write_frames(
    tmp: Path,
    frames: Iterable[np.ndarray],
    fps: float,
    encoding: Any,
    images: bool,
    video: bool,
    checksums: dict[str, str],
) -> int:
    """Write ``img1/*.jpg`` through the output encoding, and ``video.mp4``; bytes of the JPEGs.

    With a codec (``encoding.video_kbps > 0``) ``video.mp4`` is its coded stream (kept only
    when ``video``); without one, ``video`` writes an OpenCV ``mp4v`` file of the rendered
    frames at OpenCV's default quality.
    """
    from synth_data.video import encode_output, encode_video

    codec = encoding.video_kbps > 0
    if not images:
        if codec:
            encode_video(frames, fps, encoding, tmp / "video.mp4")
        else:
            for _ in _mp4v_frames(tmp / "video.mp4", frames, fps):
                pass
        return 0
    if video and not codec:
        frames = _mp4v_frames(tmp / "video.mp4", frames, fps)
    into = tmp / "video.mp4" if (video and codec) else None
    total = 0
    for t, data in enumerate(encode_output(frames, fps, encoding, into)):
        rel = f"img1/{t + 1:06d}.jpg"
        with open(tmp / rel, "wb") as fh:
            fh.write(data)
        checksums[rel] = hashlib.sha256(data).hexdigest()
        total += len(data)
    return total


def _mp4v_frames(path: Path, frames: Iterable[np.ndarray], fps: float) -> Iterator[np.ndarray]:
    """Yield ``frames`` unchanged while writing them to an OpenCV ``mp4v`` file at ``path``."""
    import cv2

    writer = None
    n = 0
    try:
        for frame in frames:
            if writer is None:
                h, w = frame.shape[:2]
                writer = cv2.VideoWriter(
                    str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h)
                )
                if not writer.isOpened():
                    raise RuntimeError("OpenCV cannot write mp4v video on this machine")
            writer.write(frame)
            n += 1
            yield frame
    finally:
        if writer is not None:
            writer.release()
    if writer is not None:  # every frame written (not stopped by an error): read it back
        require_whole_video(path, n)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platform without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
