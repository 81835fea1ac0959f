"""Adaptive parameter policies: stable-baselines3 on ``crowdsim/TrackerTuning-v0``.

* :func:`train` -- PPO or SAC over N asynchronous environments; saves ``model.zip`` (with the
  environment's settings inside, :data:`POLICY_META`), ``learning_curve.json`` and a
  learning-curve PNG.
* :func:`load_policy` -- read a ``model.zip`` back (refusing one for another environment).
* :func:`policy_tracker` / :func:`tuned_tracker` -- a tracker driven by a loaded policy (or
  by a ``best_params.json``) for ``crowdsim track`` and :mod:`envs.heldout`.

torch and stable-baselines3 come from the ``rl`` extra and are imported on use; a missing one
raises :class:`crowdsim.optional.DependencyNotInstalled` with the install line.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
import zipfile
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.checks import require_choice, require_number
from crowdsim.optional import require
from envs.outputs import check_outputs, write_outputs
from envs.param_space import ParamSpace, load_params, require_tunable

ALGOS: tuple[str, ...] = ("ppo", "sac")
MAX_ENVS = 64
"""Most environment processes of one run (each holds its tracker and episode: ~640 MB)."""
MAX_STEPS = 10**9
TRAIN_FILES: tuple[str, ...] = ("learning_curve.json", "model.zip", "learning_curve.png")
"""What :func:`train` writes: the record (it lists the others' SHA-256, so a rerun replaces
them and never a user's own file of the same name: :mod:`envs.outputs`), the policy, the plot."""
POLICY_META = "crowdsim.json"
"""Entry added to ``model.zip``: the algorithm and the environment settings it was trained on."""


def _policy_meta(algo: str, env_kwargs: dict[str, Any], space: ParamSpace) -> dict[str, Any]:
    from envs.tracker_tuning import ENV_ID, OBS_FIELDS

    return {
        "format": 1,
        "env_id": ENV_ID,
        "algo": algo,
        "env_kwargs": env_kwargs,
        "observation": [f[0] for f in OBS_FIELDS] + [f"param:{n}" for n in space.names],
        "action": list(space.names),
        "space": space.signature(),
    }


def train(
    algo: str,
    *,
    out: str | os.PathLike[str],
    n_envs: int = 1,
    steps: int = 2048,
    env_kwargs: dict[str, Any] | None = None,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Train PPO or SAC on ``TrackerTuning-v0`` over ``n_envs`` asynchronous envs.

    Writes ``OUT/model.zip`` (stable-baselines3, with :data:`POLICY_META` inside),
    ``OUT/learning_curve.png`` and ``OUT/learning_curve.json``: the mean step reward (accuracy
    at T px, %) of every finished episode against the environment steps so far.
    """
    require_choice("", "--algo", algo, ALGOS)
    require_number("", "--envs", n_envs, lo=1, hi=MAX_ENVS, integer=True)
    require_number("", "--steps", steps, lo=1, hi=MAX_STEPS, integer=True)
    require_number("", "--seed", seed, lo=0, hi=2**32 - 1, integer=True)
    if env_kwargs is not None and not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs must be a dict, got {type(env_kwargs).__name__}")
    try:  # they go into model.zip: refused now, not after hours of training
        json.dumps(env_kwargs or {})
    except (TypeError, ValueError):
        raise ValueError(
            "env_kwargs must be JSON values (scenarios as a dict or a string, not objects): "
            "they are saved inside model.zip"
        ) from None
    require("torch", "rl", "crowdsim train")
    sb3 = require("stable_baselines3", "rl", "crowdsim train")
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from envs.tracker_tuning import TrackerTuningEnv

    log = log or (lambda msg: print(msg, file=sys.stderr))
    out = Path(out)
    env_kwargs = dict(env_kwargs or {})
    probe = TrackerTuningEnv(**env_kwargs)  # bad settings are refused before anything is made
    space = probe.space
    # episodes rendered now, over every env's process, so that no env renders while the
    # others wait for it in lockstep (an env's reset then reads its episode back)
    filled = probe.episodes.fill(workers=n_envs, progress=progress)
    if filled is not None:
        log(
            f"episode cache {probe.episodes.store.root}: {filled['stored']} episodes stored, "
            f"{filled['present']} already there ({filled['wall_s']:.0f} s)"
        )
    probe.close()
    # checked now, made when the results are written (a stopped run leaves no empty folder)
    check_outputs(out, TRAIN_FILES[0], TRAIN_FILES[1:], _is_train_record, "crowdsim train")
    # each subprocess environment dies with this process at once and silently (no orphan of
    # ~640 MB printing BrokenPipeError after a SIGKILL): see _subprocess_env
    factory = partial(_subprocess_env, os.getpid()) if n_envs > 1 else TrackerTuningEnv
    vec = make_vec_env(
        factory,
        n_envs=n_envs,
        seed=seed,
        env_kwargs=env_kwargs,
        vec_env_cls=SubprocVecEnv if n_envs > 1 else DummyVecEnv,
        vec_env_kwargs={"start_method": "spawn"} if n_envs > 1 else None,
    )
    curve: list[dict[str, float]] = []

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.bar = None

        def _on_training_start(self) -> None:
            from crowdsim.progress import progress_bar

            self.bar = progress_bar(
                total=steps, desc=f"train {algo}", unit="step", enabled=progress, leave=True
            )

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", []):
                ep = info.get("episode")
                if ep is not None:
                    curve.append(
                        {
                            "steps": int(self.num_timesteps),
                            "reward_per_step": 100.0 * float(ep["r"]) / max(ep["l"], 1),
                            "length": int(ep["l"]),
                        }
                    )
            if self.bar is not None:
                self.bar.update(self.num_timesteps - self.bar.n)
                if curve:
                    recent = [c["reward_per_step"] for c in curve[-10:]]
                    self.bar.set_postfix(acc=f"{np.mean(recent):.1f}%", refresh=False)
            return True

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()

    if algo == "ppo":
        n_steps = max(4, min(64, math.ceil(steps / n_envs / 4)))
        model = sb3.PPO(
            "MlpPolicy",
            vec,
            n_steps=n_steps,
            batch_size=max(2, min(64, n_steps * n_envs)),
            n_epochs=10,
            learning_rate=3e-4,
            gamma=0.9,
            seed=seed,
            verbose=0,
            device="cpu",
        )
    else:
        model = sb3.SAC(
            "MlpPolicy",
            vec,
            learning_starts=min(100, max(1, steps // 4)),
            batch_size=64,
            gamma=0.9,
            train_freq=1,
            seed=seed,
            verbose=0,
            device="cpu",
        )
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(None, []))  # else SB3 leaves an empty /tmp/SB3-<time> folder
    t0 = time.perf_counter()
    try:
        model.learn(total_timesteps=steps, callback=Curve())
    finally:
        vec.close()
    wall = time.perf_counter() - t0

    def save_model(tmp: Path) -> None:
        model.save(tmp)
        with zipfile.ZipFile(tmp, "a") as zf:
            zf.writestr(POLICY_META, json.dumps(_policy_meta(algo, env_kwargs, space)))

    trained = int(model.num_timesteps)  # PPO runs whole rollouts: up to one more than asked
    doc = {
        "algo": algo,
        "envs": n_envs,
        "steps": trained,
        "steps_asked": steps,
        "wall_s": wall,
        "steps_per_s": trained / wall if wall > 0 else None,
        "episodes": curve,
        "episode_cache": filled,
    }
    title = f"{algo.upper()} on TrackerTuning-v0, {n_envs} env(s)"
    write_outputs(
        out,
        TRAIN_FILES[0],
        doc,
        {
            "model.zip": save_model,
            "learning_curve.png": lambda p: plot_learning_curve(
                curve, p, title=title, threshold_px=probe.threshold_px
            ),
        },
    )
    log(
        f"{algo}: {trained} steps in {wall:.0f} s ({trained / max(wall, 1e-9):.2f} steps/s), "
        f"{len(curve)} episode{'s' if len(curve) != 1 else ''} -> {out / 'model.zip'}"
    )
    return doc


def _is_train_record(doc: Any) -> bool:
    return isinstance(doc, dict) and {"algo", "steps", "episodes"} <= set(doc)


def _subprocess_env(parent_pid: int, **env_kwargs: Any) -> Any:
    """A ``TrackerTuning-v0`` environment built inside a ``SubprocVecEnv`` worker, tied to
    its parent: the kernel kills the worker when the parent dies (and a watchdog thread
    covers the start-up race and other platforms: :mod:`crowdsim.jobs`'s parent-death
    watch), and Ctrl-C is left to the parent (a terminal sends SIGINT to the whole process
    group; the parent closes its workers)."""
    import signal

    from crowdsim.jobs import die_with_parent
    from envs.tracker_tuning import TrackerTuningEnv

    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return TrackerTuningEnv(**env_kwargs)


def plot_learning_curve(
    curve: Sequence[dict[str, float]], path: Path, title: str = "", threshold_px: float = 5.0
) -> Path:
    """Mean step reward (%) per finished episode and its running mean, PNG; the reward is the
    accuracy at ``threshold_px`` (the environment's)."""
    from crowdsim.plotting import new_figure, save_figure

    fig, ax = new_figure(figsize=(6, 3.8))
    if curve:
        x = np.array([c["steps"] for c in curve])
        y = np.array([c["reward_per_step"] for c in curve])
        ax.plot(x, y, "o", ms=3, alpha=0.5, label="episode")
        k = max(1, len(y) // 10)
        run = np.convolve(y, np.ones(k) / k, mode="valid")
        ax.plot(x[k - 1 :], run, "-", color="C3", label=f"running mean ({k})")
        ax.legend(loc="lower right")
    else:
        ax.text(0.5, 0.5, "no finished episode", ha="center", va="center")
    ax.set_xlabel("environment steps")
    ax.set_ylabel(f"mean step reward: accuracy at {threshold_px:g} px (%)")
    ax.set_title(title or "learning curve")
    ax.grid(alpha=0.3)
    return save_figure(fig, path, dpi=110)


def policy_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The metadata (:data:`POLICY_META`) of a ``model.zip`` written by :func:`train`, checked
    without loading the model: ``ValueError`` naming the file for anything but a sound zip
    holding a model and the metadata of a ``TrackerTuning-v0`` policy of a tunable tracker.
    A ``.json`` path is a scene-aware policy (:mod:`envs.scene_aware`), checked whole."""
    import zlib

    from envs.scene_aware import SceneAwarePolicy, is_scene_policy
    from envs.tracker_tuning import ENV_ID

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no such policy file")
    if is_scene_policy(p):
        return SceneAwarePolicy.load(p).policy_meta()
    try:
        with zipfile.ZipFile(p) as zf:
            names = zf.namelist()
            raw = zf.read(POLICY_META) if POLICY_META in names else None
            if "data" not in names or "policy.pth" not in names:
                missing = "data" if "data" not in names else "policy.pth"
                if raw is not None:  # ours, but the model is missing
                    raise ValueError(
                        f"{p}: a damaged policy: the model ({missing}) is missing from the zip"
                    )
                if "data" not in names:  # (a zip cut short can show an inner zip's entries)
                    raise ValueError(
                        f"{p}: not a stable-baselines3 model (no 'data' entry: damaged, "
                        "truncated or another kind of zip)"
                    )
            bad = zf.testzip()  # CRC of every member: a damaged or truncated entry
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno is not None:
            raise
        raise ValueError(
            f"{p}: not a stable-baselines3 model (not a zip file, or a damaged one)"
        ) from None
    if bad is not None:
        raise ValueError(f"{p}: a damaged policy (zip entry {bad!r} fails its CRC check)")
    meta: Any = None
    if raw is not None:
        try:
            meta = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise ValueError(f"{p}: its {POLICY_META} is not valid JSON") from None
        if not isinstance(meta, dict):
            raise ValueError(
                f"{p}: its {POLICY_META} must be a JSON object, got {type(meta).__name__}"
            )
    if meta is None or meta.get("env_id") != ENV_ID:
        raise ValueError(
            f"{p}: not a policy for {ENV_ID} (trained on "
            f"{(meta or {}).get('env_id', 'another environment')!s}); train one "
            "with crowdsim train"
        )
    if meta.get("algo") not in ALGOS:
        raise ValueError(f"{p}: unknown algorithm {meta.get('algo')!r} (ppo or sac)")
    kwargs = meta.setdefault("env_kwargs", {})
    if not isinstance(kwargs, dict):
        raise ValueError(f"{p}: its {POLICY_META} 'env_kwargs' must be an object")
    k = kwargs.get("k_frames", 25)
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"{p}: its {POLICY_META} 'k_frames' must be an integer >= 1, got {k!r}")
    try:
        require_tunable(kwargs.get("tracker", "bqp"), "tracker")
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None
    return meta


def load_policy(path: str | os.PathLike[str]) -> tuple[Any, dict[str, Any]]:
    """``(stable-baselines3 model, metadata)`` of a ``model.zip`` written by :func:`train`,
    or ``(SceneAwarePolicy, metadata)`` of a ``scene_aware.json`` (a ``.json`` path: written
    by ``crowdsim train --algo scene``, :mod:`envs.scene_aware`).

    Refuses (``ValueError`` naming the file) one that is not such a zip (not a zip, a
    damaged or truncated one, metadata that is not a JSON object, no model or truncated
    tensors inside: :func:`policy_meta`), a policy trained on another environment, or one
    whose spaces do not match ``TrackerTuning-v0``'s.
    """
    from envs.scene_aware import SceneAwarePolicy, is_scene_policy
    from envs.tracker_tuning import ENV_ID, OBS_FIELDS

    p = Path(path)
    if is_scene_policy(p):
        pol = SceneAwarePolicy.load(p)
        return pol, pol.policy_meta()
    meta = policy_meta(p)
    kwargs = meta.get("env_kwargs", {})
    sb3 = require("stable_baselines3", "rl", "--policy")
    cls = {"ppo": sb3.PPO, "sac": sb3.SAC}[meta["algo"]]
    try:
        model = cls.load(str(p), device="cpu")
    except Exception as exc:  # noqa: BLE001 - torch / pickle errors of a damaged model
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(
            f"{p}: a damaged policy: stable-baselines3 cannot load it "
            f"({type(exc).__name__}: {first[:200]})"
        ) from None
    space = ParamSpace(
        extended=bool(kwargs.get("extended", False)), tracker=kwargs.get("tracker", "bqp")
    )
    want_obs = (len(OBS_FIELDS) + space.dim,)
    if model.observation_space.shape != want_obs or model.action_space.shape != (space.dim,):
        raise ValueError(
            f"{p}: the policy's spaces {model.observation_space.shape} -> "
            f"{model.action_space.shape} do not match {ENV_ID} ({want_obs} -> "
            f"({space.dim},))"
        )
    return model, meta


# ---------------------------------------------------------------------------- tracking
def tuned_tracker(
    source: Any,
    params: str | os.PathLike[str] | None = None,
    policy: str | os.PathLike[str] | None = None,
    overrides: dict[str, Any] | None = None,
) -> tuple[Any, Any, str]:
    """``(tracker, frame source, description)`` for ``crowdsim track --params | --policy``.

    ``params``: a ``best_params.json`` -> its tracker with those static parameters.
    ``policy``: a ``model.zip`` from :func:`train` -> its tracker and ``source``
    wrapped in :class:`envs.tracker_tuning.PolicyControlled` (the policy sets the parameters
    every ``k_frames`` frames, as in training). ``overrides`` (e.g. ``appearance``) go on top.
    """
    from dataclasses import replace

    from tracker.registry import make_tracker

    if (params is None) == (policy is None):
        raise ValueError("give exactly one of --params and --policy")
    overrides = dict(overrides or {})
    if params is not None:
        name, p = load_params(params)
        if overrides:
            p = replace(p, **overrides)
        return make_tracker(name, p), source, f"{name} with the parameters of {params}"
    model, meta = load_policy(policy)
    trk, ctl, what = policy_tracker(source, model, meta, overrides)
    return trk, ctl, f"{what}, from {policy}"


def policy_tracker(
    source: Any, model: Any, meta: dict[str, Any], overrides: dict[str, Any] | None = None
) -> tuple[Any, Any, str]:
    """``(tracker, source under the policy, description)`` for a loaded policy.

    ``model, meta`` come from :func:`load_policy` (load once, track many sequences). The
    tracker starts from the space's default action; the policy sets its parameters every
    ``k_frames`` frames (deterministically), as in training.
    """
    from envs.tracker_tuning import PolicyControlled, make_tuned_tracker
    from tracker.registry import get

    kwargs = meta.get("env_kwargs", {})
    name = kwargs.get("tracker", "bqp")
    base = get(name).make_params(**dict(overrides or {}))
    space = ParamSpace(extended=bool(kwargs.get("extended", False)), base=base)
    k = int(kwargs.get("k_frames", 25))
    clash = [n for n in space.names if n in (overrides or {})]
    if clash:  # the policy's first action replaces them: the value would be dropped in silence
        raise ValueError(
            f"--set {clash[0]}={overrides[clash[0]]}: {policy_description(meta)} sets "
            f"{clash[0]} itself; drop it (tuned by the policy: {', '.join(space.names)})"
        )
    trk = make_tuned_tracker(name, space.to_params(space.default_action))
    ctl = PolicyControlled(source, trk, model, space, k_frames=k)
    return trk, ctl, f"{name} with {policy_description(meta)}"


def policy_description(meta: dict[str, Any]) -> str:
    """What a loaded policy does, in words: ``the PPO policy (every 25 frames)`` or ``the
    scene-aware choice (after 26 frames)``."""
    k = int(meta.get("env_kwargs", {}).get("k_frames", 25))
    if meta["algo"] == "scene":
        return f"the scene-aware choice (after {k + 1} frames)"
    return f"the {meta['algo'].upper()} policy (every {k} frames)"
