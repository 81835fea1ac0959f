"""Run many independent jobs on a local process pool or on Ray, with a resumable manifest.

One runner for every command that fans work out (``generate``, ``compare``, ``ablation``,
``tune``): each :class:`Job` has a unique ``key``; when it finishes its JSON-serialisable
result is recorded in a JSON manifest, so a rerun with the same manifest skips it (resume).

Example
-------
>>> import math, pathlib, tempfile
>>> manifest = pathlib.Path(tempfile.mkdtemp()) / "manifest.json"
>>> jobs = [Job(f"sqrt-{k}", math.sqrt, (k,)) for k in (4, 9)]
>>> run_jobs(jobs, manifest, progress=False)
{'sqrt-4': 2.0, 'sqrt-9': 3.0}
>>> done = []
>>> run_jobs(jobs, manifest, progress=False, on_done=lambda key, res: done.append(key))
{'sqrt-4': 2.0, 'sqrt-9': 3.0}
>>> done  # both were already in the manifest: nothing ran again
[]
>>> read_manifest(manifest)["jobs"]
{'sqrt-4': 2.0, 'sqrt-9': 3.0}

Guarantees
----------
* **No lost entries.** Every update of the manifest happens under an exclusive
  ``fcntl.flock`` on ``.<manifest name>.lock`` beside it: read, merge the new entry, write
  atomically (:mod:`crowdsim.atomic`). Two runs sharing a manifest (e.g. two ``generate``
  runs into one folder with different ``--only`` sets) keep each other's entries.
* **Workers die with their parent.** Pool workers are spawned (no fork of a process holding
  OpenCV or numba threads); on Linux each asks the kernel for ``SIGKILL`` when its parent
  dies (``prctl(PR_SET_PDEATHSIG)``), and a watchdog thread that polls the parent pid covers
  other platforms and the start-up race.
* **Prompt interruption.** SIGINT or SIGTERM to the parent raises :class:`Interrupted` (a
  ``KeyboardInterrupt``) in the caller at once: queued jobs are cancelled, running local
  workers get SIGTERM (a job unwinds, so its ``finally``/``except`` clean-ups run, and the
  worker exits) and SIGKILL after :data:`STOP_GRACE_S`; Ray tasks are cancelled with
  ``force=True``. Jobs that finished before the signal stay in the manifest. Workers ignore
  SIGINT themselves, so a terminal Ctrl-C is handled once, by the parent.
* **Failures.** A job that raises one of ``passthrough`` (default ``ValueError``,
  ``FileExistsError``: user errors) re-raises it unchanged; any other exception, or a worker
  that died, raises :class:`JobError` naming the key. Queued jobs are then cancelled, running
  ones finish and are recorded, so a rerun resumes.

Job functions must be picklable (module-level) for ``workers > 1`` and for Ray; with
``workers == 1`` (or a single job) they run in the calling process. Ray's output must be
visible to the driver; the manifest is only written by the driver.
"""

from __future__ import annotations

import atexit
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from crowdsim.atomic import write_text_atomic
from crowdsim.checks import require_choice, require_number

MANIFEST_FORMAT: int = 1
STOP_GRACE_S: float = 3.0
"""Seconds a terminated worker gets to clean up before it is killed."""
WATCHDOG_PERIOD_S: float = 0.5
"""How often a worker checks that its parent is still alive (fallback to PDEATHSIG)."""
RAY_CONNECT_TIMEOUT_S: float = 5.0
"""Seconds :func:`ray_init` waits for a Ray cluster's address to answer (Ray itself retries
an address where nothing listens for many minutes)."""


def one_numba_thread() -> None:
    """A ``worker_init`` for pools of one job per process: numba's parallel loops use one
    thread each (the processes share the cores)."""
    import numba

    numba.set_num_threads(1)


class JobError(RuntimeError):
    """A job failed or its worker died; ``key`` names it. Finished jobs stay recorded."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


EXIT_CODES: dict[str, int] = {"SIGINT": 130, "SIGTERM": 143}
"""Exit code of a command stopped by each signal (128 + the signal number, as a shell reports
a process the signal killed), whatever the command."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped the run; ``signal_name`` says which.

    ``detail`` is what the interrupted work wants the one line that reports it to add (what was
    cleaned up, what was kept); code that catches the interrupt to clean up sets it and
    re-raises.
    """

    def __init__(self, signal_name: str, detail: str = "") -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name
        self.detail = detail

    @property
    def exit_code(self) -> int:
        return EXIT_CODES.get(self.signal_name, 130)


@dataclass(frozen=True)
class Job:
    """One unit of work.

    Parameters
    ----------
    key : str
        Unique name; the manifest records the result under it.
    fn : callable
        ``fn(*args, **kwargs)`` returns a JSON-serialisable result. Module-level (picklable)
        when it runs in a pool or on Ray.
    args : tuple
    kwargs : dict
    size : float
        Progress units of the job (e.g. its frames); the bar's total is the sum.
    progress_kw : str, optional
        When given, ``fn`` receives under this keyword a callable ``advance(n, **status)``
        that moves the progress bar by ``n`` units while the job runs (also from pool
        workers); ``status`` (e.g. ``best="91.2%"``) is shown beside the bar.
    """

    key: str
    fn: Callable[..., Any]
    args: tuple = ()
    kwargs: dict[str, Any] = field(default_factory=dict)
    size: float = 1.0
    progress_kw: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.key, str) or not self.key:
            raise ValueError(f"Job.key must be a non-empty string, got {self.key!r}")
        if not callable(self.fn):
            raise ValueError(f"Job.fn of {self.key!r} must be callable, got {self.fn!r}")
        require_number("Job", "size", self.size, lo=0)


# ---------------------------------------------------------------------------- manifest
def _empty(section: str) -> dict[str, Any]:
    return {"format": MANIFEST_FORMAT, section: {}}


def read_manifest(path: str | os.PathLike[str], section: str = "jobs") -> dict[str, Any]:
    """The manifest at ``path`` (an empty one when there is none), unlocked.

    Returns ``{"format": 1, section: {key: result, ...}, ...}``; other top-level keys of the
    file are kept. A file at ``path`` that is not such a manifest (not JSON, another tool's
    JSON, a folder) was not written by crowdsim, whose manifests are written whole
    (:func:`locked_manifest`): a ``ValueError`` refuses it instead of reading it as empty and
    replacing it.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        return _empty(section)
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, not crowdsim's manifest") from None
    except UnicodeDecodeError:  # not text: not crowdsim's (below)
        text = ""
    try:
        data = json.loads(text)
    except ValueError:
        data = None
    if not (
        isinstance(data, dict)
        and data.get("format") == MANIFEST_FORMAT
        and isinstance(data.get(section, {}), dict)
    ):
        raise ValueError(
            f"{path}: not a crowdsim manifest (its {section!r} table of format "
            f"{MANIFEST_FORMAT}); refusing to replace it: move it away or choose another "
            "output folder"
        )
    data.setdefault(section, {})
    return data


def lock_path(path: str | os.PathLike[str]) -> Path:
    """The lock file of the manifest ``path``: ``.<name>.lock`` beside it."""
    path = Path(path)
    return path.parent / f".{path.name}.lock"


@contextmanager
def manifest_lock(path: str | os.PathLike[str]) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the manifest's lock file (no-op where fcntl is missing)."""
    lock = lock_path(path)
    lock.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock, as before this module
        yield
        return
    with open(lock, "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


@contextmanager
def locked_manifest(
    path: str | os.PathLike[str], section: str = "jobs"
) -> Iterator[dict[str, Any]]:
    """Lock, read and yield the manifest; on a normal exit write it back atomically.

    Modify the yielded dict in place (``m[section][key] = result``); entries of other runs
    written meanwhile are in it, because the file is read after the lock is taken.
    """
    with manifest_lock(path):
        data = read_manifest(path, section)
        yield data
        data[section] = dict(sorted(data[section].items()))
        write_text_atomic(path, json.dumps(data, indent=1) + "\n")


# ---------------------------------------------------------------------------- workers
_QUEUE: Any = None
_IN_JOB = False
_UNWINDING = False
"""Set once a worker's running job has been sent :class:`_Terminated`: a later SIGTERM (the
executor's manager thread sends one to every worker once another worker has exited) must not
cut the job's clean-ups short."""
_LAST_SIGNAL: list[str] = []
"""The name of the last signal :func:`interruptible` turned into :class:`Interrupted` (for an
interrupt that C code raised as a bare ``KeyboardInterrupt``)."""


class _Terminated(BaseException):
    """Raised inside a worker's running job by SIGTERM so that its clean-ups run."""


def die_with_parent(parent_pid: int) -> None:
    """Ask for SIGKILL when the parent dies (Linux), and watch the parent pid (everywhere)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - exotic libc
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_PERIOD_S)
            if os.getppid() != parent_pid:
                os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="crowdsim-parent-watchdog", daemon=True).start()


def _on_sigterm(signum: int, frame: Any) -> None:
    global _UNWINDING
    if _UNWINDING:  # the job is already unwinding; SIGKILL after the grace time bounds it
        return
    if _IN_JOB:
        _UNWINDING = True
        raise _Terminated()
    os._exit(128 + signum)


def _worker_init(parent_pid: int, queue: Any, user_init: Callable[[], None] | None) -> None:
    global _QUEUE
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    signal.signal(signal.SIGTERM, _on_sigterm)
    _QUEUE = queue
    if user_init is not None:
        user_init()


class _Advance:
    """Picklable ``advance(n, **status)`` for a job in a pool worker: sends
    ``(key, n, status)`` to the parent."""

    def __init__(self, key: str) -> None:
        self.key = key

    def __call__(self, n: float = 1, **status: Any) -> None:
        if _QUEUE is not None:
            _QUEUE.put((self.key, n, status))


def _call_in_worker(job: Job) -> Any:
    global _IN_JOB
    kwargs = dict(job.kwargs)
    if job.progress_kw:
        kwargs[job.progress_kw] = _Advance(job.key)
    _IN_JOB = True
    try:
        return job.fn(*job.args, **kwargs)
    except _Terminated:  # the job's own clean-ups have run while unwinding
        os._exit(128 + signal.SIGTERM)
    finally:
        _IN_JOB = False


def _call_on_ray(job: Job) -> Any:
    return job.fn(*job.args, **job.kwargs)


# ---------------------------------------------------------------------------- driver
class _Progress:
    """The bar, with per-job units so a finished job tops up to exactly its size."""

    def __init__(self, jobs: Sequence[Job], enabled: bool, desc: str, unit: str) -> None:
        from crowdsim.progress import progress_bar

        self.bar = progress_bar(
            total=sum(j.size for j in jobs), unit=unit, desc=desc, enabled=enabled
        )
        self.sizes = {j.key: j.size for j in jobs}
        self.seen: dict[str, float] = {}

    def advance(self, key: str, n: float, status: dict[str, Any] | None = None) -> None:
        if status:
            self.bar.set_postfix(status, refresh=False)
        room = self.sizes.get(key, 0.0) - self.seen.get(key, 0.0)
        n = min(n, room)
        if n > 0:
            self.seen[key] = self.seen.get(key, 0.0) + n
            self.bar.update(n)

    def finish(self, key: str) -> None:
        self.advance(key, self.sizes.get(key, 0.0))

    def close(self) -> None:
        self.bar.close()


def _in_compiled_callback(frame: Any) -> bool:
    """Whether ``frame`` is numba's unpickling callback, which compiled code calls."""
    code = getattr(frame, "f_code", None)
    return (
        code is not None
        and code.co_name == "_numba_unpickle"
        and Path(code.co_filename).parts[-3:] == ("numba", "core", "serialize.py")
    )


def interrupt_in(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt that ``exc`` stands for: ``exc`` itself, or the interrupt in its chain
    of causes and contexts; else ``None``. An error raised while an interrupt unwinds stands
    for the interrupt: a C extension that called back into Python when the signal's handler
    raised reports a ``SystemError`` (``returned a result with an exception set``, the
    interrupt as its cause), and a library's clean-up may fail on the state the interrupt
    left (Optuna's ``_run_trial``, interrupted while it tells a trial's result, raises
    ``UnboundLocalError`` from its ``finally``).

    >>> interrupt_in(Interrupted("SIGTERM")).signal_name
    'SIGTERM'
    >>> try:
    ...     raise SystemError("returned a result with an exception set") from Interrupted("SIGINT")
    ... except SystemError as exc:
    ...     interrupt_in(exc).signal_name
    'SIGINT'
    >>> try:
    ...     try:
    ...         raise Interrupted("SIGTERM")
    ...     finally:
    ...         raise UnboundLocalError("cannot access local variable 'updated_state'")
    ... except UnboundLocalError as exc:
    ...     interrupt_in(exc).signal_name
    'SIGTERM'
    >>> interrupt_in(SystemError("other")) is None
    True
    """
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def check_ray_address(address: str | None, timeout_s: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """A ``ValueError`` in one line when nothing answers at the ``HOST:PORT`` (or
    ``ray://HOST:PORT``) of ``address`` within ``timeout_s``: ``ray.init`` waited many minutes
    there, printing retries. ``None``, ``"auto"``, ``"local"`` and what is not ``HOST:PORT``
    are left to Ray, which finds the cluster or names the bad format itself.

    >>> check_ray_address("127.0.0.1:1")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: --address 127.0.0.1:1: no Ray cluster answers there (Connection refused); ...
    """
    import socket

    if address is None:
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        why = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise ValueError(
            f"--address {address}: no Ray cluster answers there ({why}); start one with "
            "`ray start --head` or give the address it printed"
        ) from None


def ray_init(ray: Any, address: str | None) -> None:
    """Start (or join) Ray unless it runs, keeping this process's SIGINT and SIGTERM handlers:
    ``ray.init`` installs its own, and a SIGTERM then ended a run with exit 15 and Ray's stack
    dump instead of the one line and 143 (:func:`interruptible`). A SIGTERM while Ray starts
    (its handler exits with 15) raises :class:`Interrupted` too. An ``address`` where nothing
    answers is refused at once (:func:`check_ray_address`)."""
    import signal

    if ray.is_initialized():
        return
    check_ray_address(address)
    main = threading.current_thread() is threading.main_thread()
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    # registered before ray.init, so it runs after a Ctrl-C that lands while Ray starts (a
    # node half started) and, once the command has returned, before Ray's own exit hook
    atexit.unregister(ray_shutdown)  # once, however often Ray is started
    atexit.register(ray_shutdown, ray)
    try:
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    except SystemExit as exc:  # a SIGTERM while it starts: Ray's handler calls sys.exit(15)
        if exc.code != signal.SIGTERM:
            raise
        raise Interrupted("SIGTERM") from None
    finally:
        for sig, handler in saved.items():
            if handler is not None:
                signal.signal(sig, handler)


def ray_shutdown(ray: Any) -> None:
    """``ray.shutdown()`` with SIGINT and SIGTERM ignored while it runs (in the main thread):
    a Ctrl-C that landed in it (as a run ended, or a second one) cut it short, and the
    local Ray instance's dashboard and runtime-env agents were left running, orphaned."""
    import signal

    main = threading.current_thread() is threading.main_thread()
    sigs = (signal.SIGINT, signal.SIGTERM)
    saved = {s: signal.signal(s, signal.SIG_IGN) for s in sigs} if main else {}
    try:
        ray.shutdown()
    finally:
        for sig, handler in saved.items():
            if handler is not None:
                signal.signal(sig, handler)


@contextmanager
def interruptible() -> Iterator[None]:
    """While inside (in the main thread), SIGINT and SIGTERM raise :class:`Interrupted`.

    :func:`run_jobs` uses it; a command wraps its whole run in it too, so that a signal
    during its own preparation ends the same way. Previous handlers are restored on exit.

    A signal that lands while Python code runs inside a C callback -- numba compiling calls
    back into Python through ctypes (llvmlite's object cache) -- raises there, and ctypes
    swallows it ("Exception ignored on calling ctypes callback function"): the signal would
    be lost and the command run on. The :data:`sys.unraisablehook` installed here sees the
    swallowed :class:`Interrupted` and asks a watcher thread, started on entry, to send the
    signal again a few milliseconds later, so it is raised once the callback has returned.
    A signal that lands inside that hook (the re-sent one, on a loaded machine) is not raised
    there, where it would be swallowed once more, but handed to the watcher the same way.

    Compiled numba code calls back into Python too (``numba.core.serialize._numba_unpickle``
    fetches its constants), and a signal that arrived while a kernel ran is delivered there,
    at the first Python line since: raised there, it would come out of the kernel as
    ``SystemError: ... returned a result with an exception set``. Such a signal goes to the
    watcher the same way and is raised once the kernel has returned. Any other such wrapping
    is undone where the interrupt is reported (:func:`interrupt_in`).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    resend: list[str] = []  # signal names the watcher must send again
    wake = threading.Event()
    active = threading.Lock()  # held while sending, so none is sent once the block is left
    done = False

    def in_hook(frame: Any) -> bool:
        while frame is not None:
            if frame.f_code is unraisable.__code__:
                return True
            frame = frame.f_back
        return False

    def handler(signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        if in_hook(frame) or _in_compiled_callback(frame):
            resend.append(name)
            wake.set()
            return
        _LAST_SIGNAL[:] = [name]
        raise Interrupted(name)

    def unraisable(info: Any) -> None:
        if isinstance(info.exc_value, Interrupted):
            resend.append(info.exc_value.signal_name)
            wake.set()
            return
        old_hook(info)

    def watcher() -> None:
        while True:
            wake.wait()
            wake.clear()
            if done:
                return
            time.sleep(0.005)  # let the callback that swallowed it return first
            with active:
                if done:
                    return
                if resend:  # once, however often it was swallowed
                    name = resend[-1]
                    resend.clear()
                    os.kill(os.getpid(), signal.Signals[name])

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    old_hook = sys.unraisablehook
    sys.unraisablehook = unraisable
    threading.Thread(target=watcher, name="crowdsim-signal-resend", daemon=True).start()
    try:
        yield
    finally:
        try:
            with active:
                done = True
            wake.set()
        finally:  # restored even if a second signal lands here
            sys.unraisablehook = old_hook
            for s, h in old.items():
                signal.signal(s, h)


def run_jobs(
    jobs: Sequence[Job],
    manifest_path: str | os.PathLike[str],
    *,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    on_done: Callable[[str, Any], None] | None = None,
    section: str = "jobs",
    desc: str = "jobs",
    unit: str = "job",
    passthrough: tuple[type[BaseException], ...] = (ValueError, FileExistsError),
    worker_init: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Run every job whose key is not yet in the manifest; return all the jobs' results.

    Parameters
    ----------
    jobs : sequence of Job
        Unique keys.
    manifest_path : path
        JSON manifest; results are recorded under ``manifest[section][key]`` as each job
        finishes (under the lock, merged with what other runs wrote).
    workers : int
        Local processes (``backend="local"``; 1 runs in this process), or Ray tasks running
        at a time (``backend="ray"``).
    backend : {"local", "ray"}
        ``"ray"``: one Ray task (1 CPU) per job on the cluster at ``address`` (a local Ray
        instance when None).
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).
    on_done : callable, optional
        ``on_done(key, result)`` in this process after each job is recorded.
    section, desc, unit : str
        Manifest section; progress bar label and unit.
    passthrough : tuple of exception types
        Raised unchanged from a job; others become :class:`JobError`.
    worker_init : callable, optional
        Picklable, called once in each pool worker (e.g. to limit its threads).

    Returns
    -------
    dict
        ``{key: result}`` in the order of ``jobs`` (earlier runs' results included).

    Raises
    ------
    ValueError
        Duplicate keys, bad ``workers`` or ``backend``, Ray missing.
    JobError
        A job failed or a worker died.
    Interrupted
        SIGINT or SIGTERM; queued jobs were cancelled and running ones stopped.
    """
    require_choice("run_jobs", "backend", backend, ("local", "ray"))
    require_number("run_jobs", "workers", workers, lo=1, integer=True)
    keys = [j.key for j in jobs]
    if len(set(keys)) != len(keys):
        dup = next(k for k in keys if keys.count(k) > 1)
        raise ValueError(f"run_jobs: two jobs share the key {dup!r}")
    manifest_path = Path(manifest_path)
    done = read_manifest(manifest_path, section)[section]
    todo = [j for j in jobs if j.key not in done]
    if todo:
        bar = _Progress(todo, progress, desc, unit)

        def record(job: Job, result: Any) -> None:
            try:
                json.dumps(result)
            except (TypeError, ValueError):
                raise JobError(
                    job.key, f"{job.key}: the result is not JSON-serialisable: {result!r:.200}"
                ) from None
            with locked_manifest(manifest_path, section) as m:
                m[section][job.key] = result
            bar.finish(job.key)
            if on_done is not None:
                on_done(job.key, result)

        try:
            with interruptible():
                if backend == "ray":
                    _run_ray(todo, int(workers), address, record, passthrough)
                elif workers == 1 or len(todo) == 1:
                    _run_inline(todo, record, bar, passthrough)
                else:
                    _run_pool(
                        todo, min(int(workers), len(todo)), record, bar, passthrough, worker_init
                    )
        finally:
            bar.close()
    done = read_manifest(manifest_path, section)[section]
    return {k: done[k] for k in keys if k in done}


def _failure(
    job: Job, exc: BaseException, passthrough: tuple[type[BaseException], ...]
) -> BaseException:
    if isinstance(exc, passthrough):
        return exc
    stopped = interrupt_in(exc)  # a signal that came out of a compiled kernel or a clean-up
    if stopped is not None:
        return stopped
    return JobError(job.key, f"{job.key}: {type(exc).__name__}: {exc}")


def _run_inline(
    todo: list[Job],
    record: Callable[[Job, Any], None],
    bar: _Progress,
    passthrough: tuple[type[BaseException], ...],
) -> None:
    for job in todo:
        kwargs = dict(job.kwargs)
        if job.progress_kw:
            kwargs[job.progress_kw] = lambda n=1, key=job.key, **st: bar.advance(key, n, st)
        try:
            result = job.fn(*job.args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - reported with the key
            raise _failure(job, exc, passthrough) from exc
        record(job, result)


def _drain(queue: Any, bar: _Progress) -> None:
    import queue as queue_mod

    while True:
        try:
            key, n, status = queue.get_nowait()
        except queue_mod.Empty:
            return
        except (EOFError, OSError, ValueError):  # queue closed
            return
        bar.advance(key, n, status)


def _stop_pool(pool: Any) -> None:
    """SIGTERM every worker, SIGKILL it after the grace time; queued jobs then fail with the
    broken pool and never run. (Futures are not cancelled first: Python 3.11's executor
    raises InvalidStateError in its manager thread when a broken pool meets a cancelled
    future.)"""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.kill()
            p.join(1.0)


def _run_pool(
    todo: list[Job],
    workers: int,
    record: Callable[[Job, Any], None],
    bar: _Progress,
    passthrough: tuple[type[BaseException], ...],
    worker_init: Callable[[], None] | None,
) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, CancelledError, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")  # no fork of a process holding OpenCV/numba threads
    queue = ctx.Queue()
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=ctx,
        initializer=_worker_init,
        initargs=(os.getpid(), queue, worker_init),
    )
    futures: dict[Any, Job] = {}
    try:
        for job in todo:
            futures[pool.submit(_call_in_worker, job)] = job
        pending = set(futures)
        failure: BaseException | None = None
        while pending:
            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(queue, bar)
            for fut in finished:
                job = futures[fut]
                try:
                    result = fut.result()
                except CancelledError:
                    continue
                except BrokenProcessPool:
                    failure = failure or JobError(
                        job.key,
                        f"a worker process died while running {job.key}; finished "
                        "jobs are kept, rerun the same command to resume",
                    )
                except Exception as exc:  # noqa: BLE001 - reported with the key
                    failure = failure or _failure(job, exc, passthrough)
                else:
                    record(job, result)
            if failure is not None:
                for fut in pending:
                    fut.cancel()  # queued ones; running ones finish and are recorded
        _drain(queue, bar)
        if failure is not None:
            raise failure
    except KeyboardInterrupt:
        _stop_pool(pool)
        raise
    finally:
        pool.shutdown(wait=True)
        queue.close()
        queue.join_thread()


def _run_ray(
    todo: list[Job],
    workers: int,
    address: str | None,
    record: Callable[[Job, Any], None],
    passthrough: tuple[type[BaseException], ...],
) -> None:
    """At most ``workers`` Ray tasks at a time (``--workers`` caps them as it caps local
    processes: all at once had taken every CPU of the cluster whatever it said); on a failure
    the queued jobs are never started and the running ones finish and are recorded, as in a
    pool."""
    from crowdsim.optional import require

    ray = require("ray", "distributed", "--backend ray")
    ray_init(ray, address)
    task = ray.remote(num_cpus=1)(_call_on_ray)
    queued = list(todo)
    refs: dict[Any, Job] = {}
    failure: BaseException | None = None
    try:
        while refs or (queued and failure is None):
            while queued and failure is None and len(refs) < workers:
                job = queued.pop(0)
                refs[task.remote(job)] = job
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            for ref in ready:
                job = refs.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - Ray wraps worker errors
                    failure = failure or _ray_failure(job, exc, passthrough)
                    continue
                record(job, result)
        if failure is not None:
            raise failure
    except BaseException as exc:
        for ref in refs:
            ray.cancel(ref, force=True)
        if refs:  # cancelling is asynchronous: let the workers die before the caller cleans
            # up after them (a task still writing had finished a sequence after it)
            ray.wait(list(refs), num_returns=len(refs), timeout=STOP_GRACE_S)
        if isinstance(exc, KeyboardInterrupt) and not isinstance(exc, Interrupted):
            # ray.wait ran interruptible's handler in its C++ loop and raised a bare
            # KeyboardInterrupt in place of its Interrupted: the caller's clean-up (which
            # catches Interrupted) was skipped, and a SIGTERM ended with SIGINT's 130
            raise Interrupted(_LAST_SIGNAL[0] if _LAST_SIGNAL else "SIGINT") from None
        raise


def _ray_failure(
    job: Job, exc: BaseException, passthrough: tuple[type[BaseException], ...]
) -> BaseException:
    """What a failed Ray task raises: the job's own exception as a pool's would be
    (:func:`_failure`: one line naming the key), not Ray's wrapper, whose text is the
    worker's whole traceback in terminal colours; a worker that died is named in one line."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        return _failure(job, cause, passthrough)
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return JobError(
        job.key,
        f"{job.key}: the Ray task failed ({type(exc).__name__}: {first}); finished jobs are "
        "kept, rerun the same command to resume",
    )
