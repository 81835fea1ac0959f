"""Spec files -> sequences on disk: resumable, atomic, parallel (local pool or Ray).

``generate(specs, out)`` writes ``out/<spec.name>/`` for every spec and keeps
``out/manifest.json``::

    {"format": 1, "sequences": {"seq1": {"spec_sha256": ..., "frames": 840, "bytes": ...,
                                          "files": {"img1/000001.jpg": "<sha256>", ...}}}}

What a sequence looks like is decided in :mod:`synth_data.scene` (simulation, camera,
renderer; shared with the in-memory :class:`synth_data.sequence.InMemorySequence`); this
module only writes to disk and runs the jobs through :func:`crowdsim.jobs.run_jobs`.

* **Atomic**: each sequence is written to ``out/.crowdsim-tmp-<name>-<pid>-<token>`` (a
  marker file inside, written first, proves it is ours) and renamed when complete
  (:func:`synth_data.writer.write_sequence`); the folder also carries its own
  ``checksums.json``, so a sequence renamed just before a kill is still recognised.
* **Resumable**: a sequence folder whose checksums verify and whose ``meta.json`` has the same
  spec digest is skipped. Leftover temporary folders of dead processes (marker checked) are
  removed; nothing else is.
* **Concurrent runs**: manifest updates are merged under a file lock, so two runs into one
  folder with different sequences keep each other's entries.
* **No silent overwrite**: a folder made from another spec (or another ``--frames``), or one
  that fails verification, raises :class:`FileExistsError` unless ``overwrite=True``; even
  then it is replaced only when crowdsim can prove it wrote every file in it
  (:func:`synth_data.mot.not_ours`), otherwise ``ValueError`` names the first file that
  is not its own, before anything runs.
* **Parallel**: ``backend="local"`` runs a spawn-context process pool of ``workers``
  processes (in-process when ``workers == 1``) whose workers die with this process;
  ``backend="ray"`` runs one Ray task per sequence, at most ``workers`` at a time, on the
  cluster at ``address`` (a local Ray instance when None). The output folder must be visible
  to every Ray node (shared file system).
* **Interruption**: SIGINT/SIGTERM stop the run promptly, remove this run's temporary folders
  and raise :class:`crowdsim.jobs.Interrupted` (``removed`` lists what was deleted); finished
  sequences stay in the manifest.
* **Failures leave nothing half-made**: file-system errors (full disk, read-only folder) pass
  through as ``OSError`` naming the path; a run that finished nothing removes the manifest,
  lock and output folder it created.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from crowdsim.checks import require_workers
from crowdsim.jobs import (
    Interrupted,
    Job,
    JobError,
    lock_path,
    locked_manifest,
    one_numba_thread,
    read_manifest,
)
from crowdsim.jobs import run_jobs as _run_jobs
from synth_data.mot import SUITE_MANIFEST, not_ours, require_outside_sequences, verify_sequence
from synth_data.scene import Scene
from synth_data.spec import SequenceSpec
from synth_data.writer import clean_stale_tmp, require_ours, write_sequence

MANIFEST = SUITE_MANIFEST
MANIFEST_SECTION = "sequences"
MANIFEST_FORMAT = 1


class GenerationError(RuntimeError):
    """A worker died or failed; finished sequences are kept and a rerun resumes."""


# ---------------------------------------------------------------------------- one sequence
def build_sequence(
    spec: SequenceSpec,
    out: str | os.PathLike[str],
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Simulate and render one spec into ``out/<spec.name>``; returns its manifest entry."""
    import cv2

    cv2.setNumThreads(1)  # one sequence per core; OpenCV's own threads only add contention
    scene = Scene.from_spec(spec)
    if not scene.camera.visible(scene.tracks.pixels).any():  # as crowdsim render refuses it
        cam = scene.camera
        raise ValueError(
            f"{spec.source or spec.name}: camera: no person is inside the {cam.width}x"
            f"{cam.height} frame centred on ({cam.center[0]:g}, {cam.center[1]:g}) m at "
            f"{cam.px_per_m:g} px/m in any of the {spec.frames} frames; check camera.center, "
            "width/height and px_per_m"
        )
    meta = {
        "spec": spec.to_dict(),
        "spec_sha256": spec.digest(),
        "seed": spec.seed,
        "spec_file": spec.source,
    }
    try:
        entry = write_sequence(
            Path(out) / spec.name,
            scene.traj,
            camera=scene.camera,
            appearance=scene.appearance,
            seed=scene.seed,
            events=scene.events,
            name=spec.name,
            meta=meta,
            images=spec.output["images"],
            video=spec.output["video"],
            overwrite=overwrite,
            progress=progress,
            tracks=scene.tracks,  # built for the check above; not a second time
        )
    except FileExistsError:
        # another run into the same folder (a second generate, a table run) finished this
        # sequence meanwhile: the same spec gives the same sequence to the byte, so it is
        # this job's too; a folder from another spec is still refused
        entry, _ = _existing_entry(Path(out) / spec.name, spec)
        if overwrite or entry is None:
            raise
        return entry
    entry["spec_sha256"] = spec.digest()
    return entry


# ---------------------------------------------------------------------------- manifest
def read_manifest_of(out: str | os.PathLike[str]) -> dict[str, Any]:
    """The manifest of the folder ``out`` (an empty one when there is none; a file there that
    is not crowdsim's manifest is refused, :func:`crowdsim.jobs.read_manifest`)."""
    return read_manifest(Path(out) / MANIFEST, MANIFEST_SECTION)


def _existing_entry(seq_dir: Path, spec: SequenceSpec) -> tuple[dict[str, Any] | None, str]:
    """(manifest entry, "") when ``seq_dir`` is a verified match of ``spec``, else (None, why)."""
    try:
        meta = json.loads((seq_dir / "meta.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None, "is incomplete (no readable meta.json)"
    if meta.get("spec_sha256") != spec.digest():
        return None, "was generated from a different spec or --frames"
    checks = verify_sequence(seq_dir)
    if checks is None:
        return None, "fails checksum verification"
    size = sum((seq_dir / rel).stat().st_size for rel in checks)
    return {
        "name": spec.name,
        "frames": int(meta.get("frames", spec.frames)),
        "files": checks,
        "bytes": size,
        "spec_sha256": spec.digest(),
    }, ""


# ---------------------------------------------------------------------------- driver
def generate(
    specs: list[SequenceSpec],
    out: str | os.PathLike[str],
    *,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Generate every spec into ``out``; returns the manifest (see the module docstring).

    Raises
    ------
    ValueError
        Bad arguments (duplicate names, ``workers`` outside ``[1, os.cpu_count()]`` locally
        or ``[1, 256]`` on Ray, unknown backend, Ray missing), or, with ``overwrite``, a
        folder to replace that crowdsim cannot prove it wrote.
    FileExistsError
        A sequence folder exists but does not match, and ``overwrite`` is False.
    GenerationError
        A worker died or failed; completed sequences are in the manifest.
    crowdsim.jobs.Interrupted
        SIGINT/SIGTERM; this run's temporary folders are gone (``exc.removed``).
    """
    if log is None:
        from tqdm import tqdm

        def log(msg: str) -> None:  # prints above the progress bar instead of through it
            tqdm.write(msg, file=sys.stderr)

    if backend not in ("local", "ray"):
        raise ValueError(f"--backend must be local or ray, got {backend!r}")
    require_workers("--workers", workers, backend)
    if backend == "ray":
        from crowdsim.optional import require

        require("ray", "distributed", "--backend ray")
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        files = [s.source or "(in memory)" for s in specs if s.name == dup[0]]
        raise ValueError(f"two specs share the sequence name {dup[0]!r}: {' and '.join(files[:2])}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out must be a folder, got the file {str(out)!r}")
    require_outside_sequences("--out", out, out, itself=True)
    read_manifest_of(out)  # a manifest.json that is not crowdsim's: refused before any work
    fresh = (
        not out.exists(),
        not (out / MANIFEST).exists(),
        not lock_path(out / MANIFEST).exists(),
    )
    try:
        return _generate(specs, out, workers, backend, address, overwrite, progress, log)
    except BaseException as exc:
        _undo_empty_start(out, *fresh)
        if isinstance(exc, OSError) and exc.filename is None and exc.errno:
            # e.g. ENOSPC while writing a frame: name the output folder
            raise OSError(exc.errno, exc.strerror, str(out)) from exc
        raise


def _undo_empty_start(out: Path, made_out: bool, made_manifest: bool, made_lock: bool) -> None:
    """After a failed run that finished nothing, remove the files it created (manifest, lock,
    the output folder itself), so a failure leaves nothing behind."""
    try:
        if read_manifest_of(out)[MANIFEST_SECTION]:
            return
        if made_manifest:
            (out / MANIFEST).unlink(missing_ok=True)
        if made_lock and made_out:  # never pull a lock file from under another run
            lock_path(out / MANIFEST).unlink(missing_ok=True)
        if made_out:
            out.rmdir()  # only when empty
    except (OSError, ValueError):  # ValueError: not crowdsim's manifest, never touched
        pass


def _generate(
    specs: list[SequenceSpec],
    out: Path,
    workers: int,
    backend: str,
    address: str | None,
    overwrite: bool,
    progress: bool,
    log: Callable[[str], None],
) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    clean_stale_tmp(out)
    found: dict[str, dict[str, Any] | None] = {}  # verified entry, or None: (re)generate
    for spec in specs:
        seq_dir = out / spec.name
        if not seq_dir.exists():
            found[spec.name] = None
            continue
        entry, why = _existing_entry(seq_dir, spec)
        if entry is None and not overwrite:
            foreign = not_ours(seq_dir)
            if foreign is not None:  # --overwrite would refuse it too: say why, not --overwrite
                raise FileExistsError(
                    f"{seq_dir} exists and {why}, and crowdsim cannot replace it ({foreign}); "
                    "move it away or choose another --out"
                )
            raise FileExistsError(f"{seq_dir} exists and {why}; pass --overwrite to replace it")
        if entry is None:  # to be replaced: refuse before anything (the manifest) changes
            require_ours(seq_dir)
        found[spec.name] = entry
    with locked_manifest(out / MANIFEST, MANIFEST_SECTION) as manifest:
        seqs = manifest[MANIFEST_SECTION]
        for name in list(seqs):
            if not (out / name).is_dir():
                del seqs[name]
        for name, entry in found.items():
            if entry is None:
                seqs.pop(name, None)
            else:
                seqs[name] = entry
                log(f"{name}: complete, checksums verified; skipped")
    todo = [s for s in specs if found[s.name] is None]
    if todo:
        _run(
            todo,
            out.resolve() if backend == "ray" else out,
            overwrite,
            workers,
            backend,
            address,
            progress,
            log,
        )
    return read_manifest_of(out)


def _run(
    todo: list[SequenceSpec],
    out: Path,
    overwrite: bool,
    workers: int,
    backend: str,
    address: str | None,
    progress: bool,
    log: Callable[[str], None],
) -> None:
    t0 = time.perf_counter()

    def done(name: str, entry: dict[str, Any]) -> None:
        log(
            f"{name}: {entry['frames']} frames, {entry['bytes'] / 1e6:.1f} MB "
            f"in {time.perf_counter() - t0:.1f} s"
        )

    jobs = [
        Job(s.name, build_sequence, (s, str(out), overwrite), size=s.frames, progress_kw="progress")
        for s in todo
    ]
    try:
        _run_jobs(
            jobs,
            out / MANIFEST,
            workers=workers,
            backend=backend,
            address=address,
            progress=progress,
            on_done=done,
            section=MANIFEST_SECTION,
            desc="generating",
            unit="frame",
            worker_init=one_numba_thread,
            passthrough=(ValueError, OSError, MemoryError),
        )
    except JobError as exc:
        raise GenerationError(str(exc)) from exc
    except Interrupted as exc:
        exc.removed = clean_stale_tmp(out)  # workers are dead: their leftovers are stale
        raise
