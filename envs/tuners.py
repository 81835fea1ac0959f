"""Tuners of a tracker's static parameters (BQP, PNMC, NCC): Optuna and Ray Tune drivers.

* :func:`tune` -- black-box search of the static parameters on the bandit environment
  (``crowdsim/TrackerTuningBandit-v0``): Optuna (TPE or CMA-ES) with its study in SQLite by
  default, so a killed run resumes without losing a finished trial; a PostgreSQL URL or a
  journal file serve several machines; ``backend="ray"`` runs Ray Tune with ``OptunaSearch``
  on a Ray cluster. Writes ``best_params.json``, the optimisation history and the parameter
  importances as PNGs, and scores the best parameters against the paper defaults on
  **held-out** sequences (other seeds than the ones tuned on; :mod:`envs.heldout`).
* :class:`Objective` -- the sequences a trial scores (shared with :mod:`envs.heldout`).

Adaptive policies (PPO / SAC) are trained in :mod:`envs.training`. Heavy stacks (optuna, ray)
are imported on use; a missing one raises :class:`DependencyNotInstalled` naming the extra to
install.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import sys
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import (
    StudyStorageError,
    new_study_files,
    output_folder,
    sha256_file,
    signals_held,
    study_storage,
)
from crowdsim.checks import require_choice, require_number, require_sequences, require_workers
from crowdsim.jobs import Interrupted, check_ray_address, ray_init, read_manifest
from crowdsim.optional import DependencyNotInstalled, require
from envs.episodes import (
    EpisodeSource,
    ScenarioDistribution,
    SuiteEpisodes,
    make_episodes,
    shows_someone,
)
from envs.heldout import (
    HELDOUT_FILES,
    HELDOUT_SEED,
    check_heldout_out,
    evaluate_heldout,
    write_heldout,
)
from envs.outputs import check_outputs, read_record, write_outputs
from envs.param_space import ParamSpace, require_tunable

STUDY_FILE = "study.db"
JOBS_MANIFEST = "tune_jobs.json"
"""The jobs runner's record of the finished workers (:mod:`crowdsim.jobs`), in ``--out``."""
DEFAULT_STUDY_NAME = "crowdsim-tune"
SAMPLERS: tuple[str, ...] = ("tpe", "cmaes")
BACKENDS: tuple[str, ...] = ("local", "ray")


# ---------------------------------------------------------------------------- objective
@dataclass(frozen=True, kw_only=True)
class Objective:
    """What one tuning trial scores: mean accuracy at ``threshold_px`` over fixed episodes.

    Attributes
    ----------
    suite : str, optional
        Built-in suite name or folder of MOT sequences (exclusive with ``scenarios``).
    scenarios : str or dict, optional
        ``"all"``, ``"nonstationary"``, a comma list of scenarios, a distribution file, or the
        fields of :class:`envs.episodes.ScenarioDistribution`.
    only : tuple of str
        Suite sequences to tune on.
    heldout_only : tuple of str
        Sequences of a folder of MOT sequences to score on (it cannot be re-seeded; built-in
        suites, spec folders and scenarios use other seeds of the same sequences instead).
    frames : int, optional
        Frames per sequence.
    train_episodes : int
        Episodes every trial is scored on: the first ones of stream 0, or of the suite's
        sequences (a suite of more is scored on its first ``train_episodes``, which
        :func:`tune` says).
    threshold_px : float
        Accuracy threshold T, px.
    extended : bool
        Tune the tracker's extra tunables too (BQP: 8 parameters instead of 5).
    tracker : str
        Registry name of a tunable tracker (a row of :data:`envs.param_space.TUNABLES`).
    """

    suite: str | None = None
    scenarios: Any = None
    only: tuple[str, ...] = ()
    heldout_only: tuple[str, ...] = ()
    frames: int | None = None
    train_episodes: int = 3
    threshold_px: float = 5.0
    extended: bool = False
    tracker: str = "bqp"

    def __post_init__(self) -> None:
        require_number("Objective", "train_episodes", self.train_episodes, lo=1, integer=True)
        require_number("Objective", "threshold_px", self.threshold_px, lo=0)
        require_tunable(self.tracker)
        if (self.suite is None) == (self.scenarios is None):
            raise ValueError("give exactly one of --suite NAME and --scenarios DIST")
        if self.frames is not None:
            require_number("Objective", "frames", self.frames, lo=2, integer=True)
        for name in ("only", "heldout_only"):
            value = getattr(self, name)
            # one name is one sequence (tuple("seq8") would be its letters)
            names = (value,) if isinstance(value, str) else value or ()
            if not isinstance(names, (tuple, list)) or not all(
                isinstance(n, str) and n for n in names
            ):
                raise ValueError(f"Objective.{name} must be sequence names, got {value!r}")
            object.__setattr__(self, name, tuple(names))
        if isinstance(self.scenarios, Mapping):
            object.__setattr__(self, "scenarios", ScenarioDistribution.from_dict(self.scenarios))
        if self.suite is not None:
            object.__setattr__(self, "suite", _resolved_suite(str(self.suite)))
        if isinstance(self.scenarios, str):
            object.__setattr__(self, "scenarios", _resolved_scenarios(self.scenarios))

    @property
    def folder(self) -> bool:
        """Whether the suite is a folder of MOT sequences: read as they are, never re-seeded
        (held-out scoring takes its ``heldout_only`` sequences once each)."""
        from synth_data.suites import is_spec_suite

        return self.suite is not None and not is_spec_suite(self.suite)

    def episodes(self, heldout: bool = False, cache: int = 0) -> EpisodeSource:
        """Training (stream 0) or held-out episodes."""
        if heldout and self.folder:
            if not self.heldout_only:
                raise ValueError(
                    f"{self.suite}: a folder of sequences cannot be re-seeded; "
                    "name held-out sequences with --heldout-only"
                )
            known = SuiteEpisodes.folder_names(self.suite)
            require_sequences("--heldout-only", self.heldout_only, known, str(self.suite))
            return make_episodes(
                suite=self.suite,
                only=self.heldout_only,
                frames=self.frames,
                cache=cache,
                cache_frames=cache > 0,
            )
        return make_episodes(
            suite=self.suite,
            scenarios=self.scenarios,
            only=self.only or None,
            frames=self.frames,
            seed=HELDOUT_SEED if heldout else 0,
            cache=cache,
            cache_frames=cache > 0,
        )

    def n_train(self, source: EpisodeSource) -> int:
        return (
            min(self.train_episodes, len(source)) if self.suite is not None else self.train_episodes
        )

    def space(self) -> ParamSpace:
        from tracker.registry import get

        return ParamSpace(extended=self.extended, base=get(self.tracker).make_params())

    def describe(self) -> dict[str, Any]:
        d = asdict(self)
        sc = self.scenarios
        if sc is not None and not isinstance(sc, str):
            d["scenarios"] = sc.to_dict()
        d["only"] = list(self.only)
        d["heldout_only"] = list(self.heldout_only)
        return d


class Scorer:
    """Scores parameter sets on an objective's training episodes through the bandit env.

    The episodes are built once and their frames kept in memory, so that every trial after
    the first one costs only the tracking.
    """

    def __init__(self, objective: Objective) -> None:
        from envs.tracker_tuning import TrackerTuningBanditEnv

        self.objective = objective
        src = objective.episodes(cache=objective.train_episodes)
        self.indices = _peopled(src, objective.n_train(src))
        self.n = len(self.indices)
        self.env = TrackerTuningBanditEnv(
            episodes=src,
            threshold_px=objective.threshold_px,
            extended=objective.extended,
            tracker=objective.tracker,
        )
        self.space = self.env.space

    def __call__(self, values: dict[str, float]) -> tuple[float, list[float]]:
        """``(mean accuracy %, per-episode accuracies %)`` of the tuned ``values``."""
        action = self.space.to_action(values)
        accs = []
        for i in self.indices:
            self.env.reset(options={"episode": i})
            _, reward, *_ = self.env.step(action)
            accs.append(100.0 * reward)
        return float(np.mean(accs)), accs


def _peopled(src: EpisodeSource, n: int) -> list[int]:
    """The first ``n`` episodes of ``src`` with someone in view (a distribution's camera
    can frame nobody; the held-out scoring skips such episodes too)."""
    from envs.tracker_tuning import MAX_EMPTY_DRAWS

    found: list[int] = []
    tried = min(len(src), MAX_EMPTY_DRAWS * n)
    for i in range(tried):
        if shows_someone(src.episode(i)):
            found.append(i)
            if len(found) == n:
                return found
    raise ValueError(
        f"only {len(found)} of the first {tried} training "
        f"episodes have someone in view, fewer than --train-episodes {n}; give the "
        "scenarios more people or a higher density"
    )


_SCORERS: dict[str, Scorer] = {}


def _scorer(objective: Objective) -> Scorer:
    key = json.dumps(objective.describe(), sort_keys=True)
    if key not in _SCORERS:
        _SCORERS.clear()
        _SCORERS[key] = Scorer(objective)
    return _SCORERS[key]


# ---------------------------------------------------------------------------- storage
def storage_url(study: str | None, out: Path) -> str:
    """The storage of ``--study``: ``None`` -> ``sqlite:///OUT/study.db``; a URL
    (``sqlite:///``, ``postgresql://``, ``mysql://``) as is; a ``*.log`` / ``*.journal``
    path or ``journal:PATH`` -> an Optuna journal file."""
    if study is None:
        return f"sqlite:///{(out / STUDY_FILE).resolve()}"
    s = str(study)
    if s.startswith("journal:"):
        return s
    if s.split("?", 1)[0] in ("sqlite://", "sqlite:///", "sqlite:///:memory:"):
        # each connection would get its own empty database: the workers and the heartbeat
        # thread would see no study, and nothing would be left to resume
        raise ValueError(
            f"--study {s}: an in-memory SQLite study cannot be shared with the trial workers "
            "or resumed; give a file (sqlite:///study.db)"
        )
    if "://" in s:
        return s
    if s.endswith((".log", ".journal", ".jsonl")):
        return f"journal:{Path(s).resolve()}"
    if s.endswith((".db", ".sqlite", ".sqlite3")):
        return f"sqlite:///{Path(s).resolve()}"
    raise ValueError(
        f"--study must be a database URL (sqlite:///..., postgresql://...), a "
        f"journal file (*.log or journal:PATH) or a *.db file, got {s!r}"
    )


def _check_sqlite(path: Path) -> None:
    """Refuse a file that is not SQLite, or an SQLite database that is not an Optuna study."""
    if path.is_dir():  # SQLite would only say "disk I/O error"
        raise ValueError(f"--study {path}: is a folder, not an SQLite file")
    if not path.exists() or path.stat().st_size == 0:
        return
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            tables = {
                r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")
            }
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        raise ValueError(f"{path}: not an Optuna study (corrupt or not SQLite: {exc})") from None
    if tables and not {"studies", "trials", "version_info"} <= tables:
        raise ValueError(
            f"{path}: an SQLite database that is not an Optuna study (tables "
            f"{', '.join(sorted(tables)[:5])}); choose another --study or --out"
        )


def check_storage(url: str) -> None:
    """Refuse a study file that exists and is not an Optuna study (SQLite or journal),
    reading it only: nothing is created. Other URLs are checked when opened."""
    if url.startswith("sqlite:///"):
        _check_sqlite(Path(url[len("sqlite:///") :]))
    elif url.startswith("journal:"):
        path = Path(url[len("journal:") :])
        if path.is_dir():
            raise ValueError(f"--study {path}: is a folder, not a journal file")
        if path.is_file() and path.stat().st_size:
            _check_journal(path)


def _check_journal(path: Path) -> None:
    """Every line of an Optuna journal is a JSON object; the last may be cut short (a writer
    killed mid-line: Optuna skips it too)."""
    with open(path, "rb") as fh:
        lines = fh.read().split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    for number, line in enumerate(lines[:-1], start=1):
        try:
            ok = isinstance(json.loads(line), dict)
        except (UnicodeDecodeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(
                f"{path}: not an Optuna journal file (corrupt or foreign: line {number} is "
                "not a JSON record)"
            )
    if lines and not lines[0].startswith((b"{", b"[")):
        raise ValueError(f"{path}: not an Optuna journal file (corrupt or foreign)")


_HELD: dict[type, type] = {}


def _signals_held_in_calls(base: type) -> type:
    """``base`` (an Optuna storage class) whose methods hold SIGINT and SIGTERM back until
    they return (:func:`crowdsim.atomic.signals_held`; in the main thread, where Python runs
    the handlers), so that an interrupt lands between storage calls, never inside one.

    One that landed inside a read left its SQLite statement unfinished: the statement, kept
    alive by the interrupt's traceback, which Optuna holds while it writes the trial's
    failure, kept the database's shared lock, and that write (or the trial's heartbeat)
    waited for it through the 120 s busy timeout: a stopped ``tune`` hung for two minutes
    (1 run in 30 under load, from random-time SIGTERMs). A call that waits for another
    process's lock delays the interrupt, by that timeout at most."""
    if base not in _HELD:

        class Held(base):  # type: ignore[misc, valid-type]
            def __getattribute__(self, name: str) -> Any:
                attr = super().__getattribute__(name)
                if name.startswith("__") or not callable(attr):
                    return attr

                def held(*args: Any, **kwargs: Any) -> Any:
                    with signals_held():
                        return attr(*args, **kwargs)

                return held

        Held.__name__ = Held.__qualname__ = f"SignalsHeld{base.__name__}"
        _HELD[base] = Held
    return _HELD[base]


def open_storage(url: str) -> Any:
    """An Optuna storage for ``url`` (see :func:`storage_url`); heartbeats on databases so
    trials of a killed worker are failed and retried. Its calls hold signals back until they
    return (:func:`_signals_held_in_calls`)."""
    optuna = require("optuna", "rl", "crowdsim tune")
    if url.startswith("journal:"):
        from optuna.storages.journal import JournalFileBackend

        path = Path(url[len("journal:") :])
        if path.exists() and path.stat().st_size:
            head = path.read_bytes()[:1]
            if head not in (b"{", b"["):
                raise ValueError(f"{path}: not an Optuna journal file (corrupt or foreign)")
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            return optuna.storages.JournalStorage(JournalFileBackend(str(path)))
        except Exception as exc:  # a broken line: JSONDecodeError, KeyError of a bad record
            raise ValueError(
                f"{path}: not an Optuna journal file (corrupt or foreign: "
                f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
            ) from None
    if url.startswith("sqlite:///"):
        path = Path(url[len("sqlite:///") :])
        _check_sqlite(path)
        path.parent.mkdir(parents=True, exist_ok=True)
    import warnings

    from optuna.storages import RDBStorage

    RDBStorage = _signals_held_in_calls(RDBStorage)  # noqa: N806 - the class, signal-safe
    retry = getattr(optuna.storages, "RetryHeartbeatStaleTrialCallback", None)
    # several workers share one SQLite file: wait for its lock instead of failing at once
    engine = {"connect_args": {"timeout": 120}} if url.startswith("sqlite:") else None
    try:
        with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna's words
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            if retry is not None:  # optuna >= 4.9
                return RDBStorage(
                    url,
                    engine_kwargs=engine,
                    heartbeat_interval=30,
                    grace_period=90,
                    heartbeat_stale_trial_callback=retry(max_retry=1),
                )
            return RDBStorage(
                url,
                engine_kwargs=engine,
                heartbeat_interval=30,
                grace_period=90,
                failed_trial_callback=optuna.storages.RetryFailedTrialCallback(max_retry=1),
            )
    except ImportError as exc:  # a database driver (psycopg2, pymysql) is missing
        raise DependencyNotInstalled(f"{url.split(':')[0]} storage needs a driver: {exc}") from None
    except Exception as exc:  # SQLAlchemy errors: corrupt file, unreachable server
        raise ValueError(
            f"cannot open the study storage {url!r}: "
            f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
        ) from None


def _make_sampler(name: str, space: ParamSpace, seed: int, trials: int) -> Any:
    import optuna

    require_choice("", "--sampler", name, SAMPLERS)
    if name == "cmaes":
        require("cmaes", "rl", "--sampler cmaes")
        # the paper defaults are the study's first (enqueued) trial; CMA-ES starts from the
        # centre of the box otherwise (Optuna >= 4.9 deprecates x0)
        return optuna.samplers.CmaEsSampler(
            seed=seed, n_startup_trials=0, warn_independent_sampling=False
        )
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=max(3, min(10, trials // 3)))


def open_study(
    url: str,
    name: str,
    objective: Objective,
    sampler: str,
    seed: int,
    trials: int,
    enqueue_defaults: bool = True,
) -> Any:
    """Create or resume the study ``name``; a study made for another parameter space or
    objective is refused (its trials would not be comparable). A new study gets the paper
    defaults as its first trial (``enqueue_defaults``; Ray Tune evaluates them itself)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    with new_study_files(url):  # a half-made database of this run is not left behind
        storage = open_storage(url)
        space = objective.space()
        signature = {"space": space.signature(), "objective": objective.describe()}
        try:
            study = optuna.create_study(
                storage=storage,
                study_name=name,
                direction="maximize",
                sampler=_make_sampler(sampler, space, seed, trials),
                load_if_exists=True,
            )
        except (ValueError, DependencyNotInstalled):
            raise
        except Exception as exc:  # storage errors (SQLAlchemy, journal) on a foreign file
            raise ValueError(
                f"cannot open study {name!r} in {url}: {type(exc).__name__}: "
                f"{str(exc).splitlines()[0] if str(exc) else ''}"
            ) from None
        # a resumed study gets a sampler seeded past its history: the same seed would draw
        # the same startup points again (a run killed after trial k repeats trials 1..k)
        from optuna.trial import TrialState

        finished = len(
            study.get_trials(
                deepcopy=False,
                states=(TrialState.COMPLETE, TrialState.FAIL, TrialState.PRUNED),
            )
        )
        if finished:
            study.sampler = _make_sampler(sampler, space, (seed + 7919 * finished) % 2**32, trials)
        if study.direction != optuna.study.StudyDirection.MAXIMIZE:
            raise ValueError(
                f"study {name!r} in {url} minimises; it is not a crowdsim tuning "
                "study (choose another --study-name)"
            )
        old = study.user_attrs.get("crowdsim")
        if old is None:
            if study.trials:
                raise ValueError(
                    f"study {name!r} in {url} was not made by crowdsim tune; choose "
                    "another --study-name or --out"
                )
            study.set_user_attr("crowdsim", json.loads(json.dumps(signature)))
            if enqueue_defaults:
                study.enqueue_trial(
                    dict(zip(space.names, space.default.tolist(), strict=True)),
                    user_attrs={"defaults": True},
                )
        elif _comparable(old) != _comparable(json.loads(json.dumps(signature))):
            changed = [
                k
                for k in signature["objective"]
                if k != "heldout_only"
                and old.get("objective", {}).get(k) != signature["objective"][k]
            ]
            if old.get("space") != signature["space"]:
                changed.insert(0, "parameter space")
            raise ValueError(
                f"study {name!r} in {url} was made for another objective (differs in "
                f"{', '.join(map(str, changed))}); resume with the same flags, or "
                "choose another --out or --study-name"
            )
    return study


def _comparable(signature: Any) -> Any:
    """A study signature without ``heldout_only`` (the held-out sequences change no trial's
    score, so resuming with other ones, or ``--heldout 0`` and none, is the same study) and
    with a suite folder's path resolved."""
    if not isinstance(signature, dict) or not isinstance(signature.get("objective"), dict):
        return signature
    objective = {k: v for k, v in signature["objective"].items() if k != "heldout_only"}
    if isinstance(objective.get("suite"), str):
        # a study from before suite folders were stored resolved holds the path as typed
        objective["suite"] = _resolved_suite(objective["suite"])
    if isinstance(objective.get("scenarios"), str):  # and scenarios files likewise
        objective["scenarios"] = _resolved_scenarios(objective["scenarios"])
    return {**signature, "objective": objective}


def _resolved_suite(suite: str) -> str:
    """A built-in suite's name as it is; a suite folder's absolute path, so that one folder
    is one suite however it is typed (``./own/``, its absolute path, or a relative path from
    another working folder): the study signature holds it."""
    from synth_data.suites import SUITE_NAMES

    if suite not in SUITE_NAMES and Path(suite).is_dir():
        return str(Path(suite).resolve())
    return suite


def _resolved_scenarios(scenarios: str) -> str:
    """A scenarios file's absolute path, as :func:`_resolved_suite` does for suite folders:
    ``d.json`` and ``./d.json``, or the file named from another working folder, are one
    objective (a resume had been refused as "another objective"), and Ray Tune, which runs
    each trial in a folder of its own, finds it. Names and comma lists stay as they are."""
    path = Path(scenarios.strip())
    return str(path.resolve()) if path.is_file() else scenarios


def _requeue_defaults(study: Any, space: ParamSpace) -> None:
    """Enqueue the paper defaults again when no trial of them is complete, waiting or running
    (the enqueued one failed: Ctrl-C or a kill during the study's first trial). Without it the
    study never scores them and ``default_value`` stays null for good."""
    from optuna.trial import TrialState

    live = (TrialState.COMPLETE, TrialState.WAITING, TrialState.RUNNING)
    if any(t.user_attrs.get("defaults") for t in study.get_trials(deepcopy=False, states=live)):
        return
    study.enqueue_trial(
        dict(zip(space.names, space.default.tolist(), strict=True)),
        user_attrs={"defaults": True},
    )


def complete_trials(study: Any) -> list[Any]:
    from optuna.trial import TrialState

    return study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))


def _fail_orphans(study: Any) -> int:
    """Mark RUNNING trials of a killed run as FAIL (only for a study this run owns)."""
    from optuna.trial import TrialState

    n = 0
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study._storage.set_trial_state_values(t._trial_id, state=TrialState.FAIL)
        n += 1
    return n


class _OutLock:
    """An exclusive lock on ``OUT/.tune.lock``: two local runs never share one study file.

    A run that fails removes the lock file if it created it (nothing is left behind by a
    refused input); a finished run leaves it (hidden, empty) beside its results."""

    def __init__(self, out: Path) -> None:
        self.path = out / ".tune.lock"
        self.fh = None
        self.created = False

    def __enter__(self) -> _OutLock:
        import fcntl

        self.created = not self.path.exists()
        self.fh = open(self.path, "a+")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.close()
            raise ValueError(
                f"{self.path.parent}: another crowdsim tune is running on this folder"
            ) from None
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        if self.fh is not None:
            if exc_type is not None and self.created:
                self.path.unlink(missing_ok=True)  # still ours: we hold the lock
            self.fh.close()


# ---------------------------------------------------------------------------- local runs
class _QuietInterrupt(logging.Filter):
    """Drops Optuna's "Trial N failed ... KeyboardInterrupt" warnings (a traceback of 35-65
    lines) for a trial that Ctrl-C or SIGTERM stopped: the trial is marked failed as usual
    and the interrupt goes on to the command, which says "interrupted" in one line."""

    def __init__(self) -> None:
        super().__init__()
        self.trials: set[int] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        for n in list(self.trials):
            if msg.startswith(f"Trial {n} failed"):
                if msg.startswith(f"Trial {n} failed with value"):  # Optuna's last word on it
                    self.trials.discard(n)
                return False
        return True


_QUIET = _QuietInterrupt()


def _objective_fn(objective: Objective, space: ParamSpace) -> Callable[[Any], float]:
    # installed on use (importing a library module changes no process-wide setting);
    # adding the same filter again is a no-op
    logging.getLogger("optuna.study._optimize").addFilter(_QUIET)

    def fn(trial: Any) -> float:
        try:
            values = space.optuna_suggest(trial)
            value, per = _scorer(objective)(values)
            # inside too: a signal during this storage write had Optuna log a traceback
            trial.set_user_attr("per_episode", [round(v, 4) for v in per])
        except KeyboardInterrupt:  # jobs.Interrupted (SIGINT, SIGTERM) included
            _QUIET.trials.add(trial.number)
            raise
        return value

    return fn


def _worker(
    url: str,
    name: str,
    objective: Objective,
    sampler: str,
    seed: int,
    trials: int,
    share: int | None = None,
    advance: Callable[..., None] | None = None,
) -> int:
    """One optimisation process: runs trials until the study holds ``trials`` complete ones,
    and at most ``share`` of them (the workers' shares add up to the trials still missing,
    so parallel workers never overshoot ``trials``).

    ``advance(1, best=...)`` (from :func:`crowdsim.jobs.run_jobs`) moves the shared progress
    bar after each trial this worker finishes. Returns the number of trials it ran.
    """
    from optuna.study import MaxTrialsCallback
    from optuna.trial import TrialState

    study = open_study(url, name, objective, sampler, seed, trials)
    if len(complete_trials(study)) >= trials:
        return 0
    ran = 0

    def tick(study: Any, trial: Any) -> None:
        nonlocal ran
        ran += 1
        if advance is not None:
            ts = complete_trials(study)
            advance(1, best=f"{max(t.value for t in ts):.2f}%" if ts else "n/a")

    if share is not None and share <= 0:
        return 0
    before = set(threading.enumerate())
    try:
        with study_storage(url):  # a full disk mid-run: one line, not SQLAlchemy's traceback
            study.optimize(
                _objective_fn(objective, objective.space()),
                n_trials=share,
                callbacks=[MaxTrialsCallback(trials, states=(TrialState.COMPLETE,)), tick],
                gc_after_trial=False,
                show_progress_bar=False,
            )
    finally:
        _stop_heartbeats(set(threading.enumerate()) - before)
    return ran


def _stop_heartbeats(threads: set[threading.Thread]) -> None:
    """Stop the trials' heartbeat threads among ``threads`` that are still running.

    Optuna starts a (non-daemon) heartbeat thread as a trial begins and stops it as the
    trial ends, with nothing to guard the two against an interrupt: a SIGTERM that landed
    just as a trial began or ended left one beating, every 30 s, for ever, and the stopped
    ``tune`` printed its line but never exited (seen 1 run in 20 under load). Each such
    thread waits on its stop event (its third argument); setting it ends the thread."""
    for t in threads:
        target = getattr(t, "_target", None)
        args = getattr(t, "_args", ())
        if getattr(target, "__name__", "") == "_record_heartbeat" and len(args) == 3:
            args[2].set()
    for t in threads:
        if getattr(getattr(t, "_target", None), "__name__", "") == "_record_heartbeat":
            t.join(timeout=5.0)


def _run_local(
    url: str,
    name: str,
    objective: Objective,
    sampler: str,
    seed: int,
    trials: int,
    workers: int,
    progress: bool,
    out: Path,
) -> None:
    """``workers`` optimisation processes on :func:`crowdsim.jobs.run_jobs` (in this process
    for one): they share the study, so each stops when it holds ``trials`` complete trials.
    With several workers, the trials still missing are shared out among the workers still
    to run, so that together they finish exactly ``trials`` (parallel workers stopping on the
    count alone overshoot: ``--trials 6 --workers 2`` ended with 7). The runner's manifest
    (``OUT/tune_jobs.json``) records a worker once it has finished; a killed run leaves the
    unfinished ones unrecorded and a rerun starts them again on the same study."""
    from optuna.trial import TrialState

    from crowdsim.jobs import Job, run_jobs

    study = open_study(url, name, objective, sampler, seed, trials)
    if workers > 1:
        # Two processes on one SQLite study can both pop the same enqueued (WAITING) trial
        # and one then fails with "Cannot tell a COMPLETE trial" (seen on CI): run the
        # enqueued ones -- the paper defaults -- here before fanning out.
        fn = _objective_fn(objective, objective.space())
        while len(complete_trials(study)) < trials and study.get_trials(
            deepcopy=False, states=(TrialState.WAITING,)
        ):
            with study_storage(url):
                study.optimize(fn, n_trials=1, gc_after_trial=False, show_progress_bar=False)
    left = trials - len(complete_trials(study))
    if left <= 0:
        return
    manifest = out / JOBS_MANIFEST
    keys = [f"{name}/to-{trials}/worker-{i + 1}-of-{workers}" for i in range(workers)]
    done = read_manifest(manifest)["jobs"]
    todo = [i for i, key in enumerate(keys) if key not in done]
    if not todo:  # every worker finished, yet trials are missing (some failed): run again
        todo = list(range(workers))
        keys = [f"{key}/again-from-{trials - left}" for key in keys]
    share = {i: left // len(todo) + (k < left % len(todo)) for k, i in enumerate(todo)}
    jobs = [
        Job(
            keys[i],
            _worker,
            (url, name, objective, sampler, seed + i, trials, share[i] if workers > 1 else None),
            size=max(share[i], 1),
            progress_kw="advance",
        )
        for i in todo
        if share[i] > 0
    ]
    run_jobs(
        jobs,
        manifest,
        workers=workers,
        progress=progress,
        desc="tune",
        unit="trial",
        passthrough=(ValueError, StudyStorageError),  # a study storage that failed
    )


def _run_ray(
    url: str,
    name: str,
    objective: Objective,
    sampler: str,
    seed: int,
    trials: int,
    workers: int,
    address: str | None,
    out: Path,
    progress: bool = True,
) -> Any:
    """Ray Tune with OptunaSearch; every result also goes to the Optuna study at ``url``.

    A rerun runs the trials still missing from the study (Ray's own experiment folder,
    ``OUT/ray``, keeps each run's trial logs)."""
    ray = require("ray", "distributed", "--backend ray")
    require("ray.tune", "distributed", "--backend ray")
    from ray import tune as rtune
    from ray.tune.search.optuna import OptunaSearch

    space = objective.space()
    study = open_study(url, name, objective, sampler, seed, trials, enqueue_defaults=False)
    done = len(complete_trials(study))
    if done >= trials:
        return study
    ray_init(ray, address)  # keeps our handlers: Ray's own ended a SIGTERM with exit 134

    def trainable(config: dict[str, float]) -> dict[str, float]:
        value, _ = _scorer(objective)({k: float(config[k]) for k in space.names})
        return {"accuracy": value}

    import optuna

    # a resumed run hands the study's finished trials to the searcher as evaluated points
    # (not re-run) and seeds it past them, so that it continues the search instead of
    # drawing the first run's points again
    history = [t for t in complete_trials(study) if set(t.params) == set(space.names)]
    if history:
        points = [{k: float(t.params[k]) for k in space.names} for t in history]
        rewards = [float(t.value) for t in history]
    else:
        points = [dict(zip(space.names, space.default.tolist(), strict=True))]
        rewards = None
    search = OptunaSearch(
        metric="accuracy",
        mode="max",
        points_to_evaluate=points,
        evaluated_rewards=rewards,
        sampler=_make_sampler(sampler, space, (seed + 7919 * len(history)) % 2**32, trials),
    )
    tuner = rtune.Tuner(
        rtune.with_resources(trainable, {"cpu": 1}),
        param_space=space.ray_search_space(),
        tune_config=rtune.TuneConfig(
            search_alg=search, num_samples=trials - done, max_concurrent_trials=max(1, workers)
        ),
        run_config=rtune.RunConfig(
            name=name, storage_path=str((out / "ray").resolve()), verbose=int(progress)
        ),
    )
    with _sigterm_stops_tune() as stopped_by:  # Ray Tune's SIGINT handler ends it early
        results = tuner.fit()
    dists = space.optuna_distributions()
    for r in results:
        if r.error is None and r.metrics and "accuracy" in r.metrics:
            values = {k: float(r.config[k]) for k in space.names}
            attrs = {"ray": True}
            if np.allclose(space.to_action(values), 0.0, atol=1e-12):
                attrs["defaults"] = True
            study.add_trial(
                optuna.trial.create_trial(
                    params=values,
                    distributions=dists,
                    value=float(r.metrics["accuracy"]),
                    user_attrs=attrs,
                )
            )
    ended = sum(1 for r in results if r.error is not None or "accuracy" in (r.metrics or {}))
    if ended < trials - done:  # stopped early: a Ctrl-C or SIGTERM, which Ray Tune takes
        raise Interrupted(stopped_by[0] if stopped_by else "SIGINT", _kept(study))
    errors = [r.error for r in results if r.error is not None]
    if errors and not complete_trials(study):  # else the caller fails on an empty max()
        first = str(errors[0]).strip().splitlines() or [type(errors[0]).__name__]
        raise ValueError(
            f"--backend ray: no trial finished ({len(errors)} failed; the first: {first[-1]})"
        )
    return study


def _kept(study: Any) -> str:
    """What the line of a stopped run says of its study (:class:`crowdsim.jobs.Interrupted`'s
    ``detail``)."""
    kept = len(complete_trials(study))
    return f"the study keeps its {kept} finished trial(s); the same command resumes"


@contextmanager
def _sigterm_stops_tune() -> Iterator[list[str]]:
    """While inside (in the main thread), a SIGTERM stops Ray Tune as its own SIGINT handler
    does, gracefully (finished trials kept), and is noted in the yielded list.

    Ray Tune installs a SIGINT handler for the length of ``Tuner.fit``, and nothing for
    SIGTERM: Ray's core handler ended the run with its stack dump and exit 134, and
    :func:`crowdsim.jobs.interruptible`'s, raising inside Ray Tune, left its shutdown
    waiting a minute for a lost GCS. So a SIGTERM calls the SIGINT handler in place at the
    time, Ray Tune's (which it puts back after the first signal), and :func:`_run_ray` reports
    it as SIGTERM: one line and exit 143. Otherwise it raises :class:`~crowdsim.jobs.
    Interrupted` as :func:`~crowdsim.jobs.interruptible` would."""
    import signal
    import threading

    seen: list[str] = []
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    ours = signal.getsignal(signal.SIGINT)

    def forward(signum: int, frame: Any) -> None:
        seen.append("SIGTERM")
        handler = signal.getsignal(signal.SIGINT)
        if handler is ours or not callable(handler):  # not Ray Tune's (a second signal)
            raise Interrupted("SIGTERM")
        handler(signal.SIGINT, frame)

    saved = signal.signal(signal.SIGTERM, forward)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGTERM, saved)
        # Ray Tune puts its SIGINT handler back only after a signal: after a whole run it
        # stayed, and swallowed the first Ctrl-C of the held-out scoring that follows
        signal.signal(signal.SIGINT, ours)


# ---------------------------------------------------------------------------- results
TUNE_FILES: tuple[str, ...] = ("best_params.json", "history.png", "importance.png")
"""What :func:`tune` writes beside its study: the record, then its two plots."""


def _is_tune_record(doc: Any) -> bool:
    return isinstance(doc, dict) and {"params", "space", "study", "trials"} <= set(doc)


def _stale_heldout(out: Path) -> list[Path]:
    """The held-out scores an earlier tune run wrote into ``out`` (listed with their digests
    in its ``best_params.json``) and still there unchanged. A run that scores none removes
    them once its own record is written: left beside the new parameters, they would read as
    this run's. A file changed since, or one this program cannot prove it wrote, is kept."""
    listed = (read_record(out / TUNE_FILES[0], _is_tune_record) or {}).get("heldout_files")
    if not isinstance(listed, dict):
        return []
    return [
        out / name
        for name in HELDOUT_FILES
        if listed.get(name) and (out / name).is_file() and sha256_file(out / name) == listed[name]
    ]


def check_tune_out(out: Path, heldout: bool) -> None:
    """Refuse a folder holding a ``best_params.json``, ``history.png`` or ``importance.png``
    (or, with held-out scoring, a ``heldout.*``) that ``crowdsim tune`` cannot prove it
    wrote: a user's own files are never replaced (:mod:`envs.outputs`). Reads only."""
    check_outputs(out, TUNE_FILES[0], TUNE_FILES[1:], _is_tune_record, "crowdsim tune")
    read_manifest(out / JOBS_MANIFEST)  # the workers' record: another tool's file is refused
    if heldout:
        check_heldout_out(out)


@dataclass
class TuneResult:
    """What :func:`tune` found and wrote."""

    best_params: dict[str, float | int]
    best_value: float
    default_value: float | None
    trials: int
    heldout: dict[str, Any] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)


def plot_history(study: Any, path: Path, threshold_px: float | None = None) -> Path:
    """Every complete trial's accuracy (at ``threshold_px``, named on the axis where given)
    and the best so far, PNG."""
    from matplotlib.ticker import MaxNLocator

    from crowdsim.plotting import new_figure, save_figure

    ts = sorted(complete_trials(study), key=lambda t: t.number)
    x = np.array([t.number for t in ts])
    y = np.array([t.value for t in ts])
    fig, ax = new_figure(figsize=(6, 3.8))
    if len(ts):
        ax.plot(x, y, "o", ms=4, alpha=0.6, label="trial")
        ax.step(x, np.maximum.accumulate(y), where="post", color="C3", label="best so far")
        d = [t for t in ts if t.user_attrs.get("defaults")]
        if d:
            ax.axhline(d[0].value, color="0.4", ls="--", lw=1, label="paper defaults")
    ax.set_xlabel("trial")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # trials are numbered, not 0.5
    at = "T" if threshold_px is None else f"{threshold_px:g}"
    ax.set_ylabel(f"accuracy at {at} px on the tuning sequences (%)")
    ax.set_title("optimisation history")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    return save_figure(fig, path, dpi=110)


def _importances(study: Any) -> dict[str, float]:
    """fANOVA importances of the parameters (Optuna's evaluator); ``{}`` when there are too
    few trials or no variation to attribute."""
    import optuna

    ts = complete_trials(study)
    if len(ts) < 2 or np.ptp([t.value for t in ts]) == 0:
        return {}
    try:
        imp = optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError):
        return {}
    return {k: float(v) for k, v in imp.items()}


def plot_importances(
    study: Any, path: Path, imp: dict[str, float] | None = None
) -> tuple[Path, dict[str, float]]:
    """The importances (:func:`_importances` unless given) as a bar chart, PNG."""
    from crowdsim.plotting import new_figure, save_figure

    if imp is None:
        imp = _importances(study)
    fig, ax = new_figure(figsize=(5.5, 3.2))
    if imp:
        names = list(imp)[::-1]
        ax.barh(names, [imp[n] for n in names], color="C0")
        ax.set_xlabel("importance (fANOVA, fraction of variance)")
    else:
        ax.text(0.5, 0.5, "not enough trials or variation", ha="center", va="center")
        ax.set_axis_off()
    ax.set_title("parameter importances")
    return save_figure(fig, path, dpi=110), {k: float(v) for k, v in imp.items()}


def _require_unseen(objective: Objective) -> None:
    """Refuse ``--heldout-only`` sequences that are also tuning sequences (``--only``, or
    every sequence of the folder without it): their scores would not be held out."""
    from synth_data.suites import is_spec_suite

    if not objective.heldout_only or objective.suite is None or is_spec_suite(objective.suite):
        return  # a built-in suite's held-out sequences are re-seeded, never tuned on
    train = set(objective.only) or set(SuiteEpisodes.folder_names(objective.suite))
    seen = [n for n in objective.heldout_only if n in train]
    if seen:
        where = (
            "--only" if objective.only else f"every sequence of {objective.suite} without --only"
        )
        raise ValueError(
            f"--heldout-only {seen[0]}: also a tuning sequence ({where}); held-out "
            "sequences must be ones the tuner never scores"
        )


def tune(
    objective: Objective,
    *,
    trials: int,
    out: str | os.PathLike[str],
    sampler: str = "tpe",
    study: str | None = None,
    study_name: str = DEFAULT_STUDY_NAME,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    seed: int = 0,
    heldout: int = 3,
    heldout_metrics: str = "full",
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> TuneResult:
    """Tune the static parameters; see the module docstring. Resumes an existing study."""
    if not isinstance(objective, Objective):
        raise ValueError(f"tune needs an envs.tuners.Objective, got {type(objective).__name__}")
    require_number("", "--trials", trials, lo=1, integer=True)
    require_choice("", "--backend", backend, BACKENDS)
    require_workers("--workers", workers, backend)
    require_number("", "--heldout", heldout, lo=0, integer=True)
    require_number("", "--seed", seed, lo=0, hi=2**32 - 1, integer=True)
    require_choice("", "--sampler", sampler, SAMPLERS)
    require_choice("", "heldout_metrics", heldout_metrics, ("full", "accuracy"))
    require("optuna", "rl", "crowdsim tune")
    if sampler == "cmaes":
        require("cmaes", "rl", "--sampler cmaes")
    if backend == "ray":  # before anything is created (no lock file, no empty study)
        require("ray", "distributed", "--backend ray")
        require("ray.tune", "distributed", "--backend ray")
        check_ray_address(address)
    elif address is not None:
        raise ValueError(f"--address needs --backend ray, got --address {address!r}")
    log = log or (lambda msg: print(msg, file=sys.stderr))
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file, not a folder")
    url = storage_url(study, out)
    space = objective.space()
    source = objective.episodes()  # validate suite / scenarios / --only before any work
    n = objective.n_train(source)
    if objective.suite is not None and n < len(source):
        # said, never in silence: --only seq1 .. seq9 had tuned on the first three alone
        names = [str(getattr(source.spec(i), "name", i)) for i in range(len(source))]
        log(
            f"--train-episodes {n}: each trial scores the first {n} of the suite's "
            f"{len(source)} sequences ({', '.join(names[:n])}; not {', '.join(names[n:])}); "
            "raise --train-episodes to score them all"
        )
    if heldout:
        objective.episodes(heldout=True)  # a suite folder needs --heldout-only: say it now
        _require_unseen(objective)
    check_storage(url)  # a foreign study file is refused before anything is created
    check_tune_out(out, heldout > 0)
    # a run refused or stopped before writing anything leaves no folder of its own
    with output_folder(out):
        return _tune_locked(
            objective,
            out,
            url,
            space,
            trials=trials,
            sampler=sampler,
            study=study,
            study_name=study_name,
            workers=workers,
            backend=backend,
            address=address,
            seed=seed,
            heldout=heldout,
            heldout_metrics=heldout_metrics,
            progress=progress,
            log=log,
        )


def _tune_locked(
    objective: Objective,
    out: Path,
    url: str,
    space: ParamSpace,
    *,
    trials: int,
    sampler: str,
    study: str | None,
    study_name: str,
    workers: int,
    backend: str,
    address: str | None,
    seed: int,
    heldout: int,
    heldout_metrics: str,
    progress: bool,
    log: Callable[[str], None],
) -> TuneResult:
    """:func:`tune` after its checks, holding ``OUT/.tune.lock``."""
    with _OutLock(out):
        # the study's own writes too: a disk that is full when the study opens or resumes ends
        # in one line, as one that fills during the trials does
        with study_storage(url):
            st = open_study(
                url,
                study_name,
                objective,
                sampler,
                seed,
                trials,
                enqueue_defaults=backend == "local",
            )
            if study is None:
                n = _fail_orphans(st)  # our own file: RUNNING trials belong to a killed run
                if n:
                    log(f"marked {n} unfinished trial(s) of an interrupted run as failed")
            if backend == "local":
                _requeue_defaults(st, space)  # a run killed in its first trial failed them
        before = len(complete_trials(st))
        if before:
            log(f"resuming study {study_name!r}: {before} finished trial(s) in {url}")
        if backend == "ray":
            st = _run_ray(
                url, study_name, objective, sampler, seed, trials, workers, address, out, progress
            )
        else:
            try:
                _run_local(
                    url, study_name, objective, sampler, seed, trials, workers, progress, out
                )
            except Interrupted as exc:  # say what is kept, as a Ray run does
                exc.detail = exc.detail or _kept(st)
                raise
            st = open_study(url, study_name, objective, sampler, seed, trials)
        ts = complete_trials(st)
        best = max(ts, key=lambda t: t.value)
        best_values = space.typed(best.params)
        defaults = [t for t in ts if t.user_attrs.get("defaults")]
        default_value = float(defaults[0].value) if defaults else None
        files = {"study": url}
        importances = _importances(st)
        result = TuneResult(
            best_params=best_values,
            best_value=float(best.value),
            default_value=default_value,
            trials=len(ts),
            files=files,
        )
        if heldout:
            best_params = space.to_params(space.to_action(best_values))
            result.heldout = evaluate_heldout(
                objective,
                {"defaults": space.base, "tuned": best_params},
                heldout,
                metrics=heldout_metrics,
                progress=progress,
            )
            files.update(write_heldout(result.heldout, out))
        stale = [] if result.heldout else _stale_heldout(out)
        doc = {
            "format": 1,
            "tracker": objective.tracker,
            "params": best_values,
            "action": space.to_action(best_values).round(6).tolist(),
            "value": result.best_value,
            "default_value": default_value,
            "trial": int(best.number),
            "trials": len(ts),
            "metric": (
                f"mean accuracy at {objective.threshold_px:g} px (%) on the tuning sequences, "
                "frame 1 (the initialisation) left out; track --evaluate and the held-out "
                "scores count it"
            ),
            "objective": objective.describe(),
            "space": space.describe(),
            "importances": importances,
            "study": {"storage": url, "name": study_name},
            "heldout": result.heldout.get("summary", {}),
            # what this run's held-out scoring wrote: a later run without it removes them
            "heldout_files": {
                name: sha256_file(out / name) for name in HELDOUT_FILES if result.heldout
            },
        }
        written = write_outputs(
            out,
            "best_params.json",
            doc,
            {
                "history.png": lambda p: plot_history(st, p, objective.threshold_px),
                "importance.png": lambda p: plot_importances(st, p, importances),
            },
        )
        files["history"] = str(written["history.png"])
        files["importance"] = str(written["importance.png"])
        files["best_params"] = str(written["best_params.json"])
        for path in stale:  # after the new record: it never lists scores that are gone
            path.unlink(missing_ok=True)
        if stale:
            names = ", ".join(p.name for p in stale)
            log(f"removed the earlier run's held-out scores ({names}): none this run")
    return result
