"""Spec files -> sequences on disk: resumable, atomic, parallel (local pool or Ray).

``generate(specs, out)`` writes ``out/<spec.name>/`` for every spec and keeps
``out/manifest.json``::

    {"format": 1, "sequences": {"seq1": {"spec_sha256": ..., "frames": 840, "bytes": ...,
                                          "files": {"img1/000001.jpg": "<sha256>", ...}}}}

* **Atomic**: each sequence is written to ``out/.tmp-<name>-<pid>`` and renamed when complete
  (:func:`synth_data.writer.write_sequence`); the folder also carries its own
  ``checksums.json``, so a sequence renamed just before a kill is still recognised.
* **Resumable**: a sequence folder whose checksums verify and whose ``meta.json`` has the same
  spec digest is skipped. Leftover temporary folders of dead processes are removed.
* **No silent overwrite**: a folder made from another spec (or another ``--frames``), or one
  that fails verification, raises :class:`FileExistsError` unless ``overwrite=True``.
* **Parallel**: ``backend="local"`` runs a spawn-context process pool of ``workers``
  processes (in-process when ``workers == 1``); ``backend="ray"`` runs one Ray task per
  sequence on the cluster at ``address`` (a local Ray instance when None). The output folder
  must be visible to every Ray node (shared file system).
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import write_text_atomic
from synth_data.spec import SequenceSpec
from synth_data.writer import TMP_PREFIX, verify_sequence, write_sequence

MANIFEST = "manifest.json"
EXTENT_PERCENTILE = 1.0
"""The camera frames the 1st to 99th percentile of the crowd's positions on each axis."""
MANIFEST_FORMAT = 1
SETTLE_S = 3.0
"""Seconds after entering and before leaving during which positions do not set the frame."""


class GenerationError(RuntimeError):
    """A worker died or failed; finished sequences are kept and a rerun resumes."""


# ---------------------------------------------------------------------------- one sequence
def simulate(spec: SequenceSpec) -> Any:
    """Run the spec's scenario: ``frames`` rows after ``warmup_steps`` dropped steps."""
    from crowdsim.params import SocialForceParams
    from crowdsim.scenarios import make_scenario
    from crowdsim.simulation import Simulation
    from crowdsim.trajectories import Trajectories

    params = {k: v for k, v in spec.scenario.items() if k != "name"}
    scenario = make_scenario(spec.scenario["name"], **params)
    sf = SocialForceParams()
    if abs(sf.dt - 1.0 / spec.fps) > 1e-12:
        sf = replace(sf, dt=1.0 / spec.fps)
    sim = Simulation(scenario, seed=spec.seed, params=sf)
    traj = sim.run(spec.warmup_steps + spec.frames - 1)
    pos = traj.positions[spec.warmup_steps:]
    keep = ~np.isnan(pos[..., 0]).all(axis=0)
    meta = dict(traj.meta)
    meta["warmup_steps"] = spec.warmup_steps
    return Trajectories(positions=pos[:, keep], ids=traj.ids[keep], dt=traj.dt,
                        attributes={k: v[keep] for k, v in traj.attributes.items()}, meta=meta)


def crowd_extent(traj: Any, percent: float = EXTENT_PERCENTILE,
                 settle_s: float = SETTLE_S) -> tuple[float, ...]:
    """``(xmin, ymin, xmax, ymax)`` metres holding all but ``percent`` % of the positions
    on each side: where the crowd is, not every straggler (the camera frames this).

    Positions within ``settle_s`` seconds (at most a quarter of the clip) of an agent
    entering (after the first frame) or leaving (before the last frame) do not count, so
    that sources and sinks, where people appear and vanish, fall outside the frame: in the
    video people walk in and out across its border, as they do in real footage.
    """
    present = traj.present
    t = present.shape[0]
    k = min(max(0, int(round(settle_s / traj.dt))), t // 4)  # short clips: a quarter
    settled = present.copy()
    if k:
        rows = np.arange(t)[:, None]
        seen = present.any(axis=0)
        first = np.where(seen, present.argmax(axis=0), 0)
        last = np.where(seen, t - 1 - present[::-1].argmax(axis=0), t - 1)
        settled &= ~((first > 0) & (rows < first + k))
        settled &= ~((last < t - 1) & (rows > last - k))
        if not settled.any():
            settled = present
    xy = traj.positions[settled]
    if len(xy) == 0:
        raise ValueError("the simulation produced no agent inside the recorded frames")
    if len(xy) > 2_000_000:  # a subsample is plenty for percentiles
        xy = xy[:: len(xy) // 1_000_000]
    lo = np.percentile(xy, percent, axis=0)
    hi = np.percentile(xy, 100.0 - percent, axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def camera_for(spec_camera: dict[str, Any], template_px: int, extent: tuple[float, ...],
               seed: int, focus: tuple[float, float] | None = None) -> Any:
    """The :class:`~crowdsim.camera.Camera` of a spec's ``[camera]`` table for ``extent``.

    Without an explicit ``center`` the camera looks at the centre of ``extent``; when the
    frame is smaller than the extent it moves towards ``focus`` (e.g. the crowd's median
    position) as far as it can while staying inside the extent.
    """
    from crowdsim.camera import Camera
    from crowdsim.render import default_px_per_m

    cam = spec_camera
    if ("width" in cam) != ("height" in cam):
        raise ValueError("camera: give both width and height, or neither")
    size = (cam["width"], cam["height"]) if "width" in cam else None
    camera = Camera.fit(extent, px_per_m=float(cam.get("px_per_m", default_px_per_m(template_px))),
                        size=size, margin_m=float(cam.get("margin_m", 1.0)),
                        max_size=(cam.get("max_width", 1920), cam.get("max_height", 1080)),
                        tilt_deg=float(cam.get("tilt_deg", 0.0)),
                        distance_m=float(cam.get("distance_m", 60.0)),
                        jitter_px=float(cam.get("jitter_px", 0.0)), seed=seed)
    if "center" in cam:
        camera = replace(camera, center=tuple(float(c) for c in cam["center"]))
    elif focus is not None:
        half = (camera.width / camera.px_per_m / 2.0, camera.height / camera.px_per_m / 2.0)
        centre = []
        for axis in (0, 1):
            lo, hi = extent[axis], extent[axis + 2]
            if hi - lo <= 2 * half[axis]:
                centre.append((lo + hi) / 2.0)
            else:
                centre.append(float(np.clip(focus[axis], lo + half[axis], hi - half[axis])))
        camera = replace(camera, center=(centre[0], centre[1]))
    return camera


def build_sequence(spec: SequenceSpec, out: str | os.PathLike[str], overwrite: bool = False,
                   progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Simulate and render one spec into ``out/<spec.name>``; returns its manifest entry."""
    import cv2

    cv2.setNumThreads(1)  # one sequence per core; OpenCV's own threads only add contention
    traj = simulate(spec)
    xy = traj.positions[traj.present]
    focus = (float(np.median(xy[:, 0])), float(np.median(xy[:, 1])))
    camera = camera_for(spec.camera, spec.appearance.template_px, crowd_extent(traj), spec.seed,
                        focus=focus)
    meta = {"spec": spec.to_dict(), "spec_sha256": spec.digest(), "seed": spec.seed,
            "spec_file": spec.source}
    entry = write_sequence(Path(out) / spec.name, traj, camera=camera,
                           appearance=spec.appearance, seed=spec.seed, name=spec.name, meta=meta,
                           images=spec.output["images"], video=spec.output["video"],
                           overwrite=overwrite, progress=progress)
    entry["spec_sha256"] = spec.digest()
    return entry


class _QueueProgress:
    """Picklable progress callback for pool workers: batches frame counts into a queue."""

    def __init__(self, q: Any) -> None:
        self.q = q

    def __call__(self, n: int) -> None:
        self.q.put(n)


def _single_threaded() -> None:
    """One sequence per worker process: keep numba's parallel loops to one thread."""
    import numba

    numba.set_num_threads(1)


def _pool_task(spec: SequenceSpec, out: str, overwrite: bool, q: Any) -> dict[str, Any]:
    _single_threaded()
    return build_sequence(spec, out, overwrite, _QueueProgress(q))


def _ray_task(spec: SequenceSpec, out: str, overwrite: bool) -> dict[str, Any]:
    _single_threaded()
    return build_sequence(spec, out, overwrite)


# ---------------------------------------------------------------------------- manifest
def read_manifest(out: Path) -> dict[str, Any]:
    """The manifest of ``out`` (an empty one when missing or unreadable)."""
    try:
        data = json.loads((out / MANIFEST).read_text())
        if isinstance(data, dict) and isinstance(data.get("sequences"), dict):
            return data
    except (OSError, json.JSONDecodeError):
        pass
    return {"format": MANIFEST_FORMAT, "sequences": {}}


def write_manifest(out: Path, manifest: dict[str, Any]) -> None:
    manifest["sequences"] = dict(sorted(manifest["sequences"].items()))
    write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - someone else's process
        return True
    return True


def clean_stale_tmp(out: Path) -> list[Path]:
    """Remove ``.tmp-*-<pid>`` folders of processes that no longer run."""
    removed = []
    for p in out.glob(f"{TMP_PREFIX}*"):
        try:
            pid = int(p.name.rsplit("-", 1)[1])
        except (IndexError, ValueError):
            continue
        if p.is_dir() and (pid == os.getpid() or not _pid_alive(pid)):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


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
    return {"name": spec.name, "frames": int(meta.get("frames", spec.frames)), "files": checks,
            "bytes": size, "spec_sha256": spec.digest()}, ""


# ---------------------------------------------------------------------------- driver
def generate(specs: list[SequenceSpec], out: str | os.PathLike[str], *, workers: int = 1,
             backend: str = "local", address: str | None = None, overwrite: bool = False,
             progress: bool = True, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Generate every spec into ``out``; returns the manifest (see the module docstring).

    Raises
    ------
    ValueError
        Bad arguments (duplicate names, workers < 1, unknown backend, Ray missing).
    FileExistsError
        A sequence folder exists but does not match, and ``overwrite`` is False.
    GenerationError
        A worker died or failed; completed sequences are in the manifest.
    """
    if log is None:
        from tqdm import tqdm

        def log(msg: str) -> None:  # prints above the progress bar instead of through it
            tqdm.write(msg, file=sys.stderr)

    if backend not in ("local", "ray"):
        raise ValueError(f"--backend must be local or ray, got {backend!r}")
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"two specs share the sequence name {dup[0]!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out must be a folder, got the file {str(out)!r}")
    out.mkdir(parents=True, exist_ok=True)
    clean_stale_tmp(out)
    manifest = read_manifest(out)
    manifest["format"] = MANIFEST_FORMAT
    seqs = manifest["sequences"]
    for name in list(seqs):
        if not (out / name).is_dir():
            del seqs[name]
    todo: list[SequenceSpec] = []
    for spec in specs:
        seq_dir = out / spec.name
        if not seq_dir.exists():
            seqs.pop(spec.name, None)
            todo.append(spec)
            continue
        entry, why = _existing_entry(seq_dir, spec)
        if entry is not None:
            seqs[spec.name] = entry
            log(f"{spec.name}: complete, checksums verified; skipped")
        elif overwrite:
            seqs.pop(spec.name, None)
            todo.append(spec)
        else:
            raise FileExistsError(f"{seq_dir} exists and {why}; pass --overwrite to replace it")
    write_manifest(out, manifest)
    if not todo:
        return manifest
    if backend == "ray":
        _run_ray(todo, out, overwrite, address, manifest, progress, log)
    elif workers == 1 or len(todo) == 1:
        _run_inline(todo, out, overwrite, manifest, progress, log)
    else:
        _run_pool(todo, out, overwrite, min(workers, len(todo)), manifest, progress, log)
    return manifest


def _bar(total: int, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", desc="generating", disable=not enabled,
                dynamic_ncols=True, smoothing=0.1)


def _done(out: Path, manifest: dict[str, Any], entry: dict[str, Any], t0: float,
          log: Callable[[str], None]) -> None:
    manifest["sequences"][entry["name"]] = entry
    write_manifest(out, manifest)
    log(f"{entry['name']}: {entry['frames']} frames, {entry['bytes'] / 1e6:.1f} MB "
        f"in {time.perf_counter() - t0:.1f} s")


def _run_inline(todo: list[SequenceSpec], out: Path, overwrite: bool, manifest: dict[str, Any],
                progress: bool, log: Callable[[str], None]) -> None:
    with _bar(sum(s.frames for s in todo), progress) as bar:
        for spec in todo:
            t0 = time.perf_counter()
            entry = build_sequence(spec, out, overwrite, bar.update)
            _done(out, manifest, entry, t0, log)


def _run_pool(todo: list[SequenceSpec], out: Path, overwrite: bool, workers: int,
              manifest: dict[str, Any], progress: bool, log: Callable[[str], None]) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")  # no fork of a process holding OpenCV/numba threads
    t0 = time.perf_counter()
    with ctx.Manager() as mgr, _bar(sum(s.frames for s in todo), progress) as bar:
        q = mgr.Queue()
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = {pool.submit(_pool_task, s, str(out), overwrite, q): s for s in todo}
            pending = set(futures)
            failure: BaseException | None = None
            while pending:
                finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                _drain(q, bar)
                for fut in finished:
                    spec = futures[fut]
                    try:
                        _done(out, manifest, fut.result(), t0, log)
                    except BrokenProcessPool:
                        failure = GenerationError(
                            f"a worker process died while generating {spec.name}; finished "
                            "sequences are kept, rerun the same command to resume")
                    except (ValueError, FileExistsError) as exc:
                        failure = exc
                    except Exception as exc:  # noqa: BLE001 - reported with the sequence name
                        failure = GenerationError(f"{spec.name}: {type(exc).__name__}: {exc}")
                if failure is not None:
                    for fut in pending:
                        fut.cancel()
                    break
            _drain(q, bar)
        if failure is not None:
            raise failure


def _drain(q: Any, bar: Any) -> None:
    n = 0
    while True:
        try:
            n += q.get_nowait()
        except queue.Empty:
            break
        except (EOFError, OSError):  # manager gone
            break
    if n:
        bar.update(n)


def _run_ray(todo: list[SequenceSpec], out: Path, overwrite: bool, address: str | None,
             manifest: dict[str, Any], progress: bool, log: Callable[[str], None]) -> None:
    try:
        import ray
    except ImportError:
        raise ValueError("--backend ray needs Ray, an optional extra: "
                         "pip install 'crowdsim[distributed]'") from None
    if not ray.is_initialized():
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    task = ray.remote(num_cpus=1)(_ray_task)
    t0 = time.perf_counter()
    refs = {task.remote(s, str(out.resolve()), overwrite): s for s in todo}
    with _bar(sum(s.frames for s in todo), progress) as bar:
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            for ref in ready:
                spec = refs.pop(ref)
                try:
                    entry = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - Ray wraps worker errors
                    raise GenerationError(f"{spec.name}: Ray task failed: {exc}") from None
                bar.update(spec.frames)
                _done(out, manifest, entry, t0, log)
