"""crowdsim.jobs: resumable manifest under a lock, failures, prompt stop, no orphan workers."""

from __future__ import annotations

import doctest
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import crowdsim.jobs as jobs_mod
from crowdsim.jobs import Interrupted, Job, JobError, read_manifest, run_jobs

ROOT = Path(__file__).resolve().parents[2]

HELPERS = textwrap.dedent("""
    import os, time

    def square(x, progress=None):
        if progress is not None:
            progress(1)
        return x * x

    def fail(x):
        raise RuntimeError(f"boom {x}")

    def user_error(x):
        raise ValueError(f"bad value {x}")

    def sleeper(folder, name):
        # record the worker pid (whole: written aside, then renamed), then work for a long time
        # (inside the try: a job that has shown its pid has its clean-up to run)
        path = os.path.join(folder, f"{name}.pid")
        try:
            with open(path + ".tmp", "w") as fh:
                fh.write(str(os.getpid()))
            os.replace(path + ".tmp", path)
            time.sleep(60)
        finally:
            with open(os.path.join(folder, f"{name}.cleaned"), "w") as fh:
                fh.write("1")
        return name

    def slow_cleaner(folder):
        # a clean-up that takes a while: a second SIGTERM arrives during it
        try:
            open(os.path.join(folder, "started"), "w").close()
            time.sleep(60)
        finally:
            open(os.path.join(folder, "cleaning"), "w").close()
            time.sleep(0.5)
            open(os.path.join(folder, "cleaned"), "w").close()
""")


@pytest.fixture()
def helpers(tmp_path, monkeypatch):
    (tmp_path / "jobhelpers.py").write_text(HELPERS)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), str(ROOT)]))
    import importlib

    import jobhelpers

    return importlib.reload(jobhelpers)


def test_module_example_runs():
    assert doctest.testmod(jobs_mod).failed == 0


@pytest.mark.parametrize("workers", [1, 2])
def test_results_recorded_and_resumed(tmp_path, helpers, workers):
    manifest = tmp_path / "m.json"
    seen = []
    jobs = [Job(f"k{i}", helpers.square, (i,), progress_kw="progress") for i in range(4)]
    out = run_jobs(
        jobs, manifest, workers=workers, progress=False, on_done=lambda k, r: seen.append(k)
    )
    assert out == {f"k{i}": i * i for i in range(4)} and sorted(seen) == sorted(out)
    assert read_manifest(manifest)["jobs"] == out
    seen.clear()
    more = jobs + [Job("k9", helpers.square, (9,))]
    assert (
        run_jobs(
            more, manifest, workers=workers, progress=False, on_done=lambda k, r: seen.append(k)
        )["k9"]
        == 81
    )
    assert seen == ["k9"]  # the first four were resumed from the manifest


def test_failures_name_the_key_and_keep_finished_jobs(tmp_path, helpers):
    manifest = tmp_path / "m.json"
    with pytest.raises(JobError, match=r"bad: RuntimeError: boom 3") as info:
        run_jobs(
            [Job("ok", helpers.square, (2,)), Job("bad", helpers.fail, (3,))],
            manifest,
            progress=False,
        )
    assert info.value.key == "bad"
    assert read_manifest(manifest)["jobs"] == {"ok": 4}
    with pytest.raises(ValueError, match="bad value 5"):  # user errors pass through as is
        run_jobs([Job("u", helpers.user_error, (5,))], manifest, progress=False)
    with pytest.raises(JobError, match=r"bad: RuntimeError: boom 1"):
        run_jobs(
            [Job("bad", helpers.fail, (1,)), Job("s", helpers.square, (3,))],
            manifest,
            workers=2,
            progress=False,
        )
    assert read_manifest(manifest)["jobs"]["s"] == 9  # the running one finished, recorded
    with pytest.raises(ValueError, match="two jobs share the key 'a'"):
        run_jobs([Job("a", helpers.square, (1,)), Job("a", helpers.square, (2,))], manifest)
    with pytest.raises(ValueError, match=r"run_jobs.workers must be an integer >= 1, got 0"):
        run_jobs([], manifest, workers=0)
    with pytest.raises(ValueError, match=r"Job.size must be a finite number >= 0"):
        Job("x", helpers.square, size=float("nan"))


def test_concurrent_runs_merge_the_manifest_under_the_lock(tmp_path, helpers):
    manifest = tmp_path / "m.json"
    script = (
        "import sys; from crowdsim.jobs import Job, run_jobs; import jobhelpers as h\n"
        "p = sys.argv[1]\n"
        "run_jobs([Job(f'{p}{i}', h.square, (i,)) for i in range(150)], sys.argv[2], "
        "progress=False)\n"
    )
    procs = [
        subprocess.Popen([sys.executable, "-c", script, p, str(manifest)], cwd=tmp_path)
        for p in ("a", "b", "c")
    ]
    assert [p.wait(timeout=60) for p in procs] == [0, 0, 0]
    done = json.loads(manifest.read_text())["jobs"]
    assert len(done) == 450 and done["b149"] == 149 * 149


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "\nState:\tZ" not in fh.read()
    except FileNotFoundError:
        return False


def _start_sleepers(tmp_path: Path, n: int, workers: int) -> tuple[subprocess.Popen, list[int]]:
    script = (
        "import sys; from crowdsim.jobs import Job, run_jobs, Interrupted\n"
        "import jobhelpers as h\n"
        f"jobs = [Job(f's{{i}}', h.sleeper, ({str(tmp_path)!r}, f's{{i}}')) "
        f"for i in range({n})]\n"
        "try:\n"
        f"    run_jobs(jobs, {str(tmp_path / 'm.json')!r}, workers={workers}, "
        "progress=False)\n"
        "except Interrupted as exc:\n"
        "    print('stopped by', exc.signal_name); sys.exit(2)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 30
    busy = min(n, workers)
    while len(list(tmp_path.glob("*.pid"))) < busy and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    pids = [int(p.read_text()) for p in tmp_path.glob("*.pid")]
    assert len(pids) == busy, "the workers did not start"
    return proc, pids


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_stops_promptly_and_workers_clean_up(tmp_path, helpers, sig):
    proc, pids = _start_sleepers(tmp_path, n=4, workers=2)
    t0 = time.monotonic()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=20)
    assert time.monotonic() - t0 < jobs_mod.STOP_GRACE_S + 2
    assert proc.returncode == 2 and out.strip() == f"stopped by {sig.name}", err
    assert "Traceback" not in err
    assert not any(_alive(p) for p in pids)
    # running jobs unwound (their finally ran), queued ones never started
    assert len(list(tmp_path.glob("*.cleaned"))) == 2 and len(list(tmp_path.glob("*.pid"))) == 2
    assert read_manifest(tmp_path / "m.json")["jobs"] == {}


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 30) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.02)


def test_a_second_sigterm_does_not_cut_a_clean_up_short(tmp_path, helpers):
    # once one worker has exited, the executor's manager thread SIGTERMs every other worker,
    # which may be in its job's clean-up by then: that second signal must not cut it short
    script = (
        "import signal, sys; from crowdsim import jobs; import jobhelpers as h\n"
        "signal.signal(signal.SIGTERM, jobs._on_sigterm)\n"
        f"jobs._call_in_worker(jobs.Job('c', h.slow_cleaner, ({str(tmp_path)!r},)))\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path, text=True)
    _wait_for(tmp_path / "started", proc)
    proc.send_signal(signal.SIGTERM)
    _wait_for(tmp_path / "cleaning", proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 128 + signal.SIGTERM
    assert (tmp_path / "cleaned").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_die_with_a_killed_parent(tmp_path, helpers):
    proc, pids = _start_sleepers(tmp_path, n=2, workers=2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=10)
    deadline = time.monotonic() + 5
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids)


def test_interrupted_is_a_keyboard_interrupt():
    exc = Interrupted("SIGTERM")
    assert isinstance(exc, KeyboardInterrupt) and exc.signal_name == "SIGTERM"


def _clean_up_fails_under_an_interrupt():
    # as Optuna's _run_trial does when the signal lands while it tells a trial's result:
    # its finally reads a name the interrupted try never set
    try:
        raise Interrupted("SIGTERM")
    finally:
        raise UnboundLocalError("cannot access local variable 'updated_state'")


def test_an_error_raised_while_an_interrupt_unwinds_is_the_interrupt(tmp_path):
    """A job whose clean-up fails on what the interrupt left stops the run as interrupted
    (CI saw ``tune`` end with a traceback and "JobError: ... UnboundLocalError", exit 1)."""
    with pytest.raises(Interrupted) as info:
        run_jobs([Job("a", _clean_up_fails_under_an_interrupt)], tmp_path / "m.json")
    assert info.value.signal_name == "SIGTERM"
    assert read_manifest(tmp_path / "m.json")["jobs"] == {}


def test_a_command_whose_clean_up_fails_under_an_interrupt_says_interrupted(monkeypatch, capsys):
    """The same for a command's own code, outside a job runner: one line, the signal's exit
    code, no traceback."""
    from crowdsim import cli
    from crowdsim.commands import evaluate

    def command(args) -> int:  # noqa: ANN001
        _clean_up_fails_under_an_interrupt()
        return 0

    monkeypatch.setattr(evaluate, "run", command)  # the parser is built in main, from this
    assert cli.main(["evaluate", "a", "b"]) == 143
    assert capsys.readouterr().err.strip().splitlines() == [
        "crowdsim evaluate: interrupted by SIGTERM"
    ]


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_a_signal_swallowed_by_a_c_callback_is_raised_after_it():
    """A signal that lands while Python runs inside a ctypes callback (numba's compiler calls
    back into Python that way) raises there and ctypes swallows it; interruptible() sends it
    again, so the command still stops, once the callback has returned."""
    import ctypes
    import ctypes.util

    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    compare_t = ctypes.CFUNCTYPE(
        ctypes.c_int, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)
    )
    fired = []

    def compare(a, b):
        if not fired:
            fired.append(True)
            signal.raise_signal(signal.SIGTERM)  # its handler raises here, inside the callback
        return a[0] - b[0]

    values = (ctypes.c_int * 4)(3, 1, 2, 0)
    with pytest.raises(Interrupted) as caught:
        with jobs_mod.interruptible():
            libc.qsort(values, 4, ctypes.sizeof(ctypes.c_int), compare_t(compare))
            assert fired  # the callback ran and swallowed the first Interrupted
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:  # the signal comes again
                time.sleep(0.001)
    assert caught.value.signal_name == "SIGTERM" and fired


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_a_signal_that_lands_inside_the_unraisable_hook_is_not_lost(monkeypatch):
    """The re-sent signal can land while the hook itself still runs (a loaded machine: CI lost
    a SIGINT that way, "Exception ignored in sys.unraisablehook", and the command ran on). Here
    the signal lands in the hook deterministically: an unrelated exception swallowed in a
    __del__ goes on to the previous hook, which sends SIGINT; it must still be raised."""
    sent = []

    def previous_hook(info):
        if not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGINT)  # handled right here, inside the hook

    monkeypatch.setattr(sys, "unraisablehook", previous_hook)

    class Dropped:
        def __del__(self):
            raise ValueError("swallowed by the interpreter")

    with pytest.raises(Interrupted) as caught:
        with jobs_mod.interruptible():
            Dropped()  # its __del__ raises: the interpreter calls the hook
            assert sent
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:  # the signal comes again, from the watcher
                time.sleep(0.001)
    assert caught.value.signal_name == "SIGINT"


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_a_signal_delivered_in_a_compiled_kernels_callback_is_raised_after_the_kernel():
    """A signal that arrives while a numba kernel runs is handled at the first Python line
    since, which can be numba's unpickling callback inside the kernel: raised there it came
    out as "SystemError: CPUDispatcher(...) returned a result with an exception set" (a
    Ctrl-C of `crowdsim track`, 4 times in 7). The handler, shown that frame, raises nothing
    and the signal comes again once the kernel has returned."""
    from types import SimpleNamespace

    from numba.core.serialize import _numba_unpickle

    in_kernel = SimpleNamespace(f_code=_numba_unpickle.__code__, f_back=None)
    with pytest.raises(Interrupted) as caught:
        with jobs_mod.interruptible():
            try:
                signal.getsignal(signal.SIGTERM)(signal.SIGTERM, in_kernel)
            except Interrupted:
                pytest.fail("raised inside the kernel's callback")
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:  # the signal comes again, from the watcher
                time.sleep(0.001)
    assert caught.value.signal_name == "SIGTERM"


def test_an_interrupt_a_c_extension_wrapped_still_ends_the_command_in_one_line(monkeypatch, capsys):
    """Any other C callback that wraps the interrupt as a SystemError's cause: the command
    still stops with the interrupt's one line and exit code, never a traceback or exit 1."""
    import crowdsim.cli as cli

    def wrapped(args):
        raise SystemError("returned a result with an exception set") from Interrupted("SIGTERM")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    args = parser.parse_args(["bench", "sim"])
    monkeypatch.setattr(parser, "parse_known_args", lambda argv=None: (args, []))
    monkeypatch.setattr(args, "func", wrapped)
    assert cli.main([]) == 143
    assert capsys.readouterr().err.strip().splitlines() == [
        "crowdsim bench sim: interrupted by SIGTERM"
    ]
    args.func = lambda a: (_ for _ in ()).throw(SystemError("a real one"))
    with pytest.raises(SystemError, match="a real one"):
        cli.main([])


def test_a_wrapped_interrupt_stops_inline_jobs_instead_of_failing_one(tmp_path):
    """run_jobs in this process: a job whose kernel handed the interrupt back as a
    SystemError stops the run as interrupted, not as that job's failure (exit 1)."""

    def job():
        raise SystemError("returned a result with an exception set") from Interrupted("SIGINT")

    with pytest.raises(Interrupted):
        run_jobs([Job("a", job)], tmp_path / "manifest.json", progress=False)


@pytest.mark.parametrize(
    "content",
    [
        "user data\n",
        '{"project": "mine"}',
        '{"format": 7, "jobs": {}}',
        '{"format": 1, "jobs": []}',
    ],
)
def test_a_manifest_crowdsim_did_not_write_is_refused_never_replaced(tmp_path, helpers, content):
    """crowdsim writes its manifests whole (format 1, a table of the section): any other file
    at the path is a user's or another tool's, refused before a job runs, and kept."""
    from crowdsim.jobs import locked_manifest

    path = tmp_path / "m.json"
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    with pytest.raises(ValueError, match="m.json: not a crowdsim manifest"):
        read_manifest(path)
    with pytest.raises(ValueError, match="refusing to replace it"):
        run_jobs([Job("a", helpers.square, (3,))], path, workers=1, progress=False)
    with pytest.raises(ValueError, match="m.json"), locked_manifest(path) as m:
        m["jobs"]["a"] = 1
    assert (path.read_bytes() if isinstance(content, bytes) else path.read_text()) == content
    (tmp_path / "d.json").mkdir()
    with pytest.raises(ValueError, match="d.json: is a folder, not crowdsim's manifest"):
        read_manifest(tmp_path / "d.json")
    # another section of a crowdsim manifest is crowdsim's: read as empty, kept on write
    path.write_text('{"format": 1, "sequences": {"s": 1}}')
    with locked_manifest(path) as m:
        m["jobs"]["a"] = 1
    assert read_manifest(path, "sequences")["sequences"] == {"s": 1}
    assert read_manifest(path)["jobs"] == {"a": 1}


@pytest.mark.parametrize("name", ["sim", "fd", "render", "solver", "track", "envs"])
def test_each_benchmark_script_is_its_bench_command(run_benchmark, name):
    """``python benchmarks/NAME.py`` runs ``crowdsim bench NAME`` itself: benchmarks/envs.py
    had shadowed the envs package (ModuleNotFoundError on every run), and the scripts had
    skipped the command's process settings and its one-line errors."""
    out = run_benchmark(f"{name}.py", "--help")
    assert out.returncode == 0, out.stderr
    assert f"usage: crowdsim bench {name}" in out.stdout
    bad = run_benchmark(f"{name}.py", "--no-such-flag")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr


def test_bench_envs_workers_are_at_most_the_cores(capsys):
    import os

    from crowdsim.cli import main

    n = (os.cpu_count() or 1) + 1
    assert main(["bench", "envs", "--only", "crowd", "--workers", str(n)]) == 2
    assert f"--workers must be in [1, {n - 1}]" in capsys.readouterr().err


# ---------------------------------------------------------------------------- Ray backend
class _TaskError(Exception):
    """Ray's wrapper of a task's exception: the job's own one as ``cause``, and the worker's
    whole traceback as its text."""

    def __init__(self, cause: BaseException) -> None:
        super().__init__(f"ray::_call_on_ray() (pid=1)\n  Traceback ...\n{cause!r}")
        self.cause = cause


class FakeRay:
    """The part of Ray that ``_run_ray`` calls: a task runs when it is first waited on, in
    the order submitted; ``most`` is the largest number of tasks submitted and not yet taken
    back with ``get`` (running, to the cluster)."""

    def __init__(self, interrupt_after: int | None = None) -> None:
        self.live: dict[int, Job] = {}
        self.most = 0
        self.cancelled: list[int] = []
        self.next = 0
        self.waits = 0
        self.interrupt_after = interrupt_after

    def is_initialized(self) -> bool:
        return True

    def remote(self, **resources):
        def wrap(fn):
            fake = self

            class Task:
                @staticmethod
                def remote(job: Job) -> int:
                    fake.next += 1
                    fake.live[fake.next] = job
                    fake.most = max(fake.most, len(fake.live))
                    return fake.next

            return Task

        return wrap

    def wait(self, refs, num_returns=1, timeout=None):
        self.waits += 1
        if self.waits - 1 == self.interrupt_after:
            raise KeyboardInterrupt  # Ray's C++ wait after it ran the signal's handler
        return sorted(refs)[:num_returns], sorted(refs)[num_returns:]

    def get(self, ref: int):
        job = self.live.pop(ref)
        try:
            return job.fn(*job.args, **job.kwargs)
        except Exception as exc:
            raise _TaskError(exc) from None

    def cancel(self, ref: int, force: bool = False) -> None:
        self.cancelled.append(ref)


@pytest.fixture()
def fake_ray(monkeypatch):
    def install(**kw) -> FakeRay:
        fake = FakeRay(**kw)
        monkeypatch.setitem(sys.modules, "ray", fake)
        return fake

    return install


@pytest.mark.parametrize("workers", [1, 2])
def test_ray_runs_at_most_workers_tasks_at_a_time(tmp_path, helpers, fake_ray, workers):
    ray = fake_ray()
    jobs = [Job(f"j{k}", helpers.square, (k,)) for k in range(5)]
    got = run_jobs(jobs, tmp_path / "m.json", workers=workers, backend="ray", progress=False)
    assert got == {f"j{k}": k * k for k in range(5)}
    assert ray.most == workers  # all five at once had taken every CPU of the cluster


def test_a_failed_ray_task_is_one_line_naming_the_job(tmp_path, helpers, fake_ray):
    ray = fake_ray()
    jobs = [
        Job("bad", helpers.fail, (3,)),
        Job("ok", helpers.square, (2,)),
        Job("never", helpers.square, (4,)),
    ]
    with pytest.raises(JobError) as info:
        run_jobs(jobs, tmp_path / "m.json", workers=2, backend="ray", progress=False)
    assert str(info.value) == "bad: RuntimeError: boom 3"  # not Ray's traceback
    assert info.value.key == "bad"
    # the running one finished and is recorded; the queued one never started
    assert read_manifest(tmp_path / "m.json")["jobs"] == {"ok": 4}
    assert ray.next == 2
    with pytest.raises(ValueError, match="^bad value 5$"):  # user errors as they are
        run_jobs(
            [Job("u", helpers.user_error, (5,))], tmp_path / "m.json", backend="ray", progress=False
        )


def test_an_interrupt_ray_raised_bare_is_the_signal_that_came(
    tmp_path, helpers, fake_ray, monkeypatch
):
    ray = fake_ray(interrupt_after=1)
    monkeypatch.setattr(jobs_mod, "_LAST_SIGNAL", ["SIGTERM"])
    jobs = [Job(f"j{k}", helpers.square, (k,)) for k in range(3)]
    with pytest.raises(Interrupted) as info:
        run_jobs(jobs, tmp_path / "m.json", workers=2, backend="ray", progress=False)
    assert info.value.signal_name == "SIGTERM"  # a bare KeyboardInterrupt had read as SIGINT
    assert ray.cancelled == [2, 3]  # the ones still running
    assert read_manifest(tmp_path / "m.json")["jobs"] == {"j0": 0}


def test_interruptible_notes_the_signal_it_raises():
    with pytest.raises(Interrupted), jobs_mod.interruptible():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
    assert jobs_mod._LAST_SIGNAL == ["SIGTERM"]


def test_an_address_where_nothing_answers_is_refused_at_once():
    import socket

    # a port held, bound and not listening, for the whole test: nothing can listen there (a
    # port merely free a moment ago could be taken meanwhile, by Ray in another test worker)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        t0 = time.monotonic()
        for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
            with pytest.raises(ValueError) as info:
                jobs_mod.check_ray_address(address)
            prefix = f"--address {address}: no Ray cluster answers there (Connection refused)"
            assert str(info.value).startswith(prefix)
            assert "\n" not in str(info.value)
        assert time.monotonic() - t0 < 5  # ray.init retried for many minutes
    for address in (None, "auto", "local", "not-an-address"):  # Ray's own to find or refuse
        jobs_mod.check_ray_address(address)


def test_ray_shutdown_is_not_cut_short_by_a_signal():
    calls = []

    class Ray:
        def shutdown(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)  # a Ctrl-C as the run ends
            time.sleep(0.1)
            calls.append("done")

    def cut_short(signum, frame):
        raise RuntimeError("the signal was raised inside ray.shutdown")

    before = signal.signal(signal.SIGINT, cut_short)
    try:
        jobs_mod.ray_shutdown(Ray())
        assert calls == ["done"]  # it had stopped half-way, the agents left running
        assert signal.getsignal(signal.SIGINT) is cut_short
    finally:
        signal.signal(signal.SIGINT, before)
