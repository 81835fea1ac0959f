"""Tuners: Optuna study resumes after a kill, bad studies are refused, RL training and
policies round-trip. Sequences are tiny (a few people, 12 small frames)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from crowdsim.optional import DependencyNotInstalled, require
from envs.episodes import tiny_scenarios
from envs.param_space import load_params
from envs.training import load_policy
from envs.tuners import Objective, complete_trials, open_study, storage_url, tune

TINY = tiny_scenarios()


def objective(**kw):
    return Objective(scenarios=dict(TINY), train_episodes=2, threshold_px=1.0, **kw)


def trials_of(out):
    con = sqlite3.connect(out / "study.db")
    try:
        rows = con.execute(
            "SELECT t.number, t.state, v.value FROM trials t LEFT JOIN "
            "trial_values v ON v.trial_id = t.trial_id ORDER BY t.number"
        ).fetchall()
    finally:
        con.close()
    return rows


def test_tune_writes_results_and_a_rerun_continues_the_study(tmp_path):
    out = tmp_path / "t"
    res = tune(
        objective(),
        trials=3,
        out=out,
        heldout=1,
        heldout_metrics="accuracy",
        progress=False,
        log=lambda m: None,
    )
    assert res.trials == 3
    first = [
        (t.number, t.params, t.value)
        for t in complete_trials(
            open_study(storage_url(None, out), "crowdsim-tune", objective(), "tpe", 0, 3)
        )
    ]
    doc = json.loads((out / "best_params.json").read_text())
    assert doc["trials"] == 3 and set(doc["params"]) == {
        "zeta",
        "eta",
        "w_sp",
        "w_g",
        "update_threshold",
    }
    # trial 0 is the paper defaults, so the best is never worse than them on the tuning set
    assert first[0][1] == {
        "zeta": 0.3,
        "eta": 0.2,
        "w_sp": 0.3,
        "w_g": 1.0,
        "update_threshold": 0.6,
    }
    assert doc["value"] >= doc["default_value"] == pytest.approx(first[0][2])
    assert set(doc["heldout"]) == {"defaults", "tuned"}
    for name in ("history.png", "importance.png", "heldout.json"):
        assert (out / name).stat().st_size > 0
    msgs = []
    res2 = tune(objective(), trials=5, out=out, heldout=0, progress=False, log=msgs.append)
    assert res2.trials == 5 and any("3 finished" in m for m in msgs)
    again = [
        (t.number, t.params, t.value)
        for t in complete_trials(
            open_study(storage_url(None, out), "crowdsim-tune", objective(), "tpe", 0, 5)
        )
    ]
    assert again[:3] == first
    # the file round-trips into the tracker's parameters
    name, params = load_params(out / "best_params.json")
    doc = json.loads((out / "best_params.json").read_text())
    assert name == "bqp" and params.zeta == pytest.approx(doc["params"]["zeta"])


@pytest.mark.parametrize("tracker", ["pnmc", "ncc"])
def test_tune_any_tunable_tracker_from_the_cli(tmp_path, tracker):
    """crowdsim tune --tracker pnmc|ncc: the tracker's own row of tunables, trial 0 at its
    defaults, a best_params.json that loads back into that tracker, and heldout reading it."""
    from crowdsim.cli import main
    from envs.param_space import ParamSpace
    from tracker.registry import get

    spec = tmp_path / "d.json"
    spec.write_text(json.dumps(dict(TINY)))
    out = tmp_path / "t"
    args = ["--scenarios", str(spec), "--tracker", tracker, "--frames", "8", "--no-progress"]
    assert main(["tune", *args, "--trials", "2", "--train-episodes", "1", "--heldout", "0",
                 "--out", str(out)]) == 0  # fmt: skip
    doc = json.loads((out / "best_params.json").read_text())
    space = ParamSpace(tracker=tracker)
    assert doc["tracker"] == tracker and set(doc["params"]) == set(space.names)
    optuna = pytest.importorskip("optuna")
    first = optuna.load_study(study_name="crowdsim-tune", storage=storage_url(None, out)).trials[0]
    assert first.params == dict(zip(space.names, space.default.tolist(), strict=True))
    name, params = load_params(out / "best_params.json")
    assert name == tracker and isinstance(params, get(tracker).params_class())
    held = tmp_path / "h"
    assert main(["heldout", *args, "--params", str(out / "best_params.json"), "--seeds", "1",
                 "--metrics", "accuracy", "--out", str(held)]) == 0  # fmt: skip


def test_a_rerun_without_heldout_scoring_removes_the_earlier_runs_scores(tmp_path, capsys):
    """tune --heldout 1, then the same folder with --heldout 0: the first run's heldout.*
    would read as the new parameters' scores, so the rerun removes the ones it wrote; a file
    the user edited since is kept."""
    from crowdsim.cli import main

    spec = tmp_path / "d.json"
    spec.write_text(json.dumps(dict(TINY)))
    out = tmp_path / "t"
    args = ["tune", "--scenarios", str(spec), "--frames", "8", "--train-episodes", "1",
            "--no-progress", "--out", str(out)]  # fmt: skip
    assert main([*args, "--trials", "2", "--heldout", "1"]) == 0
    assert all((out / n).is_file() for n in ("heldout.json", "heldout.md", "heldout.png"))
    listed = json.loads((out / "best_params.json").read_text())["heldout_files"]
    assert sorted(listed) == ["heldout.json", "heldout.md", "heldout.png"]
    (out / "heldout.md").write_text("my notes on the held-out run\n")
    capsys.readouterr()
    assert main([*args, "--trials", "3", "--heldout", "0"]) == 0
    assert not (out / "heldout.json").exists() and not (out / "heldout.png").exists()
    assert (out / "heldout.md").read_text() == "my notes on the held-out run\n"
    assert "removed the earlier run's held-out scores (heldout.json, heldout.png)" in (
        capsys.readouterr().err
    )
    doc = json.loads((out / "best_params.json").read_text())
    assert doc["heldout"] == {} and doc["heldout_files"] == {}


def test_killed_run_resumes_without_losing_finished_trials(tmp_path):
    out = tmp_path / "k"
    spec = tmp_path / "tiny.json"
    spec.write_text(json.dumps(TINY))
    cmd = [
        sys.executable,
        "-c",
        "import sys; from crowdsim.cli import main; sys.exit(main())",
        "tune",
        "--scenarios",
        str(spec),
        "--trials",
        "40",
        "--train-episodes",
        "2",
        "--threshold",
        "1",
        "--heldout",
        "0",
        "--no-progress",
        "--out",
        str(out),
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    done = []
    while time.monotonic() - t0 < 120:
        time.sleep(0.2)
        if (out / "study.db").exists():
            try:
                done = [r for r in trials_of(out) if r[1] == "COMPLETE"]
            except sqlite3.OperationalError:
                continue
            if len(done) >= 3:
                break
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stderr.close()
    before = [r for r in trials_of(out) if r[1] == "COMPLETE"]
    assert len(before) >= 3
    want = len(before) + 2
    cmd[cmd.index("40")] = str(want)
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr[-2000:]
    after = trials_of(out)
    complete = [r for r in after if r[1] == "COMPLETE"]
    assert len(complete) >= want
    assert set(before) <= set(complete)  # same numbers, same values
    assert not [r for r in after if r[1] == "RUNNING"]
    assert json.loads((out / "best_params.json").read_text())["trials"] == len(complete)


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_stopped_local_run_says_what_the_study_keeps(tmp_path):
    """SIGTERM to a local ``tune``: one line saying the finished trials are kept and the
    same command resumes (as a Ray run says; it said only "interrupted by SIGTERM")."""
    out = tmp_path / "s"
    spec = tmp_path / "tiny.json"
    spec.write_text(json.dumps(TINY))
    cmd = [sys.executable, "-c", "import sys; from crowdsim.cli import main; sys.exit(main())"]
    cmd += ["tune", "--scenarios", str(spec), "--trials", "40", "--train-episodes", "1"]
    cmd += ["--heldout", "0", "--no-progress", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        time.sleep(0.2)
        try:
            if (out / "study.db").exists() and any(r[1] == "COMPLETE" for r in trials_of(out)):
                break
        except sqlite3.OperationalError:
            continue
        assert proc.poll() is None, proc.stderr.read()[-2000:]
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err[-2000:]
    kept = sum(r[1] == "COMPLETE" for r in trials_of(out))
    assert err.strip().splitlines()[-1] == (
        f"crowdsim tune: interrupted by SIGTERM; the study keeps its {kept} finished "
        "trial(s); the same command resumes"
    )


def test_journal_storage_and_cmaes(tmp_path):
    journal = tmp_path / "shared" / "study.log"
    res = tune(
        objective(),
        trials=3,
        out=tmp_path / "j",
        study=str(journal),
        sampler="cmaes",
        heldout=0,
        progress=False,
        log=lambda m: None,
    )
    assert res.trials == 3 and journal.stat().st_size > 0
    assert storage_url(str(journal), tmp_path) == f"journal:{journal.resolve()}"


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="two local workers need two cores")
def test_two_local_workers_share_the_study(tmp_path):
    res = tune(
        objective(),
        trials=4,
        out=tmp_path / "w",
        workers=2,
        heldout=0,
        progress=False,
        log=lambda m: None,
    )
    # exactly --trials, the enqueued paper defaults included: the workers share out the
    # trials still missing (each stopping on the count alone, both finished one past it)
    assert res.trials == 4 and len(trials_of(tmp_path / "w")) == 4
    # the enqueued defaults run once, before the workers start: two processes popping one
    # enqueued trial from SQLite made one fail ("Cannot tell a COMPLETE trial", optuna #4621)
    rows = trials_of(tmp_path / "w")
    assert rows[0][1] == "COMPLETE" and all(state == "COMPLETE" for _, state, _ in rows)
    study = open_study(storage_url(None, tmp_path / "w"), "crowdsim-tune", objective(), "tpe", 0, 4)
    assert [t.number for t in study.trials if t.user_attrs.get("defaults")] == [0]


def test_bad_studies_and_sources_are_refused(tmp_path):
    out = tmp_path / "bad"
    out.mkdir()
    (out / "study.db").write_bytes(b"this is not a database at all" * 40)
    with pytest.raises(ValueError, match="not an Optuna study"):
        tune(objective(), trials=1, out=out, heldout=0, progress=False)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    con = sqlite3.connect(foreign / "study.db")
    con.execute("CREATE TABLE people (id INTEGER)")
    con.commit()
    con.close()
    with pytest.raises(ValueError, match="not an Optuna study"):
        tune(objective(), trials=1, out=foreign, heldout=0, progress=False)
    journal = tmp_path / "x.log"
    journal.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ValueError, match="not an Optuna journal"):
        tune(
            objective(), trials=1, out=tmp_path / "y", study=str(journal), heldout=0, progress=False
        )
    with pytest.raises(ValueError, match="--study must be"):
        storage_url("mystudy", tmp_path)
    with pytest.raises(ValueError, match="unknown suite 'nope'"):
        tune(Objective(suite="nope"), trials=1, out=tmp_path / "z", progress=False)
    with pytest.raises(ValueError, match="unknown scenario 'parade'"):
        Objective(scenarios="parade").episodes()
    with pytest.raises(ValueError, match="--sampler"):
        tune(objective(), trials=1, out=tmp_path / "s", sampler="grid", progress=False)


def test_missing_extras_name_the_install_line(monkeypatch, tmp_path):
    with pytest.raises(DependencyNotInstalled, match=r"pip install 'crowdsim\[distributed\]'"):
        require("crowdsim_no_such_module", "distributed", "--backend ray")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(ValueError, match=r"pip install 'crowdsim\[distributed\]'"):
        tune(objective(), trials=1, out=tmp_path / "r", backend="ray", heldout=0, progress=False)
    assert not (tmp_path / "r").exists()  # checked first: no .tune.lock, no empty study.db
    monkeypatch.setitem(sys.modules, "torch", None)  # as if torch were not installed
    from envs.training import train

    with pytest.raises(ValueError, match=r"pip install 'crowdsim\[rl\]'"):
        train("ppo", out=tmp_path, steps=1)


def test_train_ppo_saves_a_policy_that_tracks(tmp_path):
    pytest.importorskip("stable_baselines3")
    from envs.episodes import ScenarioDistribution, ScenarioEpisodes
    from envs.param_space import ParamSpace
    from envs.tracker_tuning import PolicyControlled, make_tuned_tracker
    from envs.training import train
    from tracker.runner import run_tracker

    sb3_dirs = set(Path(tempfile.gettempdir()).glob("SB3-*"))
    doc = train(
        "ppo",
        out=tmp_path,
        n_envs=1,
        steps=12,
        env_kwargs={"scenarios": dict(TINY), "k_frames": 5},
        progress=False,
        log=lambda m: None,
    )
    assert len(doc["episodes"]) >= 3  # 3 steps per 12-frame episode
    # PPO runs whole rollouts (n_steps 4 here): 12 asked, 12 trained; the record says both
    assert doc["steps_asked"] == 12 and doc["steps"] == 12
    assert doc["episodes"][-1]["steps"] <= doc["steps"]
    assert all(0 <= e["reward_per_step"] <= 100 for e in doc["episodes"])
    assert (tmp_path / "learning_curve.png").stat().st_size > 0
    assert set(Path(tempfile.gettempdir()).glob("SB3-*")) == sb3_dirs  # no logger litter
    model, meta = load_policy(tmp_path / "model.zip")
    assert meta["algo"] == "ppo" and meta["env_kwargs"]["k_frames"] == 5
    d = ScenarioDistribution(**{k: tuple(v) if isinstance(v, list) else v for k, v in TINY.items()})
    seq = ScenarioEpisodes(d, seed=7).episode(0)
    space = ParamSpace()
    trk = make_tuned_tracker("bqp", space.to_params(space.default_action))
    ctl = PolicyControlled(seq, trk, model, space, k_frames=5)
    run = run_tracker(trk, ctl, metrics="accuracy")
    assert len(ctl.actions) == 3 and run.result.n_frames == 12
    # a zip that is not a crowdsim policy is refused
    import zipfile

    other = tmp_path / "other.zip"
    with zipfile.ZipFile(other, "w") as zf:
        zf.writestr("data", "{}")
    with pytest.raises(ValueError, match="not a policy for crowdsim/TrackerTuning-v0"):
        load_policy(other)
    (tmp_path / "junk.zip").write_bytes(b"junk")
    with pytest.raises(ValueError, match="not a zip"):
        load_policy(tmp_path / "junk.zip")


def test_ray_backend_on_a_local_instance(tmp_path):
    """Ray Tune with OptunaSearch on a local 2-CPU Ray instance (no dashboard): every result
    lands in the Optuna study, the paper defaults first, and a rerun resumes."""
    ray = pytest.importorskip("ray", reason="Ray is the distributed extra (in dev since issue 13)")
    pytest.importorskip("ray.tune")
    started = not ray.is_initialized()  # another test of this process may have started one
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        out = tmp_path / "ray"
        res = tune(
            objective(),
            trials=3,
            out=out,
            backend="ray",
            workers=2,
            heldout=0,
            progress=False,
            log=lambda m: None,
        )
        assert res.trials == 3 and res.default_value is not None
        study = open_study(storage_url(None, out), "crowdsim-tune", objective(), "tpe", 0, 3)
        trials = complete_trials(study)
        assert len(trials) == 3 and all(t.user_attrs.get("ray") for t in trials)
        defaults = [t for t in trials if t.user_attrs.get("defaults")]
        assert len(defaults) == 1 and defaults[0].params == {
            "zeta": 0.3,
            "eta": 0.2,
            "w_sp": 0.3,
            "w_g": 1.0,
            "update_threshold": 0.6,
        }
        # the Ray trial scored exactly what the local scorer gives the same parameters
        from envs.tuners import Scorer

        assert defaults[0].value == pytest.approx(Scorer(objective())(defaults[0].params)[0])
        assert json.loads((out / "best_params.json").read_text())["trials"] == 3
        res = tune(objective(), trials=4, out=out, backend="ray", heldout=0, progress=False)
        assert res.trials == 4
    finally:
        if started:
            ray.shutdown()


def test_a_scenarios_file_named_another_way_resumes_its_study(tmp_path, monkeypatch):
    """``--scenarios d.json``, then ``./d.json`` or the same file from another working folder:
    one objective (as a suite folder is), never refused as "made for another objective"."""
    monkeypatch.chdir(tmp_path)
    Path("d.json").write_text(json.dumps(TINY))
    kw = dict(out=tmp_path / "o", heldout=0, progress=False, log=lambda m: None)
    assert tune(Objective(scenarios="d.json", train_episodes=1), trials=1, **kw).trials == 1
    assert tune(Objective(scenarios="./d.json", train_episodes=1), trials=2, **kw).trials == 2
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    assert tune(Objective(scenarios="../d.json", train_episodes=1), trials=3, **kw).trials == 3


def test_a_suite_of_more_sequences_than_train_episodes_is_said(tmp_path):
    """``--suite ucf9 --only seq4 seq5 seq6`` with ``--train-episodes 2``: the trials score
    seq4 and seq5 alone, and tune says so (it had dropped seq6 in silence)."""
    said: list[str] = []
    obj = Objective(suite="ucf9", only=("seq4", "seq5", "seq6"), frames=3, train_episodes=2)
    tune(obj, trials=1, out=tmp_path / "o", heldout=0, progress=False, log=said.append)
    assert any(
        "the first 2 of the suite's 3 sequences (seq4, seq5; not seq6)" in m for m in said
    ), said


def test_ray_backend_with_a_relative_scenarios_file(tmp_path, monkeypatch):
    """Ray Tune runs each trial in a folder of its own: ``--scenarios d.json`` named relative
    to the working folder had failed every trial, and the run had ended in "max() arg is an
    empty sequence"."""
    ray = pytest.importorskip("ray", reason="Ray is the distributed extra (in dev since issue 13)")
    pytest.importorskip("ray.tune")
    monkeypatch.chdir(tmp_path)
    Path("d.json").write_text(json.dumps(TINY))
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        obj = Objective(scenarios="d.json", train_episodes=1)
        res = tune(obj, trials=1, out="o", backend="ray", heldout=0, progress=False)
        assert res.trials == 1
    finally:
        if started:
            ray.shutdown()


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
@pytest.mark.parametrize("when", ["starting", "tuning"])
def test_sigterm_under_ray_ends_with_one_line_and_143(tmp_path, when):
    """SIGTERM to ``tune --backend ray`` while Ray starts or while Ray Tune runs trials: one
    line and exit 143, as every command (Ray's own handlers gave exit 15 without a word, or
    exit 134 with a stack dump)."""
    pytest.importorskip("ray", reason="Ray is the distributed extra (in dev since issue 13)")
    pytest.importorskip("ray.tune")
    out = tmp_path / "r"
    spec = tmp_path / "tiny.json"
    spec.write_text(json.dumps(TINY))
    cmd = [sys.executable, "-c", "import sys; from crowdsim.cli import main; sys.exit(main())"]
    cmd += ["tune", "--scenarios", str(spec), "--trials", "40", "--train-episodes", "1"]
    cmd += ["--backend", "ray", "--heldout", "0", "--no-progress", "--out", str(out)]
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env
    )
    started = out / "ray" / "crowdsim-tune"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        time.sleep(0.1)
        if when == "starting" and (out / "study.db").exists():
            time.sleep(2.0)  # the study is open: Ray starts (it takes some 5 s)
            break
        if when == "tuning" and started.is_dir() and any(p.is_dir() for p in started.iterdir()):
            time.sleep(1.0)  # a trial runs
            break
        assert proc.poll() is None, proc.stderr.read()[-2000:]
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err[-2000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("crowdsim tune: interrupted by SIGTERM"), err[-2000:]
    assert "Traceback" not in err and "SIGTERM received" not in err


def _tune_logged(out: Path, raises: type[BaseException], match: str | None = None) -> list:
    """Optuna's log records of a 5-trial ``tune`` into ``out`` that ends in ``raises``."""
    import logging

    records = []
    handler = logging.Handler()
    handler.emit = records.append
    logging.getLogger("optuna").addHandler(handler)
    try:
        with pytest.raises(raises, match=match):
            tune(objective(), trials=5, out=out, heldout=0, progress=False)
    finally:
        logging.getLogger("optuna").removeHandler(handler)
    return records


def test_an_interrupt_while_a_trial_notes_its_scores_prints_no_optuna_traceback(
    tmp_path, capsys, monkeypatch
):
    """The signal may land in the trial's last storage write (its per-episode scores): that
    trial too is failed in silence (Optuna had logged "Trial 1 failed ... Interrupted" with
    a 40-line traceback), and the interrupt reaches the caller."""

    import optuna

    from crowdsim.jobs import Interrupted

    noted = optuna.trial.Trial.set_user_attr
    calls = []

    def set_user_attr(self, key, value):
        calls.append(key)
        if key == "per_episode" and calls.count(key) == 2:
            raise Interrupted("SIGTERM")
        return noted(self, key, value)

    monkeypatch.setattr(optuna.trial.Trial, "set_user_attr", set_user_attr)
    records = _tune_logged(tmp_path / "i", Interrupted)
    assert not [r.getMessage() for r in records if "failed" in r.getMessage()]
    assert "Traceback" not in capsys.readouterr().err
    assert [state for _, state, _ in trials_of(tmp_path / "i")] == ["COMPLETE", "FAIL"]


def test_an_interrupt_as_a_trial_ends_leaves_no_heartbeat_thread_beating(tmp_path, monkeypatch):
    """Optuna stops a trial's heartbeat thread as the trial ends; an interrupt that lands
    just before it does left a non-daemon thread beating for ever, and the stopped command
    never exited. The tuner stops such threads on its way out."""
    import threading

    from optuna.storages._heartbeat import HeartbeatThread

    from crowdsim.jobs import Interrupted

    joins = []

    def join(self):  # the interrupt lands before the stop event is set
        joins.append(self)
        if len(joins) == 2:
            raise Interrupted("SIGTERM")
        self._stop_event.set()
        self._thread.join()

    monkeypatch.setattr(HeartbeatThread, "join", join)
    with pytest.raises(Interrupted):
        tune(objective(), trials=5, out=tmp_path / "h", heldout=0, progress=False)
    beating = joins[1]._thread
    assert beating is not None and not beating.is_alive()
    assert not [t for t in threading.enumerate() if t is beating]


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_signal_lands_between_storage_calls_never_inside_one(tmp_path, monkeypatch):
    """A SIGTERM raised inside a storage read left its SQLite statement unfinished, kept
    alive by the interrupt's traceback, holding the lock that Optuna's next write waited on
    for the 120 s busy timeout. The storage's calls (private ones too: Optuna's cache calls
    those) hold signals back until they return: the read finishes, then the interrupt."""
    from optuna.storages import RDBStorage

    from crowdsim.jobs import Interrupted, interruptible
    from envs.tuners import open_storage

    storage = open_storage(f"sqlite:///{tmp_path / 's.db'}")
    assert isinstance(storage, RDBStorage)
    read = RDBStorage.get_all_studies
    finished = []

    def get_all_studies(self):
        os.kill(os.getpid(), signal.SIGTERM)  # lands here: held until the call returns
        time.sleep(0.05)
        studies = read(self)
        finished.append(True)
        return studies

    monkeypatch.setattr(RDBStorage, "get_all_studies", get_all_studies)
    with pytest.raises(Interrupted) as info, interruptible():
        storage.get_all_studies()
        time.sleep(1.0)  # the interrupt comes here, once the call has returned
    assert finished == [True] and info.value.signal_name == "SIGTERM"


def test_interrupted_trial_prints_no_optuna_traceback(tmp_path, capsys, monkeypatch):
    """Ctrl-C (or SIGTERM, raised as jobs.Interrupted) in a trial: the trial is marked failed,
    Optuna logs nothing about it, and the interrupt reaches the caller unchanged."""

    import envs.tuners
    from crowdsim.jobs import Interrupted

    calls = []

    class Stop:
        def __init__(self, objective):
            self.space = objective.space()

        def __call__(self, values):
            calls.append(values)
            if len(calls) == 2:
                raise Interrupted("SIGTERM")
            return 50.0, [50.0]

    monkeypatch.setattr(envs.tuners, "_scorer", Stop)
    records = _tune_logged(tmp_path / "i", Interrupted)
    assert len(calls) == 2
    assert not [r.getMessage() for r in records if "failed" in r.getMessage()]
    assert "Traceback" not in capsys.readouterr().err
    states = [state for _, state, _ in trials_of(tmp_path / "i")]
    assert states == ["COMPLETE", "FAIL"]
    # an ordinary error is still logged by Optuna (the filter is for interrupts only)

    class Broken(Stop):
        def __call__(self, values):
            raise RuntimeError("a real bug")

    monkeypatch.setattr(envs.tuners, "_scorer", Broken)
    records = _tune_logged(tmp_path / "i", Exception, match="a real bug")
    assert [r for r in records if "a real bug" in r.getMessage()]


def test_broken_journal_and_files_are_named(tmp_path):
    journal = tmp_path / "j.log"
    journal.write_text('{"op_code": 0, "worker_id": "w"}\n{broken\n')
    with pytest.raises(ValueError, match=f"{journal}: not an Optuna journal file"):
        tune(objective(), trials=1, out=tmp_path / "o", study=str(journal), heldout=0)
    assert not (tmp_path / "o").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "history.png").write_bytes(b"my plot")
    with pytest.raises(ValueError, match="history.png exists and was not written by crowdsim"):
        tune(objective(), trials=1, out=mine, heldout=0, progress=False)
    assert sorted(p.name for p in mine.iterdir()) == ["history.png"]


def test_tuned_integer_fields_are_written_and_read_as_integers(tmp_path):
    """``update_every`` (an integer tunable of the extended NCC and PNMC rows) reaches
    best_params.json as 11, not 11.0, and files of earlier releases that wrote 11.0 load as 11."""
    from crowdsim.cli import main

    spec = tmp_path / "d.json"
    spec.write_text(json.dumps(dict(TINY)))
    out = tmp_path / "t"
    args = ["--scenarios", str(spec), "--tracker", "ncc", "--extended", "--frames", "8"]
    assert main(["tune", *args, "--no-progress", "--trials", "2", "--train-episodes", "1",
                 "--heldout", "0", "--out", str(out)]) == 0  # fmt: skip
    doc = json.loads((out / "best_params.json").read_text())
    assert type(doc["params"]["update_every"]) is int
    assert all(type(v) is float for k, v in doc["params"].items() if k != "update_every")
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"tracker": "pnmc", "params": {"update_every": 11.0, "tau": 0.5}}))
    name, params = load_params(old)
    assert name == "pnmc" and type(params.update_every) is int and params.update_every == 11
    assert params.tau == 0.5


def test_a_study_storage_that_fills_mid_run_is_one_os_error(tmp_path, monkeypatch, study_disk_full):
    """A full disk under the study (Optuna's commit fails) ends as one OSError naming the
    study file; the finished trials stay in the study."""
    import optuna

    storage = optuna.storages.RDBStorage
    real, told = storage.set_trial_state_values, []

    def tell(self, trial_id, state, *args, **kwargs):
        told.append(state)
        if told.count(optuna.trial.TrialState.COMPLETE) == 2:  # the second trial's result
            study_disk_full()
        return real(self, trial_id, state, *args, **kwargs)

    monkeypatch.setattr(storage, "set_trial_state_values", tell)
    db = tmp_path / "t" / "study.db"
    with pytest.raises(
        OSError, match=f"^{db}: the study storage failed: database or disk is full$"
    ):
        tune(objective(), trials=4, out=tmp_path / "t", heldout=0, progress=False)
    assert [state for _, state, _ in trials_of(tmp_path / "t")] == ["COMPLETE", "RUNNING"]


def test_history_plot_names_its_threshold_and_numbers_trials_whole(tmp_path, monkeypatch):
    """history.png's axis read "accuracy at T px" whatever --threshold was, and its trial
    axis was ticked at 0.5, 1.5, ... for a few trials."""
    optuna = pytest.importorskip("optuna")
    import crowdsim.plotting as plotting
    from envs import tuners

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="maximize")
    study.optimize(lambda t: 100 * t.suggest_float("x", 0, 1), n_trials=4)
    figs = []
    real = plotting.save_figure
    monkeypatch.setattr(
        plotting, "save_figure", lambda fig, path, dpi=120: figs.append(fig) or real(fig, path, dpi)
    )
    tuners.plot_history(study, tmp_path / "history.png", 15.0)
    (ax,) = figs[0].axes
    assert ax.get_ylabel() == "accuracy at 15 px on the tuning sequences (%)"
    lo, hi = ax.get_xlim()
    ticks = [t for t in ax.get_xticks() if lo <= t <= hi]
    assert ticks and all(float(t).is_integer() for t in ticks)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["trial", "best so far"]
    assert (tmp_path / "history.png").read_bytes()[:4] == b"\x89PNG"


def test_ray_tunes_sigint_handler_is_not_left_behind_after_a_whole_run():
    """Ray Tune installs a SIGINT handler for ``Tuner.fit`` and leaves it after a run that no
    signal stopped: the first Ctrl-C of the held-out scoring after it did nothing."""
    import signal

    from envs.tuners import _sigterm_stops_tune

    ours = signal.getsignal(signal.SIGINT)
    before = signal.getsignal(signal.SIGTERM)
    with _sigterm_stops_tune():
        signal.signal(signal.SIGINT, lambda s, f: None)  # what Tuner.fit does
    assert signal.getsignal(signal.SIGINT) is ours
    assert signal.getsignal(signal.SIGTERM) is before
