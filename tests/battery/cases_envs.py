"""Bad input to tune, train, heldout, track --params/--policy and the environments' Python API
(issue 13): every case ends in one named line, before any work, and leaves nothing behind."""

from __future__ import annotations

import json
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np

from battery.harness import Env, _truncate_jpeg, api_case, case, seq_copy
from envs.episodes import tiny_scenarios

TINY = tiny_scenarios()
POLICY_META = {
    "format": 1,
    "env_id": "crowdsim/TrackerTuning-v0",
    "algo": "ppo",
    "env_kwargs": {"k_frames": 5},
}


def _dist(**fields) -> str:
    return json.dumps({**TINY, **fields})


def _zip(path: Path, entries: dict[str, str | bytes]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in entries.items():
            zf.writestr(name, data)


def _policy(entries: dict[str, str | bytes]):
    def setup(w: Path, env: Env) -> None:
        _zip(w / "m.zip", entries)

    return setup


META = json.dumps(POLICY_META)
LIST_META = _policy({"data": "{}", "policy.pth": b"x", "crowdsim.json": "[1, 2]"})
NO_MODEL = _policy({"crowdsim.json": META})
# a torch file cut short: the zip member holds only the first bytes of a zip archive
CUT_TENSORS = _policy({"data": "{}", "policy.pth": b"PK\x03\x04cut", "crowdsim.json": META})
BROKEN_META = _policy({"data": "{}", "policy.pth": b"x", "crowdsim.json": "{not json"})


def _study_db(content: bytes | None):
    """``{w}/o/study.db``: garbage bytes, or (``None``) an SQLite database of someone else."""

    def setup(w: Path, env: Env) -> None:
        (w / "o").mkdir(parents=True)
        if content is not None:
            (w / "o" / "study.db").write_bytes(content)
            return
        import sqlite3

        con = sqlite3.connect(w / "o" / "study.db")
        con.execute("CREATE TABLE people (id INTEGER)")
        con.commit()
        con.close()

    return setup


# --- tune -------------------------------------------------------------------------------
TUNE = "tune --scenarios {w}/d.json --no-progress --out {w}/o"
D = (("d.json", _dist()),)


def tune_case(id: str, extra: str, needle: str, files=D, **kw) -> None:
    case(f"envs-tune-{id}", f"{TUNE} --trials 2 {extra}", needle, files=files, **kw)


tune_case("trials-0", "--trials 0", "--trials must be an integer >= 1, got 0")
tune_case("workers-0", "--workers 0", "--workers must be an integer in [1, 256], got 0")
tune_case("workers-huge", "--workers 100000", "--workers&&got 100000")
tune_case("workers-local-above-cores", "--workers 256", "--workers must be in [1, &&got 256")
tune_case(
    "foreign-jobs-manifest",
    "",
    "tune_jobs.json: not a crowdsim manifest&&refusing to replace it",
    files=(*D, ("o/tune_jobs.json", "user data\n")),
)
tune_case("seed-neg", "--seed -1", "--seed&&got -1")
tune_case("threshold-neg", "--threshold -1", "--threshold must be&&got -1.0")
tune_case("train-episodes-0", "--train-episodes 0", "--train-episodes&&got 0")
tune_case("frames-1", "--frames 1", "--frames must be >= 2, got 1")
tune_case(
    "tracker-bytetrack",
    "--tracker bytetrack",
    "--tracker bytetrack: no row of tunables for this tracker in envs.param_space.TUNABLES "
    "(tunable: bqp, bqp-ncc, bqp-dense, ncc, pnmc)",
)
tune_case("tracker-unknown", "--tracker magic", "unknown tracker 'magic'")
tune_case("address-local", "--address x:1", "--address needs --backend ray")
case(
    "envs-tune-only-without-suite",
    "tune --scenarios all --only seq1 --trials 1 --out {w}/o",
    "--only needs --suite",
)
tune_case(
    "scen-frames-1e9",
    "",
    "d.json: ScenarioDistribution.frames must be an integer in [2, 1000000], got 1000000000.0",
    files=(("d.json", _dist(frames=1e9)),),
)
tune_case(
    "scen-warmup-huge",
    "",
    "d.json&&warmup_steps must be an integer in [0, 100000], got 10000000",
    files=(("d.json", _dist(warmup_steps=10_000_000)),),
)
tune_case(
    "scen-agents-huge",
    "",
    "d.json&&agents must be an integer in [1, 1000000], got 5000000",
    files=(("d.json", _dist(agents=[10, 5_000_000])),),
)
tune_case(
    "scen-name-string",
    "",
    "unknown scenario 'parade'",  # one name is one family, not its letters ('p')
    files=(("d.json", _dist(scenarios="parade")),),
)
tune_case(
    "scen-binary",
    "",
    "d.json: not a JSON distribution file (binary, not UTF-8)",
    files=(("d.json", b"\xff\xfe\x00\x01binary"),),
)
tune_case(
    "scen-broken-json",
    "",
    "d.json: not valid JSON",
    files=(("d.json", '{"frames": 12,'),),
)
case(
    "envs-tune-scen-broken-toml",
    "tune --scenarios {w}/d.toml --trials 1 --out {w}/o",
    "d.toml: not valid TOML",
    files=(("d.toml", "frames = = 3\n"),),
)
tune_case(
    "scen-unknown-field",
    "",
    "d.json: unknown field(s) framez",
    files=(("d.json", json.dumps({"framez": 3})),),
)
tune_case(
    "scen-not-a-table",
    "",
    "d.json: expected a table of distribution fields",
    files=(("d.json", "[1, 2]"),),
)
tune_case(
    "scen-template-0",
    "",
    "template_px must be an integer in [4, 64], got 0",
    files=(("d.json", _dist(template_px=[0])),),
)
tune_case("study-name", "--study mystudy", "--study must be a database URL")
tune_case(
    "study-not-sqlite",
    "",
    "study.db: not an Optuna study (corrupt or not SQLite",
    setup=_study_db(b"this is not a database" * 40),
)
tune_case(
    "study-foreign-sqlite",
    "",
    "study.db: an SQLite database that is not an Optuna study (tables people)",
    setup=_study_db(None),
)
for url in ("sqlite://", "sqlite:///:memory:"):  # each connection its own empty database
    tune_case(
        f"study-in-memory-{url.count('/')}",
        f"--study {url}",
        f"--study {url}: an in-memory SQLite study cannot be shared",
    )
tune_case(
    "study-sqlite-folder",
    "--study sqlite:///{w}/s.db",
    "s.db: is a folder, not an SQLite file",
    files=(*D, ("s.db/x", "")),
)
tune_case(
    "study-journal-broken",
    "--study {w}/j.log",
    "j.log: not an Optuna journal file (corrupt or foreign: line 2",
    files=(*D, ("j.log", '{"op_code": 0}\n{broken\n{"op_code": 1}\n')),
)
case("envs-tune-out-is-file", "tune --scenarios all --trials 1 --out {afile}", "afile")
case(  # the reference row every other row is compared with cannot be replaced by a file
    "envs-heldout-params-named-defaults",
    "heldout --scenarios {w}/d.json --seeds 1 --params defaults={w}/p.json --out {w}/o",
    "--params defaults=&&names the paper defaults' row",
    files=(*D, ("p.json", '{"zeta": 0.5}')),
)
case(
    "envs-heldout-policy-named-defaults",
    "heldout --scenarios {w}/d.json --seeds 1 --policy defaults={w}/m.zip --out {w}/o",
    "--policy: the label 'defaults' is the paper defaults' row",
    files=(*D, ("m.zip", b"PK")),
)
tune_case(
    "users-history",
    "",
    "o/history.png exists and was not written by crowdsim tune",
    files=(*D, ("o/history.png", b"\x89PNG my own plot")),
)
tune_case(
    "users-heldout-md",
    "",
    "o/heldout.md exists and was not written by crowdsim heldout",
    files=(*D, ("o/heldout.md", "my notes\n")),
)
tune_case(
    "users-best-params",
    "",
    "o/best_params.json exists and was not written by crowdsim tune",
    files=(*D, ("o/best_params.json", '{"zeta": 0.5}')),
)
case(
    "envs-tune-suite-truncated-frame",
    "tune --suite {w}/s --trials 1 --out {w}/o",
    "000003.jpg: not a complete image",
    setup=seq_copy(_truncate_jpeg, keep_checksums=False),
)
case(
    "envs-tune-suite-damaged-frame",
    "tune --suite {w}/s --trials 1 --out {w}/o",
    "000004.jpg: damaged",
    setup=seq_copy(
        lambda s: shutil.copy(s / "img1" / "000001.jpg", s / "img1" / "000004.jpg"), True
    ),
)

case(
    "envs-tune-heldout-only-scenarios",
    "tune --scenarios all --heldout-only s1 --trials 1 --out {w}/o",
    "--heldout-only names sequences of a folder of MOT sequences",
)
case(
    "envs-tune-folder-needs-heldout-only",
    "tune --suite {w}/s --trials 1 --out {w}/o",
    "a folder of sequences cannot be re-seeded; name held-out sequences with --heldout-only",
    setup=seq_copy(lambda s: None, True),
)
case(
    "envs-heldout-heldout-only-unknown",
    "heldout --suite {w}/s --heldout-only nope --out {w}/o",
    "--heldout-only: no sequence 'nope'",
    setup=seq_copy(lambda s: None, True),
)
case(  # a folder's sequences are read from disk as they are: the cache had been ignored
    "envs-train-folder-episode-cache",
    "train --algo ppo --suite {w}/s --episode-cache {w}/c --steps 4 --out {w}/o",
    "--episode-cache: {w}/s holds MOT sequences, read from disk as they are",
    setup=seq_copy(lambda s: None, True),
)
for flag, needle in (  # a folder's sequences are scored once each: these had been ignored
    ("--seeds 2", "--seeds: a folder of MOT sequences cannot be re-seeded"),
    ("--only s", "--only: {w}/s's held-out sequences are the --heldout-only ones"),
):
    case(
        f"envs-heldout-folder-{flag.split()[0][2:]}",
        f"heldout --suite {{w}}/s --heldout-only s {flag} --out {{w}}/o",
        needle,
        setup=seq_copy(lambda s: None, True),
    )


def _tune_without_ray(w: Path, env: Env) -> None:
    """``tune --backend ray`` where Ray is not installed: refused before anything is made."""
    from envs.tuners import Objective, tune

    saved = {k: v for k, v in sys.modules.items() if k == "ray" or k.startswith("ray.")}
    sys.modules["ray"] = None  # type: ignore[assignment]  # as if Ray were not installed
    try:
        tune(Objective(scenarios=dict(TINY)), trials=1, out=w / "o", backend="ray", heldout=0)
    finally:
        del sys.modules["ray"]
        sys.modules.update(saved)


api_case("envs-tune-ray-missing", _tune_without_ray, "pip install 'crowdsim[distributed]'")

# --- heldout ----------------------------------------------------------------------------
HELD = "heldout --scenarios {w}/d.json --seeds 1 --no-progress --out {w}/o"
ROOM = "headroom --scenarios {w}/d.json --seeds 1 --candidates 2 --no-progress --out {w}/o"
case("envs-headroom-candidates-0", f"{ROOM} --candidates 0", "--candidates&&got 0", files=D)
case("envs-headroom-k-0", f"{ROOM} --k 0", "--k must be an integer >= 1, got 0", files=D)
case("envs-headroom-seeds-0", f"{ROOM} --seeds 0", "--seeds&&got 0", files=D)
case("envs-headroom-threshold-neg", f"{ROOM} --threshold -1", "--threshold&&got -1", files=D)
case(
    "envs-headroom-tracker-bytetrack",
    f"{ROOM} --tracker bytetrack",
    "--tracker bytetrack: no row of tunables",
    files=D,
)
case(
    "envs-heldout-users-md",
    HELD,
    "o/heldout.md exists and was not written by crowdsim heldout",
    files=(*D, ("o/heldout.md", "# my notes\n")),
)
case(
    "envs-heldout-users-png",
    HELD,
    "o/heldout.png exists and was not written by crowdsim heldout",
    files=(*D, ("o/heldout.png", b"\x89PNG mine")),
)
case(
    "envs-heldout-users-json",
    HELD,
    "o/heldout.json exists and was not written by crowdsim heldout",
    files=(*D, ("o/heldout.json", '{"my": "notes"}')),
)
case("envs-heldout-out-under-file", f"{HELD} --out {{afile}}/h", "afile is a file, not a folder")
case(
    "envs-heldout-params-binary",
    f"{HELD} --params {{w}}/p.json",
    "p.json: not a parameters file (JSON) (binary, not UTF-8 text)",
    files=(*D, ("p.json", b"\x89PNG\x00\xff")),
)
case(
    "envs-heldout-params-broken",
    f"{HELD} --params {{w}}/p.json",
    "p.json: not a parameters file (JSON) (invalid JSON",
    files=(*D, ("p.json", '{"zeta": ')),
)
case(
    "envs-heldout-params-ncc",
    f"{HELD} --params {{w}}/p.json",
    "parameters of the 'ncc' tracker, but --tracker is 'bqp'",
    files=(*D, ("p.json", '{"tracker": "ncc", "params": {}}')),
)
case(
    "envs-heldout-tracker-meanshift",
    f"{HELD} --tracker meanshift",
    "--tracker meanshift: no row of tunables for this tracker",
    files=D,
)
case(
    "envs-heldout-policy-list-meta",
    f"{HELD} --policy {{w}}/m.zip",
    "m.zip: its crowdsim.json must be a JSON object, got list",
    files=D,
    setup=LIST_META,
)
case(
    "envs-heldout-policy-no-model",
    f"{HELD} --policy {{w}}/m.zip",
    "m.zip: a damaged policy: the model (data) is missing from the zip",
    files=D,
    setup=NO_MODEL,
)
case(
    "envs-heldout-scen-frames-huge",
    HELD,
    "d.json&&frames must be an integer in [2, 1000000], got 5000000",
    files=(("d.json", _dist(frames=5_000_000)),),
)

# --- train ------------------------------------------------------------------------------
TRAIN = "train --algo ppo --scenarios {w}/d.json --steps 4 --no-progress --out {w}/o"
case(
    "envs-train-envs-0", f"{TRAIN} --envs 0", "--envs must be an integer in [1, 64], got 0", files=D
)
case("envs-train-envs-huge", f"{TRAIN} --envs 1000", "--envs&&got 1000", files=D)
case("envs-train-steps-0", f"{TRAIN} --steps 0", "--steps&&got 0", files=D)
case(
    "envs-train-tracker-bytetrack",
    f"{TRAIN} --tracker bytetrack",
    "tracker bytetrack: no row of tunables for this tracker",
    files=D,
)
case("envs-train-k-0", f"{TRAIN} --k 0", "--k must be an integer >= 1, got 0", files=D)
case("envs-train-frames-1", f"{TRAIN} --frames 1", "--frames&&got 1", files=D)
case("envs-train-threshold-nan", f"{TRAIN} --threshold nan", "--threshold&&got nan", files=D)
case(
    "envs-train-scenario-unknown",
    "train --algo ppo --scenarios marathon,parade --out {w}/o",
    "unknown scenario 'parade'",
)
case(
    "envs-train-users-model",
    TRAIN,
    "o/model.zip exists and was not written by crowdsim train",
    files=(*D, ("o/model.zip", b"PK my own zip")),
)
case(
    "envs-train-suite-truncated-frame",
    "train --algo ppo --suite {w}/s --out {w}/o",
    "000003.jpg: not a complete image",
    setup=seq_copy(_truncate_jpeg, keep_checksums=False),
)

# --- track --params / --policy / --dense --------------------------------------------------
TRACK = "track {seq} --no-progress --out {w}/r.txt"
case(
    "envs-track-params-other-tracker",
    f"{TRACK} --tracker bqp --params {{w}}/p.json",
    "p.json: made for the 'ncc' tracker, but --tracker is 'bqp'",
    files=(("p.json", '{"tracker": "ncc", "params": {}}'),),
)
case(
    "envs-track-params-binary",
    f"{TRACK} --params {{w}}/p.json",
    "p.json: not a parameters file (JSON) (binary",
    files=(("p.json", b"\xff\xd8\xff\xe0JFIF"),),
)
case(
    "envs-track-params-list",
    f"{TRACK} --params {{w}}/p.json",
    "p.json: expected a JSON object of parameters, got list",
    files=(("p.json", "[0.3, 0.2]"),),
)
case(
    "envs-track-params-unknown-field",
    f"{TRACK} --params {{w}}/p.json",
    "p.json: tracker 'bqp' has no parameter(s) zeta2",
    files=(("p.json", '{"params": {"zeta2": 1}}'),),
)
case(
    "envs-track-params-zeta-neg",
    f"{TRACK} --params {{w}}/p.json",
    "p.json: BQPParams.zeta must be a finite number >= 0, got -5",
    files=(("p.json", '{"zeta": -5}'),),
)
case(
    "envs-track-params-tracker-unknown",
    f"{TRACK} --params {{w}}/p.json",
    "p.json: unknown tracker 'magic'",
    files=(("p.json", '{"tracker": "magic", "params": {}}'),),
)
case(
    "envs-track-policy-list-meta",
    f"{TRACK} --policy {{w}}/m.zip",
    "m.zip: its crowdsim.json must be a JSON object, got list",
    setup=LIST_META,
)
case(
    "envs-track-policy-broken-meta",
    f"{TRACK} --policy {{w}}/m.zip",
    "m.zip: its crowdsim.json is not valid JSON",
    setup=BROKEN_META,
)
case(
    "envs-track-policy-no-model",
    f"{TRACK} --policy {{w}}/m.zip",
    "m.zip: a damaged policy: the model (data) is missing",
    setup=NO_MODEL,
)
case(
    "envs-track-policy-cut-tensors",
    f"{TRACK} --policy {{w}}/m.zip",
    "m.zip: a damaged policy: stable-baselines3 cannot load it",
    setup=CUT_TENSORS,
)
case(
    "envs-track-policy-not-zip",
    f"{TRACK} --policy {{w}}/m.zip",
    "m.zip: not a stable-baselines3 model (not a zip file",
    files=(("m.zip", b"not a zip at all"),),
)
case(
    "envs-track-policy-ncc",
    f"{TRACK} --tracker ncc --policy {{w}}/m.zip",
    "m.zip: made for the 'bqp' tracker, but --tracker is 'ncc'",
    setup=CUT_TENSORS,
)
case(
    "envs-track-dense-speedup",
    f"{TRACK} --dense --set speedup=true",
    "--dense (no speed-up sampling) contradicts --set speedup=True",
)
case(
    "envs-track-dense-ncc",
    f"{TRACK} --tracker ncc --dense",
    "--dense sets a parameter that --tracker ncc does not have (trackers with it: bqp, "
    "bqp-ncc, bqp-dense)",
)
case(
    "envs-track-appearance-clash",
    f"{TRACK} --appearance ncc --set appearance=kcf",
    "--appearance ncc contradicts --set appearance=kcf",
)
case(
    "envs-track-truncated-no-checksums",
    "track {w}/s --tracker ncc --no-progress --out {w}/r.txt",
    "000003.jpg: not a complete image",
    setup=seq_copy(_truncate_jpeg, keep_checksums=False),
)


# --- the environments' Python API --------------------------------------------------------
def _make(**kw):
    import gymnasium as gym

    import envs  # noqa: F401 - registers the ids

    def call(w: Path, env: Env) -> object:
        return gym.make("crowdsim/TrackerTuning-v0", **kw)

    return call


api_case("envs-api-make-k-0", _make(scenarios=dict(TINY), k_frames=0), "k_frames&&got 0")
api_case(
    "envs-api-make-threshold-neg",
    _make(scenarios=dict(TINY), threshold_px=-1.0),
    "threshold_px&&got -1.0",
)
api_case(
    "envs-api-make-ocsort",
    _make(scenarios=dict(TINY), tracker="ocsort"),
    "tracker ocsort: no row of tunables for this tracker",
)
api_case(
    "envs-api-make-frames-huge",
    _make(scenarios={**TINY, "frames": 10**9}),
    "ScenarioDistribution.frames must be an integer in [2, 1000000]",
)
api_case(
    "envs-api-make-unknown-field",
    _make(scenarios={"framez": 3}),
    "unknown field(s) framez",
)
api_case("envs-api-make-scenario", _make(scenarios="marathon,parade"), "unknown scenario 'parade'")


def _env(**kw):
    def call(w: Path, env: Env) -> object:
        from envs.tracker_tuning import TrackerTuningEnv

        return TrackerTuningEnv(**kw)

    return call


api_case("envs-api-env-render-mode", _env(render_mode="human"), "render_mode&&'human'")
api_case(
    "envs-api-make-episodes",
    _make(episodes="ucf9"),
    "episodes must be an envs.episodes.EpisodeSource, got str",
)
api_case(
    "envs-api-make-suite-only-letters",
    _make(suite="ucf9", only="seq99"),
    "--only: no sequence 'seq99'",  # one name, not the letters of it
)


def _stepped(action):
    def call(w: Path, env: Env) -> object:
        from envs.tracker_tuning import TrackerTuningEnv

        e = TrackerTuningEnv(scenarios={**TINY, "frames": 4}, k_frames=2)
        e.reset(seed=0)
        return e.step(action)

    return call


api_case("envs-api-step-shape", _stepped(np.zeros(4)), "action must be 5 real numbers")
api_case("envs-api-step-column", _stepped(np.zeros((5, 1))), "got shape (5, 1) of float64")
api_case("envs-api-step-complex", _stepped(np.zeros(5) + 1j), "of complex128")
api_case("envs-api-step-dict", _stepped({"zeta": 1.0}), "got {{'zeta': 1.0}}")
api_case("envs-api-step-nan", _stepped(np.full(5, np.nan)), "action must be finite")
api_case("envs-api-step-inf", _stepped(np.r_[np.inf, np.zeros(4)]), "action must be finite")


def _step_before_reset(w: Path, env: Env) -> object:
    from envs.tracker_tuning import TrackerTuningEnv

    return TrackerTuningEnv(scenarios=dict(TINY)).step(np.zeros(5))


def _reset_needed() -> tuple[type[BaseException], ...]:
    import gymnasium as gym

    return (gym.error.ResetNeeded,)


api_case("envs-api-step-before-reset", _step_before_reset, "call reset()", raises=_reset_needed())


def _space(call):
    def run(w: Path, env: Env) -> object:
        from envs.param_space import ParamSpace

        return call(ParamSpace)

    return run


api_case(
    "envs-api-space-base",
    _space(lambda P: P(base={"zeta": 1})),
    "ParamSpace(base=...) must be the parameters of a tunable tracker",
)
api_case("envs-api-space-lack", _space(lambda P: P().to_action({"zeta": 1})), "lack eta")
api_case(
    "envs-api-space-unknown",
    _space(lambda P: P().params_from_dict({"zeta2": 1})),
    "unknown BQPParams parameter(s) zeta2",
)


def _load_params(w: Path, env: Env) -> object:
    from envs.param_space import load_params

    return load_params(w / "p.json")


api_case(
    "envs-api-load-params-binary",
    _load_params,
    "p.json: not a parameters",
    files=(("p.json", b"\x00\xff"),),
)
api_case(
    "envs-api-load-params-magic",
    _load_params,
    "p.json: unknown tracker 'magic'",
    files=(("p.json", '{"tracker": "magic"}'),),
)


def _load_policy(w: Path, env: Env) -> object:
    from envs.training import load_policy

    return load_policy(w / "m.zip")


api_case(
    "envs-api-load-policy-list-meta",
    _load_policy,
    "must be a JSON object, got list",
    setup=LIST_META,
)
api_case(
    "envs-api-load-policy-algo",
    _load_policy,
    "m.zip: unknown algorithm 'dqn' (ppo or sac)",
    setup=_policy({"data": "{}", "policy.pth": b"x", "crowdsim.json": META.replace("ppo", "dqn")}),
)


def _objective(**kw):
    def call(w: Path, env: Env) -> object:
        from envs.tuners import Objective

        return Objective(**kw)

    return call


api_case(
    "envs-api-objective-meanshift",
    _objective(scenarios="all", tracker="meanshift"),
    "--tracker meanshift: no row of tunables",
)
api_case("envs-api-objective-none", _objective(), "give exactly one of --suite NAME")
api_case(
    "envs-api-objective-episodes-0",
    _objective(scenarios="all", train_episodes=0),
    "Objective.train_episodes&&got 0",
)
api_case(
    "envs-api-objective-unknown-field",
    _objective(scenarios={"agentz": [1, 2]}),
    "unknown field(s) agentz",
)
api_case("envs-api-objective-only", _objective(suite="ucf9", only=5), "Objective.only&&5")


def _dist_api(**kw):
    def call(w: Path, env: Env) -> object:
        from envs.episodes import ScenarioDistribution

        return ScenarioDistribution(**kw)

    return call


api_case(
    "envs-api-dist-agents-huge",
    _dist_api(agents=(1, 10**7)),
    "ScenarioDistribution.agents must be an integer in [1, 1000000], got 10000000",
)
api_case("envs-api-dist-scenarios-int", _dist_api(scenarios=5), "a scenario name or a list")
api_case("envs-api-dist-template", _dist_api(template_px="big"), "template_px&&'big'")


def _train_objects(w: Path, env: Env) -> object:
    from envs.episodes import ScenarioDistribution
    from envs.training import train

    return train("ppo", out=w / "o", env_kwargs={"scenarios": ScenarioDistribution()})


api_case("envs-api-train-objects", _train_objects, "env_kwargs must be JSON values")


def _crowd(actions, **kw):
    def call(w: Path, env: Env) -> object:
        from envs import crowd_v0

        par = crowd_v0.parallel_env(n_agents=6, max_cycles=3, **kw)
        par.reset(seed=0)
        return par.step(actions(par.agents) if callable(actions) else actions)

    return call


api_case(
    "envs-api-crowd-unknown-agent",
    _crowd({"ped_99": [0.0, 0.0]}),
    "unknown agent 'ped_99'; agents are named 'ped_<id>' with ids below max_agents = 6",
)
api_case("envs-api-crowd-misspelt-agent", _crowd({"pde_0": [0.0, 0.0]}), "unknown agent 'pde_0'")
api_case(
    "envs-api-crowd-scalar-action",
    _crowd(lambda agents: {agents[0]: 1.0}),
    "action of 'ped_0' must have shape (2,)&&got shape ()",
)
api_case(
    "envs-api-crowd-wrong-shape",
    _crowd(lambda agents: {agents[1]: [1.0, 2.0, 3.0]}),
    "action of 'ped_1' must have shape (2,)&&got shape (3,)",
)
api_case(
    "envs-api-crowd-nan-action",
    _crowd(lambda agents: {agents[2]: [np.nan, 0.0]}),
    "action of 'ped_2' must be finite",
)
api_case("envs-api-crowd-not-dict", _crowd([[0.0, 0.0]]), "actions must be a dict")


def _aec(face: str, call_on):
    """An AEC face of the crowd after ``reset``, given to ``call_on``."""

    def call(w: Path, env: Env) -> object:
        from envs import crowd_v0

        aec = getattr(crowd_v0, face)(n_agents=4, max_cycles=3)
        aec.reset(seed=0)
        return call_on(aec)

    return call


for face in ("raw_env", "env"):
    api_case(
        f"envs-api-aec-{face}-observe-unknown",
        _aec(face, lambda aec: aec.observe("ped_99")),
        "unknown agent 'ped_99'",
    )
    api_case(  # refused by the step that gives it, not at the cycle's end
        f"envs-api-aec-{face}-nan-action",
        _aec(face, lambda aec: aec.step([np.nan, 0.0])),
        "action of 'ped_0' must be finite",
    )
    api_case(  # never clipped into range
        f"envs-api-aec-{face}-inf-action",
        _aec(face, lambda aec: aec.step(np.array([np.inf, 0.0], np.float32))),
        "action of 'ped_0' must be finite",
    )
    api_case(
        f"envs-api-aec-{face}-wrong-shape",
        _aec(face, lambda aec: aec.step([0.0, 0.0, 0.0])),
        "action of 'ped_0' must have shape (2,)",
    )


def _arrays(act):
    def call(w: Path, env: Env) -> object:
        from envs.crowd import CrowdParallelEnv

        e = CrowdParallelEnv(n_agents=6)
        e.reset_arrays(0)
        n = len(e.agent_ids)
        return e.step_arrays(np.zeros((n, 2)), act(n))

    return call


api_case("envs-api-arrays-act-long", _arrays(lambda n: np.ones(n + 3, bool)), "act must be a")
api_case("envs-api-arrays-act-2d", _arrays(lambda n: np.ones((n, 2), bool)), "act must be a")
api_case("envs-api-arrays-act-float", _arrays(lambda n: np.full(n, 0.5)), "got float64 of shape")


def _reset(make, **kw):
    def call(w: Path, env: Env) -> object:
        return make().reset(**kw)

    return call


def _crowd_made():
    from envs.crowd import CrowdParallelEnv

    return CrowdParallelEnv(n_agents=4)


def _tuning_made(**kw):
    def make():
        from envs.tracker_tuning import TrackerTuningEnv

        return TrackerTuningEnv(**{"scenarios": {**TINY, "frames": 4}, **kw})

    return make


api_case("envs-api-crowd-seed-neg", _reset(_crowd_made, seed=-1), "reset.seed&&got -1")
api_case("envs-api-crowd-seed-bool", _reset(_crowd_made, seed=True), "reset.seed&&got True")
api_case("envs-api-crowd-options", _reset(_crowd_made, options="x"), "options must be a dict")
api_case("envs-api-tuning-seed-frac", _reset(_tuning_made(), seed=1.5), "reset.seed&&got 1.5")
api_case("envs-api-tuning-options", _reset(_tuning_made(), options=[1]), "options must be a")
api_case(
    "envs-api-tuning-episode-beyond-pool",
    _reset(_tuning_made(pool=2), options={"episode": 5}),
    "options['episode'] must be an integer in [0, 1], got 5",
)


def _other_trackers_params(w: Path, env: Env) -> object:
    from envs.tracker_tuning import TrackerTuningEnv
    from tracker.registry import get

    return TrackerTuningEnv(scenarios=TINY, start_params=get("pnmc").make_params())


api_case(
    "envs-api-tuning-start-params-other-tracker",
    _other_trackers_params,
    "start_params must be the 'bqp' tracker's BQPParams, got PNMCParams",
)


def _crowd_env(**kw):
    def call(w: Path, env: Env) -> object:
        from envs.crowd import CrowdParallelEnv

        return CrowdParallelEnv(**kw)

    return call


api_case("envs-api-crowd-param-unknown", _crowd_env(n_agent=5), "unknown parameter(s) n_agent")
api_case("envs-api-crowd-vmax-0", _crowd_env(vmax=0.0), "CrowdEnvParams.vmax&&got 0.0")
api_case("envs-api-crowd-render-size", _crowd_env(render_size=(0, 5)), "render_size&&got 0")
api_case("envs-api-crowd-ids-text", _crowd_env(controlled_ids="abc"), "controlled_ids&&'abc'")
api_case("envs-api-crowd-agents-huge", _crowd_env(n_agents=10**7), "n_agents&&got 10000000")


def _policy_controlled(w: Path, env: Env) -> object:
    from envs.param_space import ParamSpace
    from envs.tracker_tuning import PolicyControlled

    return PolicyControlled(None, None, None, ParamSpace(), k_frames=0)


api_case("envs-api-policy-controlled-k", _policy_controlled, "k_frames&&got 0")


# --- an empty path would mean the working folder: refused, naming the flag ----------------
for command, extra in (
    ("heldout", ["--scenarios", "{w}/d.json", "--seeds", "1"]),
    ("tune", ["--scenarios", "{w}/d.json", "--trials", "1"]),
    ("train", ["--algo", "ppo", "--scenarios", "{w}/d.json", "--steps", "8"]),
    ("headroom", ["--scenarios", "{w}/d.json", "--seeds", "1"]),
):
    case(
        f"envs-{command}-out-empty",
        [command, *extra, "--out", ""],
        "--out must name a file or folder, got ''",
        files=D,
    )

for flag in ("--episodes", "--candidates"):
    case(  # --algo scene's flags: never ignored in silence
        f"envs-train-ppo{flag}",
        ["train", "--algo", "ppo", "--scenarios", "{w}/d.json", flag, "3", "--out", "{w}/o"],
        f"{flag} is for --algo scene",
        files=D,
    )

case(  # --algo ppo / sac's flag: never ignored in silence by --algo scene
    "envs-train-scene--steps",
    ["train", "--algo", "scene", "--scenarios", "{w}/d.json", "--steps", "3", "--out", "{w}/o"],
    "--steps is for --algo ppo / sac",
    files=D,
)

case(  # a one-sequence folder gives one episode, whatever --episodes asks: the cause is named
    "envs-train-scene-one-sequence",
    ["train", "--algo", "scene", "--suite", "{seq}", "--episodes", "2", "--out", "{w}/o"],
    "got 1 (--episodes 2, but the suite or folder holds 1 training sequence(s))",
)
