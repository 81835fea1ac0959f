"""Scene-aware tuning (issue 15, item 3): parameters chosen from what the tracker sees.

A :class:`SceneAwarePolicy` tracks the first ``k_frames + 1`` frames of a sequence with its
*opening* setting (the best single setting of the training episodes), looks at what the
tracker saw (the scene entries of the ``TrackerTuning-v0`` observation: targets, density,
spacing, speeds, flow order, appearance confidence, solver effort; never the ground truth),
and from then on tracks with one of ``M`` fixed candidate settings (the defaults and ``M - 1``
scrambled Sobol points, as ``crowdsim headroom``): the one that scored best, on average, on
the ``k`` training episodes whose observations were nearest (standardised Euclidean
distance). It is a nearest-neighbour contextual bandit with full feedback:
:func:`fit_scene_aware` tracks every training episode once per candidate, so every arm's
reward is known for every context.

The fit runs twice when needed: once opening with the defaults, which finds the best single
setting, then again opening with that setting, so that the features and scores the policy
learns from are those of the opening it will use. ``k`` is chosen by leave-one-out on the
training episodes alone (``k = N - 1`` is the best single setting of the other episodes, so
scene-awareness is kept only where it generalises there); the held-out sequences of
``crowdsim heldout`` are never used.

The policy has the ``predict(obs)`` face of a stable-baselines3 model, so
:class:`envs.tracker_tuning.PolicyControlled` drives it: ``crowdsim track --policy
scene_aware.json`` and ``crowdsim heldout --policy scene=DIR/scene_aware.json`` use it like a
``model.zip``. ``crowdsim train --algo scene`` fits and writes it.
"""

from __future__ import annotations

import copy
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.checks import require_number
from envs.param_space import ParamSpace, candidate_actions, read_json, require_tunable

FORMAT = "crowdsim-scene-aware"
VERSION = 1
SCENE_FILES: tuple[str, ...] = (
    "scene_fit.json",
    "scene_aware.json",
    "static_params.json",
    "scene_fit.png",
)
"""What :func:`write_scene_aware` writes: the record (the others' SHA-256 inside), the policy,
the best single static setting of the same training episodes (a ``best_params.json`` for
``--params``), and a PNG of the leave-one-out scores."""
NEIGHBOURS: tuple[int, ...] = (1, 3, 5, 9, 15)
"""Neighbour counts tried by leave-one-out (``N - 1``, the global static choice, always is)."""
EXCLUDED_FEATURES: tuple[str, ...] = ("progress",)
"""Observation entries that describe the schedule, not the scene."""


def scene_features() -> tuple[tuple[int, str], ...]:
    """``(index, name)`` of the observation entries the policy compares scenes by."""
    from envs.tracker_tuning import OBS_FIELDS

    return tuple((i, f[0]) for i, f in enumerate(OBS_FIELDS) if f[0] not in EXCLUDED_FEATURES)


class SceneAwarePolicy:
    """Nearest-neighbour choice among fixed candidate settings (module docstring).

    Parameters
    ----------
    tracker : str
        Registry name of the tuned tracker.
    extended : bool
        Whether the space includes the tracker's extra tunables.
    k_frames : int
        Frames per decision of :class:`~envs.tracker_tuning.PolicyControlled`: the choice is
        made after the first ``k_frames + 1`` frames.
    actions : (M, d) float
        Candidate settings as ``[-1, 1]`` actions of the tracker's :class:`ParamSpace`
        (row 0: the defaults).
    features : (N, f) float
        Scene features of the training episodes (:func:`scene_features`).
    scores : (N, M) float
        Accuracy (%) of every candidate on every training episode.
    neighbours : int
        How many nearest training episodes vote.
    opening : int
        Candidate tracked until the choice (``features`` and ``scores`` were measured with it).
    meta : dict
        Free record (threshold, where the episodes came from, the leave-one-out table).
    """

    def __init__(
        self,
        tracker: str,
        extended: bool,
        k_frames: int,
        actions: np.ndarray,
        features: np.ndarray,
        scores: np.ndarray,
        neighbours: int,
        opening: int = 0,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.tracker = require_tunable(tracker, "tracker")
        self.extended = bool(extended)
        self.space = ParamSpace(extended=self.extended, tracker=self.tracker)
        require_number("SceneAwarePolicy", "k_frames", k_frames, lo=1, integer=True)
        self.k_frames = int(k_frames)
        self.actions = np.asarray(actions, np.float64)
        self.features = np.asarray(features, np.float64)
        self.scores = np.asarray(scores, np.float64)
        m, n = len(self.actions), len(self.features)
        if self.actions.ndim != 2 or self.actions.shape[1] != self.space.dim or m < 1:
            raise ValueError(
                f"SceneAwarePolicy.actions must be (M, {self.space.dim}) for {self.space.names}, "
                f"got shape {self.actions.shape}"
            )
        if self.features.ndim != 2 or self.features.shape[1] != len(scene_features()) or n < 1:
            raise ValueError(
                f"SceneAwarePolicy.features must be (N, {len(scene_features())}), "
                f"got shape {self.features.shape}"
            )
        if self.scores.shape != (n, m):
            raise ValueError(
                f"SceneAwarePolicy.scores must be ({n}, {m}), got shape {self.scores.shape}"
            )
        for name, arr in (
            ("actions", self.actions),
            ("features", self.features),
            ("scores", self.scores),
        ):
            if not np.isfinite(arr).all():
                raise ValueError(f"SceneAwarePolicy.{name} must be finite")
        if np.abs(self.actions).max() > 1.0:
            raise ValueError("SceneAwarePolicy.actions must lie in [-1, 1]")
        require_number("SceneAwarePolicy", "neighbours", neighbours, lo=1, hi=n, integer=True)
        self.neighbours = int(neighbours)
        require_number("SceneAwarePolicy", "opening", opening, lo=0, hi=m - 1, integer=True)
        self.opening = int(opening)
        self.meta = dict(meta or {})
        self.mean = self.features.mean(axis=0)
        std = self.features.std(axis=0)
        self.scale = np.where(std > 1e-9, std, 1.0)
        self._calls = 0
        self._choice: np.ndarray | None = None
        self.choices: list[int] = []

    # ------------------------------------------------------------------ choosing
    def choose(self, features: np.ndarray, exclude: int | None = None, k: int | None = None) -> int:
        """Index of the candidate for a scene's ``features`` ``(f,)``: the best mean score
        over its ``k`` (default :attr:`neighbours`) nearest training episodes (``exclude``:
        one left out). Ties go to the lower index (the defaults first)."""
        k = self.neighbours if k is None else int(k)
        z = (self.features - self.mean) / self.scale
        q = (np.asarray(features, np.float64) - self.mean) / self.scale
        d = np.sqrt(((z - q) ** 2).sum(axis=1))
        if exclude is not None:
            d[exclude] = np.inf
        k = min(k, int(np.isfinite(d).sum()))
        near = np.argsort(d, kind="stable")[:k]
        return int(np.argmax(self.scores[near].mean(axis=0)))

    def reset(self) -> None:
        """Forget the current sequence's choice (:class:`PolicyControlled` calls it first)."""
        self._calls = 0
        self._choice = None

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        """The stable-baselines3 face: the opening setting at the first decision, then the
        chosen candidate for the rest of the sequence."""
        self._calls += 1
        if self._calls == 1:
            return self.actions[self.opening].copy(), None
        if self._choice is None:
            idx = [i for i, _ in scene_features()]
            j = self.choose(np.asarray(obs, np.float64)[idx])
            self.choices.append(j)
            self._choice = self.actions[j]
        return self._choice.copy(), None

    # ------------------------------------------------------------------ leave-one-out
    def leave_one_out(self, k: int) -> float:
        """Mean training score when each episode's candidate is chosen from the others."""
        n = len(self.features)
        if n < 2:
            return float(self.scores[:, 0].mean())
        return float(
            np.mean(
                [self.scores[i, self.choose(self.features[i], exclude=i, k=k)] for i in range(n)]
            )
        )

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "tracker": self.tracker,
            "extended": self.extended,
            "k_frames": self.k_frames,
            "space": self.space.signature(),
            "params": list(self.space.names),
            "feature_names": [n for _, n in scene_features()],
            "neighbours": self.neighbours,
            "opening": self.opening,
            "actions": self.actions.tolist(),
            "features": self.features.tolist(),
            "scores": self.scores.tolist(),
            "meta": self.meta,
        }

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SceneAwarePolicy:
        """Read a ``scene_aware.json``; ``ValueError`` naming the file for anything else (a
        foreign JSON, another version, a space that is not the tracker's today, bad arrays)."""
        p = Path(path)
        doc = read_json(p, "a scene-aware policy (JSON)")
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ValueError(
                f"{p}: not a scene-aware policy (write one with crowdsim train --algo scene)"
            )
        if doc.get("version") != VERSION:
            raise ValueError(
                f"{p}: scene-aware policy version {doc.get('version')!r}; "
                f"this crowdsim reads {VERSION}"
            )
        try:
            pol = cls(
                tracker=doc["tracker"],
                extended=doc["extended"],
                k_frames=doc["k_frames"],
                actions=np.asarray(doc["actions"], np.float64),
                features=np.asarray(doc["features"], np.float64),
                scores=np.asarray(doc["scores"], np.float64),
                neighbours=doc["neighbours"],
                opening=doc["opening"],
                meta=doc.get("meta") if isinstance(doc.get("meta"), dict) else {},
            )
        except KeyError as exc:
            raise ValueError(f"{p}: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{p}: {exc}") from None
        if doc.get("space") != pol.space.signature():
            raise ValueError(
                f"{p}: made for another parameter space ({doc.get('space')!r}); "
                f"{pol.tracker}'s is {pol.space.signature()!r}: fit it again"
            )
        if doc.get("feature_names") != [n for _, n in scene_features()]:
            raise ValueError(f"{p}: made for other observation entries; fit it again")
        return pol

    def policy_meta(self) -> dict[str, Any]:
        """The metadata :func:`envs.training.policy_tracker` reads."""
        return {
            "algo": "scene",
            "env_kwargs": {
                "tracker": self.tracker,
                "extended": self.extended,
                "k_frames": self.k_frames,
            },
        }


# ---------------------------------------------------------------------------- fitting
def episode_scores(
    seq: Any,
    tracker: str,
    space: ParamSpace,
    actions: np.ndarray,
    k_frames: int,
    threshold_px: float,
    opening: int = 0,
) -> dict[str, Any]:
    """Scene features after the first ``k_frames + 1`` frames (tracked with candidate
    ``opening``) and the accuracy (%) of every candidate over the whole sequence when it takes
    over from there: what :class:`PolicyControlled` would see and get.
    ``{"features", "scores"}``; ``{"skipped": True}`` when nobody is in view."""
    from envs.tracker_tuning import StepStats, make_tuned_tracker, observe, track_segment

    frames = list(seq.frames())
    n = len(frames)
    if n < k_frames + 2:
        raise ValueError(
            f"{getattr(seq, 'name', 'episode')}: {n} frames; scene-aware tuning needs more than "
            f"k + 1 = {k_frames + 1} (lower --k or raise --frames)"
        )
    gt_ids, gt = seq.gt_points()
    gt_ids, gt = np.asarray(gt_ids, np.int64), np.asarray(gt, np.float64)
    if len(gt_ids) == 0:  # the camera sees nobody: nothing to learn from
        return {"skipped": True}
    (ids0, pts0), births = seq.births()
    births = dict(births)
    first = np.asarray(actions[opening], np.float64)
    # as PolicyControlled: built and started with the defaults, the opening set after frame 0
    trk = make_tuned_tracker(tracker, space.to_params(space.default_action))
    trk.init(frames[0], ids0, pts0, int(seq.template_size))
    trk.set_params(space.to_params(first))
    seen = StepStats(trk)
    hits = total = 0
    for t in range(1, k_frames + 1):
        h, m = track_segment(trk, frames, births, gt_ids, gt, t, t + 1, threshold_px)
        hits, total = hits + h, total + m
        seen.frame()
    obs = observe(
        trk, space, first, k_frames / (n - 1), seen.confidences, seen.iterations, seen.frames
    )
    scores = []
    for a in actions:
        branch = copy.deepcopy(trk)
        branch.set_params(space.to_params(a))
        h, m = track_segment(branch, frames, births, gt_ids, gt, k_frames + 1, n, threshold_px)
        scores.append(100.0 * (hits + h) / max(total + m, 1))
    idx = [i for i, _ in scene_features()]
    return {"features": obs[idx].tolist(), "scores": scores}


def _episode_job(
    objective: Any, index: int, actions: list[list[float]], k_frames: int, opening: int
) -> dict[str, Any]:
    """Pool job of :func:`fit_scene_aware`: one training episode."""
    src = objective.episodes()
    seq = src.episode(index)
    space = ParamSpace(extended=objective.extended, tracker=objective.tracker)
    out = episode_scores(
        seq,
        objective.tracker,
        space,
        np.asarray(actions),
        k_frames,
        objective.threshold_px,
        opening,
    )
    spec = src.spec(index)
    family = getattr(getattr(src, "dist", None), "family", None)
    out["name"] = str(getattr(seq, "name", index))
    out["family"] = family(spec) if family else str(getattr(spec, "name", index))
    return out


def fit_scene_aware(
    objective: Any,
    episodes: int = 40,
    candidates: int = 17,
    k_frames: int = 25,
    seed: int = 0,
    workers: int = 1,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple[SceneAwarePolicy, dict[str, Any]]:
    """Track the first ``episodes`` training episodes of ``objective`` (stream 0, never the
    held-out ones) with every candidate, choose ``k`` by leave-one-out, return the policy and
    the fit record (per-episode scores, the leave-one-out table, wall time)."""
    import tempfile

    from crowdsim.jobs import Job, one_numba_thread, run_jobs

    log = log or (lambda msg: print(msg, file=sys.stderr))
    require_number("", "--episodes", episodes, lo=2, hi=100_000, integer=True)
    require_number("", "--k", k_frames, lo=1, integer=True)
    require_number("", "--envs", workers, lo=1, hi=os.cpu_count() or 1, integer=True)
    space = ParamSpace(extended=objective.extended, tracker=objective.tracker)
    actions = candidate_actions(space, candidates, seed=seed)
    src = objective.episodes()
    n = min(int(episodes), len(src)) if hasattr(src, "__len__") else int(episodes)
    if n < 2:
        why = (
            f" (--episodes {episodes}, but the suite or folder holds {len(src)} training "
            "sequence(s))"
            if hasattr(src, "__len__") and len(src) < int(episodes)
            else ""
        )
        raise ValueError(f"scene-aware tuning needs at least 2 training episodes, got {n}{why}")
    t0 = time.perf_counter()

    def scores_with(opening: int, tag: str) -> list[dict[str, Any]]:
        jobs = [
            Job(
                key=f"episode-{i:05d}",
                fn=_episode_job,
                args=(objective, i, actions.tolist(), int(k_frames), opening),
            )
            for i in range(n)
        ]
        with tempfile.TemporaryDirectory() as tmp:
            results = run_jobs(
                jobs,
                Path(tmp) / "fit.json",
                workers=workers,
                progress=progress,
                desc=f"scene-aware fit ({tag})",
                unit="episode",
                worker_init=one_numba_thread if workers > 1 else None,
                passthrough=(ValueError, OSError, MemoryError),
            )
        rows = [results[j.key] for j in jobs]
        kept = [r for r in rows if not r.get("skipped")]
        if len(kept) < 2:
            raise ValueError(
                f"scene-aware tuning needs at least 2 training episodes with someone in view; "
                f"{len(kept)} of {n} had any (more agents or a higher density would help)"
            )
        return kept

    rows = scores_with(0, "opening with the defaults")
    skipped = n - len(rows)
    first = np.array([r["scores"] for r in rows])
    static = int(np.argmax(first.mean(axis=0)))  # the best single setting of the training set
    if static != 0:
        rows = scores_with(static, "opening with the best single setting")
    features = np.array([r["features"] for r in rows])
    scores = np.array([r["scores"] for r in rows])
    pol = SceneAwarePolicy(
        objective.tracker, objective.extended, k_frames, actions, features, scores, 1, static
    )
    table = {}
    m = len(rows)
    for k in sorted({*(k for k in NEIGHBOURS if k < m), m - 1}):
        table[k] = pol.leave_one_out(k)
    best_k = max(table, key=lambda k: (round(table[k], 9), k))  # ties: more neighbours
    pol.neighbours = best_k
    record = {
        "episodes": len(rows),
        "skipped_empty": skipped,
        "candidates": int(len(actions)),
        "k_frames": int(k_frames),
        "threshold_px": objective.threshold_px,
        "tracker": objective.tracker,
        "neighbours": best_k,
        "opening": static,
        "leave_one_out": {str(k): v for k, v in table.items()},
        "defaults_mean": float(first[:, 0].mean()),
        "static_mean": float(scores[:, static].mean()),
        "static_params": space.values(actions[static]),
        "oracle_mean": float(scores.max(axis=1).mean()),
        "wall_s": time.perf_counter() - t0,
        "training": [
            {"name": r["name"], "family": r["family"], "best": int(np.argmax(r["scores"]))}
            for r in rows
        ],
    }
    pol.meta = {k: v for k, v in record.items() if k != "training"}
    log(
        f"scene-aware fit on {len(rows)} episodes x {len(actions)} candidates in "
        f"{record['wall_s']:.0f} s: "
        f"leave-one-out acc@{objective.threshold_px:g} {table[best_k]:.2f} % with {best_k} "
        f"neighbours (the best single setting: {record['static_mean']:.2f} %; defaults "
        f"{record['defaults_mean']:.2f} %; best per episode {record['oracle_mean']:.2f} %)"
    )
    return pol, record


def _plot_fit(record: dict[str, Any], path: Path) -> Path:
    from crowdsim.plotting import new_figure, save_figure

    fig, ax = new_figure(figsize=(6, 3.6))
    loo = record["leave_one_out"]
    ks = list(loo)
    ax.bar(range(len(ks)), [loo[k] for k in ks], color="C0", label="leave-one-out")
    ax.axhline(record["defaults_mean"], color="C1", ls="--", label="defaults")
    ax.axhline(record["oracle_mean"], color="C2", ls=":", label="best per episode")
    ax.set_xticks(
        range(len(ks)),
        [f"{k}" + (" (static)" if int(k) == record["episodes"] - 1 else "") for k in ks],
    )
    ax.set_xlabel("neighbours")
    ax.set_ylabel(f"acc@{record['threshold_px']:g} (%)")
    lo = min(min(loo.values()), record["defaults_mean"]) - 2.0
    ax.set_ylim(max(0.0, lo), min(100.0, record["oracle_mean"] + 2.0))
    ax.set_title(
        f"scene-aware fit: {record['episodes']} episodes, {record['candidates']} candidates"
    )
    ax.legend(loc="lower right", fontsize=8)
    return save_figure(fig, path, dpi=110)


def _is_scene_record(doc: Any) -> bool:
    return isinstance(doc, dict) and {"leave_one_out", "neighbours", "static_params"} <= set(doc)


def check_scene_out(out: str | os.PathLike[str]) -> None:
    """Refuse (before any work) an ``--out`` holding files of these names not written here."""
    from envs.outputs import check_outputs

    check_outputs(
        Path(out), SCENE_FILES[0], SCENE_FILES[1:], _is_scene_record, "crowdsim train --algo scene"
    )


def write_scene_aware(
    pol: SceneAwarePolicy, record: dict[str, Any], out: str | os.PathLike[str]
) -> dict[str, Path]:
    """Write :data:`SCENE_FILES` into ``out`` (atomically; see :mod:`envs.outputs`)."""
    from envs.outputs import write_outputs

    def text(doc: Any) -> Callable[[Path], None]:
        return lambda p: p.write_text(json.dumps(doc, indent=2) + "\n")

    static = {
        "tracker": pol.tracker,
        "params": record["static_params"],
        "source": "crowdsim train --algo scene",
    }
    return write_outputs(
        Path(out),
        SCENE_FILES[0],
        record,
        {
            SCENE_FILES[1]: text(pol.to_dict()),
            SCENE_FILES[2]: text(static),
            SCENE_FILES[3]: lambda p: _plot_fit(record, p),
        },
    )


def is_scene_policy(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a scene-aware policy file (by its ``.json`` suffix)."""
    return Path(path).suffix.lower() == ".json"
