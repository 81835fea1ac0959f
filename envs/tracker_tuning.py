"""Gymnasium environments in which an agent sets a tracker's parameters as it tracks.

``crowdsim/TrackerTuning-v0`` (:class:`TrackerTuningEnv`): every step applies new parameters
through :meth:`tracker.base.Tracker.set_params` and tracks the next ``K`` frames with a real
registered tracker (BQP by default; any tracker with a row of
:data:`envs.param_space.TUNABLES`: ``tracker="pnmc"``, ``"ncc"``);
``crowdsim/TrackerTuningBandit-v0`` (:class:`TrackerTuningBanditEnv`): one action scores a
whole sequence (for black-box tuners). ``import envs`` registers both (the one table,
:data:`envs.ENVS`).

The observation (:data:`OBS_FIELDS`) is computed from the base tracker's state (points,
:meth:`~tracker.base.Tracker.motion`: BQP's and PNMC's velocities, the NCC and mean-shift
baselines' last displacements; the per-target ``confidence`` of each frame) and
:meth:`tracker.base.Tracker.stats` (BQP's solver iterations and groups) only, never from the
ground truth, so an adaptive policy runs on real video too (:class:`PolicyControlled` drives
any source, a video file included). No tracker subclass exists for observation.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from crowdsim.checks import checked_seed, require_number
from envs.episodes import EpisodeSource, ScenarioDistribution, make_episodes, shows_someone
from envs.param_space import ParamSpace, require_tunable
from tracker.base import Tracker
from tracker.metrics import point_errors

ENV_ID = "crowdsim/TrackerTuning-v0"
BANDIT_ENV_ID = "crowdsim/TrackerTuningBandit-v0"
MAX_EMPTY_DRAWS: int = 100
"""Most draws in a row of episodes with nobody in view before ``reset`` gives up."""

OBS_FIELDS: tuple[tuple[str, float, float, str], ...] = (
    ("targets_log10", 0.0, 6.0, "log10(1 + active targets)"),
    ("density", 0.0, 1.0, "fraction of the image covered by head boxes: n s^2 / (W H)"),
    ("nn_distance", 0.0, 10.0, "median nearest-neighbour distance, template sizes (10 if < 2)"),
    ("speed_mean", 0.0, 5.0, "mean tracker speed |p_dot|, template sizes per frame"),
    ("speed_std", 0.0, 5.0, "standard deviation of the speeds, template sizes per frame"),
    ("flow_order", 0.0, 1.0, "|mean unit velocity| of moving targets (1 one flow, 0 mixed)"),
    ("conf_mean", -1.0, 2.0, "mean appearance confidence of the chosen positions"),
    ("conf_std", 0.0, 2.0, "standard deviation of that confidence"),
    ("conf_p10", -1.0, 2.0, "10th percentile of that confidence"),
    ("low_conf_fraction", 0.0, 1.0, "fraction of target-frames below update_threshold (if any)"),
    ("solver_iterations", 0.0, 100.0, "solver iterations per target and frame (BQP; else 0)"),
    ("group_fraction", 0.0, 1.0, "fraction of targets in a coherent-motion group (BQP; else 0)"),
    ("progress", 0.0, 1.0, "frames tracked / (sequence length - 1)"),
)
"""``(name, low, high, meaning)`` of the observation's first entries; the current parameters
(as the ``[-1, 1]`` action, :class:`envs.param_space.ParamSpace` order) follow. Confidence
entries cover the frames of the last step (0 before the first step); speeds and groups are the
tracker's state after the step. Every entry is clipped into its range."""


def make_tuned_tracker(tracker: str, params: Any) -> Tracker:
    """The registered tracker ``tracker`` (one with a row of tunables) built on ``params``."""
    from tracker.registry import get

    require_tunable(tracker, "tracker")
    return get(tracker).create(params)


class StepStats:
    """What a tracker showed over the frames of one step, for :func:`observe`: the
    per-target confidence of each frame (the base ``Tracker.confidence``) and the solver
    iterations spent (``Tracker.stats()["solver_iterations"]``, where the tracker reports
    them). :meth:`frame` after each tracked frame; :meth:`restart` at the start of a step."""

    def __init__(self, trk: Tracker) -> None:
        self.trk = trk
        self.restart()

    def _iterations(self) -> float:
        return float(self.trk.stats().get("solver_iterations", 0.0))

    def restart(self) -> None:
        self.confidences: list[np.ndarray] = []
        self.frames = 0
        self._it0 = self._iterations()

    def frame(self) -> None:
        self.confidences.append(np.asarray(self.trk.confidence, np.float64).copy())
        self.frames += 1

    @property
    def iterations(self) -> float:
        return self._iterations() - self._it0


@dataclass
class _Episode:
    """State of the sequence being tracked."""

    seq: Any
    frames: Iterator[np.ndarray]
    births: dict[int, tuple[np.ndarray, np.ndarray]]
    gt_ids: np.ndarray
    gt_points: np.ndarray
    tracks: np.ndarray
    """(T, N_gt, 2) tracked positions in ground-truth column order, NaN where not tracked."""
    t: int = 0
    frame: np.ndarray | None = None


def track_segment(
    trk: Any,
    frames: list[np.ndarray],
    births: Mapping[int, Any],
    gt_ids: np.ndarray,
    gt: np.ndarray,
    start: int,
    stop: int,
    threshold_px: float,
) -> tuple[int, int]:
    """Track frames ``start .. stop - 1`` with ``trk``; ``(hits, scored points)``."""
    hits = total = 0
    for t in range(start, stop):
        ids, pts = trk.step(frames[t], births.get(t))
        err = point_errors(gt_ids, gt[t][None], np.asarray(ids), np.asarray(pts)[None])[0]
        ok = ~np.isnan(err)
        total += int(ok.sum())
        hits += int((err[ok] <= threshold_px).sum())
    return hits, total


def observe(
    trk: Tracker,
    space: ParamSpace,
    action: np.ndarray,
    progress: float,
    confidences: list[np.ndarray],
    iterations: float,
    frames: int,
) -> np.ndarray:
    """The observation vector (:data:`OBS_FIELDS` + the action) of a tracker's state.

    Parameters
    ----------
    trk : Tracker
        After ``frames`` frames of the last step (its ``points``, its
        :meth:`~tracker.base.Tracker.motion` and :meth:`~tracker.base.Tracker.stats`).
    action : (d,) float
        The parameters in force, as the ``[-1, 1]`` action.
    progress : float
        Fraction of the sequence tracked.
    confidences : list of (n_t,) float
        Per-target confidences of each frame of the step (:class:`StepStats`).
    iterations : float
        Solver iterations spent over the step (0 for trackers without a solver).
    frames : int
        Frames tracked in the step.
    """
    from scipy.spatial import cKDTree

    s = float(max(trk.template_size, 1))
    n = len(trk.points)
    out = np.zeros(len(OBS_FIELDS) + space.dim)
    out[0] = np.log10(1.0 + n)
    if trk.frame_shape is not None:
        h, w = trk.frame_shape[:2]
        out[1] = n * s * s / float(w * h)
    out[2] = 10.0
    if n >= 2:
        d, _ = cKDTree(trk.points).query(trk.points, k=2)
        out[2] = float(np.median(d[:, 1])) / s
    vel = trk.motion()  # BQP's and PNMC's velocities, the baselines' last displacements
    if len(vel):
        speed = np.sqrt((vel**2).sum(1)) / s
        out[3] = speed.mean()
        out[4] = speed.std()
        moving = speed > 0.05
        if moving.any():
            unit = vel[moving] / (speed[moving, None] * s)
            out[5] = float(np.sqrt((unit.mean(0) ** 2).sum()))
    conf = np.concatenate(confidences) if confidences else np.zeros(0)
    conf = conf[np.isfinite(conf)]
    if conf.size:
        out[6] = conf.mean()
        out[7] = conf.std()
        out[8] = np.percentile(conf, 10)
        threshold = getattr(trk.params, "update_threshold", None)
        if threshold is not None:
            out[9] = float((conf < threshold).mean())
    if frames > 0 and n > 0:
        out[10] = iterations / float(frames * n)
    out[11] = float(trk.stats().get("group_fraction", 0.0))
    out[12] = progress
    out[len(OBS_FIELDS) :] = action
    lo, hi = obs_bounds(space)
    return np.clip(out, lo, hi).astype(np.float32)


def obs_bounds(space: ParamSpace) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` float32 arrays of the observation."""
    lo = np.array([f[1] for f in OBS_FIELDS] + [-1.0] * space.dim, np.float32)
    hi = np.array([f[2] for f in OBS_FIELDS] + [1.0] * space.dim, np.float32)
    return lo, hi


class TrackerTuningEnv(gym.Env):
    """Set a tracker's parameters (BQP's term weights and update threshold) while it tracks.

    ## Description

    A real tracker -- by default BQP (paper 1: one binary quadratic program per frame, solved
    by Frank-Wolfe with SWAP steps); PNMC or NCC with ``tracker=`` -- follows every person of
    a synthetic dense-crowd sequence. At each step the agent chooses the tracker's
    parameters -- for BQP the weights ``zeta`` (motion), ``eta`` (neighbourhood motion),
    ``w_sp`` (spatial proximity), ``w_g`` (grouping) and the appearance-update threshold; for
    the others their row of :data:`envs.param_space.TUNABLES` -- which the tracker applies
    through ``set_params`` from the next frame on; the tracker then tracks the next ``K``
    frames and the reward is its accuracy on them. A policy can thus adapt the parameters to
    the crowd (dense, fast, counterflow, low contrast) as it changes.

    ## Action Space

    For BQP ``Box(-1, 1, (5,), float32)`` (8 with ``extended=True``: also search factor,
    motion sigma, KCF learning rate; PNMC 4 / 9, NCC 2 / 3), mapped to parameter ranges by
    :class:`envs.param_space.ParamSpace`:
    piecewise linear with ``-1`` the low end, ``0`` **the paper defaults exactly** and ``+1``
    the high end (zeta 0 / 0.3 / 1.5, eta 0 / 0.2 / 1, w_sp 0 / 0.3 / 1.5, w_g 0 / 1 / 3,
    update_threshold 0 / 0.6 / 1). Out-of-range actions are clipped; ``info["clipped"]``
    counts the clipped coordinates of the step, ``info["clipped_total"]`` of the episode.

    ## Observation Space

    ``Box(low, high, (13 + d,), float32)``, each entry clipped into its range:

    ==  ====================  ==========  ======================================================
    i   name                  range       meaning
    ==  ====================  ==========  ======================================================
    0   targets_log10         [0, 6]      log10(1 + active targets)
    1   density               [0, 1]      image fraction covered by heads, ``n s^2 / (W H)``
    2   nn_distance           [0, 10]     median nearest-neighbour distance, template sizes
    3   speed_mean            [0, 5]      mean speed of the tracker's motion, templates/frame
    4   speed_std             [0, 5]      their standard deviation
    5   flow_order            [0, 1]      ``|mean unit velocity|`` (1: one flow; 0: counterflow)
    6   conf_mean             [-1, 2]     mean appearance confidence of the chosen positions
    7   conf_std              [0, 2]      its standard deviation
    8   conf_p10              [-1, 2]     its 10th percentile
    9   low_conf_fraction     [0, 1]      fraction below the update threshold (not updated)
    10  solver_iterations     [0, 100]    solver iterations per target and frame (BQP)
    11  group_fraction        [0, 1]      fraction of targets in a coherent-motion group (BQP)
    12  progress              [0, 1]      frames tracked / (length - 1)
    13+ parameters            [-1, 1]     the parameters in force, as the action
    ==  ====================  ==========  ======================================================

    Entries 6-10 describe the frames of the last step (0 after ``reset``); 10 and 11 come
    from :meth:`tracker.base.Tracker.stats` and are 0 for trackers that report neither.
    Nothing in the observation comes from the ground truth.

    ## Rewards

    A Python float in ``[0, 1]``: the fraction of the step's ground-truth points (people
    present in the frame) whose tracked point of the same id lies within ``threshold_px``
    (default 5) pixels -- the papers' accuracy at T px divided by 100, computed with
    :func:`tracker.metrics.point_errors`. A person the tracker lost counts as a miss. A step
    with no ground-truth point scores 0 (``info["gt_points"] == 0``).

    ## Starting State

    ``reset`` draws a sequence -- from the scenario distribution with ``np_random`` (seeded by
    ``reset(seed=...)``), or episode ``options["episode"]`` of the source's fixed list -- and
    initialises the tracker on frame 0 at the ground-truth positions with ``start_params``
    (default: the paper defaults, action 0). People entering later are born at their
    ground-truth position in their first frame, as in the papers.

    ## Episode End

    One episode is one sequence: ``terminated`` is true once its last frame is tracked (the
    last step may hold fewer than ``K`` frames); a step after that raises ``ResetNeeded``, as
    the bandit's does. There is no truncation; wrap the env in ``TimeLimit`` if needed.

    ## Arguments

    ``gymnasium.make("crowdsim/TrackerTuning-v0", **kwargs)``:

    * ``scenarios`` -- a :class:`envs.episodes.ScenarioDistribution`, a mapping of its
      fields, or a string (``"all"``, ``"marathon,crossing"``, a JSON/TOML file); default the
      full distribution (40-100 people, 100 frames, frames up to 640x480);
      :func:`envs.episodes.tiny_scenarios` is the smallest (quick experiments and tests);
    * ``suite``, ``only``, ``frames`` -- episodes from a suite instead (built-in name or a
      folder of MOT sequences); ``frames`` also truncates scenario sequences;
    * ``episodes`` -- a ready :class:`envs.episodes.EpisodeSource` (overrides the above);
    * ``episode_cache``, ``pool`` -- a folder of rendered episodes
      (:class:`envs.episodes.EpisodeCache`: each episode is simulated, rendered and encoded
      once, then every reset of every process reads it back, checksum checked) and, for a
      scenario distribution, the number of distinct episodes drawn and reused;
    * ``episode_seed`` -- the fixed-list stream (0 tuning, another value held-out);
    * ``k_frames`` (25) -- frames tracked per step; ``threshold_px`` (5) -- reward threshold;
    * ``extended`` (False) -- tune 8 parameters instead of 5;
    * ``tracker`` (``"bqp"``) -- registry name of a tunable tracker (``"bqp-ncc"``,
      ``"pnmc"``, ``"ncc"``: :func:`envs.param_space.tunable_trackers`);
    * ``start_params`` -- that tracker's parameters at reset (default: its defaults);
    * ``render_mode`` -- ``None`` or ``"rgb_array"`` (the current frame with ground truth in
      green and tracks in yellow, RGB).

    ## Version History

    * v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        scenarios: Any = None,
        suite: str | None = None,
        only: list[str] | None = None,
        frames: int | None = None,
        episodes: EpisodeSource | None = None,
        episode_seed: int = 0,
        episode_cache: str | None = None,
        pool: int | None = None,
        k_frames: int = 25,
        threshold_px: float = 5.0,
        extended: bool = False,
        tracker: str = "bqp",
        start_params: Any = None,
        render_mode: str | None = None,
    ) -> None:
        require_number("TrackerTuningEnv", "k_frames", k_frames, lo=1, integer=True)
        require_number("TrackerTuningEnv", "threshold_px", threshold_px, lo=0)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        require_tunable(tracker, "tracker")
        if episodes is None:
            if isinstance(scenarios, Mapping):
                scenarios = ScenarioDistribution.from_dict(scenarios)
            if suite is None and scenarios is None:
                scenarios = ScenarioDistribution()
            episodes = make_episodes(
                suite=suite,
                scenarios=scenarios,
                only=only,
                frames=frames,
                seed=episode_seed,
                episode_cache=episode_cache,
                pool=pool,
            )
        elif not isinstance(episodes, EpisodeSource):
            raise ValueError(
                f"episodes must be an envs.episodes.EpisodeSource, got {type(episodes).__name__}"
            )
        self.episodes = episodes
        self.k_frames = int(k_frames)
        self.threshold_px = float(threshold_px)
        self.tracker_name = tracker
        from tracker.registry import get

        base = get(tracker).make_params()
        if start_params is not None:
            if type(start_params) is not type(base):
                raise ValueError(
                    f"start_params must be the {tracker!r} tracker's {type(base).__name__}, "
                    f"got {type(start_params).__name__}"
                )
            base = start_params
        if not isinstance(extended, (bool, np.bool_)):
            raise ValueError(f"extended must be True or False, got {extended!r}")
        self.space = ParamSpace(extended=extended, base=base)
        self.start_action = self.space.to_action(base)
        self.action_space = spaces.Box(-1.0, 1.0, (self.space.dim,), np.float32)
        lo, hi = obs_bounds(self.space)
        self.observation_space = spaces.Box(lo, hi, dtype=np.float32)
        self.render_mode = render_mode
        self._ep: _Episode | None = None
        self._trk: Tracker | None = None
        self._seen: StepStats | None = None
        self._action = self.start_action.copy()
        self._clipped_total = 0

    # ------------------------------------------------------------------ episode
    def _pick(self, options: dict | None) -> Any:
        """The episode ``options["episode"]`` names, or a random one with someone in view:
        a distribution's camera can frame nobody (a few people, a wide hall), and such a
        draw is drawn again, as the held-out scoring skips it, up to
        :data:`MAX_EMPTY_DRAWS` times in a row."""
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset: options must be a dict or None, got {options!r}")
        unknown = sorted(map(str, set(options or {}) - {"episode"}))
        if unknown:  # a misspelt key had drawn a random episode in silence
            raise ValueError(f"reset: unknown option(s) {', '.join(unknown)}; valid: episode")
        if options and "episode" in options:
            k = options["episode"]
            n = len(self.episodes)
            require_number("reset", "options['episode']", k, lo=0, hi=n - 1, integer=True)
            return self.episodes.episode(int(k))
        for _ in range(MAX_EMPTY_DRAWS):
            seq = self.episodes.sample(self.np_random)
            if shows_someone(seq):
                return seq
        raise ValueError(
            f"reset: {MAX_EMPTY_DRAWS} episodes in a row had nobody in view; give the "
            "scenarios more people or a higher density, or a smaller view"
        )

    def _start(self, seq: Any) -> np.ndarray:
        gt_ids, gt_pts = seq.gt_points()
        if len(gt_ids) == 0:
            raise ValueError(f"sequence {seq.name!r} has no ground truth to score against")
        (ids0, pts0), births = seq.births()
        frames = iter(seq.frames())
        first = next(frames)
        gt_ids = np.asarray(gt_ids, np.int64)
        order = np.argsort(gt_ids)
        # the tracker first: a reset that fails leaves the env as it was, never half-made
        trk = make_tuned_tracker(self.tracker_name, self.space.to_params(self.start_action))
        trk.init(first, ids0, pts0, int(seq.template_size))
        self._gt_sorted = gt_ids[order]
        self._gt_order = order
        tracks = np.full((seq.length, len(gt_ids), 2), np.nan)
        self._ep = _Episode(
            seq=seq,
            frames=frames,
            births=dict(births),
            gt_ids=gt_ids,
            gt_points=np.asarray(gt_pts, np.float64),
            tracks=tracks,
            frame=first,
        )
        self._action = self.start_action.copy()
        self._trk = trk
        self._seen = StepStats(self._trk)
        self._record(0, self._trk.ids, self._trk.points)
        self._clipped_total = 0
        return observe(self._trk, self.space, self._action, 0.0, [], 0, 0)

    def _record(self, t: int, ids: np.ndarray, pts: np.ndarray) -> None:
        if len(ids) == 0:
            return
        pos = np.searchsorted(self._gt_sorted, ids)
        pos = np.minimum(pos, len(self._gt_sorted) - 1)
        ok = self._gt_sorted[pos] == ids
        self._ep.tracks[t, self._gt_order[pos[ok]]] = pts[ok]

    def _advance(self, n: int) -> tuple[int, int]:
        """Track up to ``n`` more frames; returns ``(first frame index, frames tracked)``."""
        ep, trk = self._ep, self._trk
        start = ep.t + 1
        done = 0
        while done < n and ep.t + 1 < ep.seq.length:
            frame = next(ep.frames)
            ep.t += 1
            ids, pts = trk.step(frame, ep.births.get(ep.t))
            self._seen.frame()
            self._record(ep.t, ids, pts)
            ep.frame = frame
            done += 1
        return start, done

    def _score(self, start: int, count: int) -> tuple[float, int]:
        """``(fraction within threshold, gt points)`` over frames ``start .. start+count-1``."""
        ep = self._ep
        if count == 0:
            return 0.0, 0
        sl = slice(start, start + count)
        err = point_errors(ep.gt_ids, ep.gt_points[sl], ep.gt_ids, ep.tracks[sl])
        valid = ~np.isnan(err)
        n = int(valid.sum())
        if n == 0:
            return 0.0, 0
        return float((err[valid] <= self.threshold_px).sum() / n), n

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=checked_seed(seed))
        seq = self._pick(options)
        obs = self._start(seq)
        return obs, self._info(0.0, 0, 0, 0)

    def _info(self, acc: float, gt_n: int, clipped: int, frames: int) -> dict[str, Any]:
        ep = self._ep
        return {
            "sequence": ep.seq.name,
            "frame": int(ep.t),
            "length": int(ep.seq.length),
            "frames": int(frames),
            "accuracy": 100.0 * acc,
            "gt_points": int(gt_n),
            "targets": int(len(self._trk.ids)),
            "clipped": int(clipped),
            "clipped_total": int(self._clipped_total),
            "params": self.space.values(self._action),
        }

    def _apply(self, action: Any) -> int:
        if self._ep is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a, clipped = self.space.clip(action)
        self._clipped_total += clipped
        self._action = a
        self._trk.set_params(self.space.to_params(a))
        return clipped

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._ep is not None:
            self.space.clip(action)  # a bad action is named first, even after the last frame
            if self._ep.t + 1 >= self._ep.seq.length:  # as the bandit: nothing left to score
                raise gym.error.ResetNeeded("the episode is over; call reset()")
        clipped = self._apply(action)
        seen = self._seen
        seen.restart()
        start, count = self._advance(self.k_frames)
        acc, gt_n = self._score(start, count)
        ep = self._ep
        progress = ep.t / max(ep.seq.length - 1, 1)
        obs = observe(
            self._trk,
            self.space,
            self._action,
            progress,
            seen.confidences,
            seen.iterations,
            count,
        )
        terminated = ep.t + 1 >= ep.seq.length
        return obs, float(acc), bool(terminated), False, self._info(acc, gt_n, clipped, count)

    def render(self) -> np.ndarray | None:
        """The current frame (RGB) with ground truth in green and tracks in yellow."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'")
            return None
        if self._ep is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        import cv2

        from tracker.overlay import GREEN, TAIL, YELLOW, draw_points

        ep = self._ep
        img = np.ascontiguousarray(ep.frame).copy()
        s = int(ep.seq.template_size)
        draw_points(img, ep.gt_points, ep.t, s, GREEN, TAIL)
        draw_points(img, ep.tracks, ep.t, s, YELLOW, TAIL)
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        self._ep = None
        self._trk = None
        self._seen = None


class TrackerTuningBanditEnv(TrackerTuningEnv):
    """One action scores a whole sequence: the black-box version of TrackerTuning-v0.

    ## Description

    The same tracker and sequences as :class:`TrackerTuningEnv`, as a one-step episode for
    black-box tuners (Optuna, Ray Tune): the action is the static parameter set, the step
    tracks the whole sequence with it.

    ## Action Space

    As ``TrackerTuning-v0``: ``Box(-1, 1, (5,), float32)`` (8 with ``extended``), action 0 =
    the paper defaults; clipped, counted in ``info["clipped"]``.

    ## Observation Space

    As ``TrackerTuning-v0`` (13 + d entries). After ``reset`` it describes frame 0 (crowd
    size, density, spacing; no velocities or confidences yet), after the step the end of the
    sequence and the whole run's confidence and solver statistics.

    ## Rewards

    A Python float in ``[0, 1]``: the fraction of ground-truth points of frames ``1 .. T-1``
    (frame 0 is the initialisation, exact by construction) tracked within ``threshold_px``
    px. ``info["accuracy"]`` is the same in percent.

    ## Starting State

    As ``TrackerTuning-v0``: a sequence drawn with ``np_random`` or
    ``options["episode"]``; the tracker is initialised when the action arrives.

    ## Episode End

    After the one step (``terminated`` is true).

    ## Arguments

    As ``TrackerTuning-v0`` (``k_frames`` is unused).

    ## Version History

    * v0: initial version.
    """

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._ep is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._ep.t > 0:
            raise gym.error.ResetNeeded("the bandit episode is over; call reset()")
        clipped = self._apply(action)
        seen = self._seen
        seen.restart()
        start, count = self._advance(self._ep.seq.length)
        acc, gt_n = self._score(start, count)
        obs = observe(
            self._trk, self.space, self._action, 1.0, seen.confidences, seen.iterations, count
        )
        return obs, float(acc), True, False, self._info(acc, gt_n, clipped, count)


# ---------------------------------------------------------------------------- adaptive runs
class PolicyControlled:
    """``source`` with a policy setting the tracker's parameters every ``k_frames`` frames.

    Same sequence face as ``source``; its :meth:`frames` generator lets ``policy`` observe
    the tracker (:func:`observe`) and call ``set_params`` before each block of ``k_frames``
    frames, so any driver that feeds frames to ``tracker`` one by one (``Tracker.track``,
    :func:`tracker.runner.run_tracker`) tracks adaptively. ``actions`` collects the
    ``(d,)`` actions taken.

    Parameters
    ----------
    source : sequence source
    tracker : Tracker
        The tracker that will consume the frames (see :func:`make_tuned_tracker`).
    policy : object with ``predict(obs, deterministic=...) -> (action, state)``
        A stable-baselines3 model trained on ``TrackerTuning-v0`` with the same ``space``.
    space : ParamSpace
    k_frames : int
    """

    def __init__(
        self,
        source: Any,
        tracker: Tracker,
        policy: Any,
        space: ParamSpace,
        k_frames: int = 25,
        deterministic: bool = True,
    ) -> None:
        require_number("PolicyControlled", "k_frames", k_frames, lo=1, integer=True)
        self.source = source
        self.tracker = tracker
        self.policy = policy
        self.space = space
        self.k_frames = int(k_frames)
        self.deterministic = bool(deterministic)
        self.actions: list[np.ndarray] = []
        for k in ("name", "frame_rate", "width", "height", "length", "template_size"):
            setattr(self, k, getattr(source, k, None))

    def births(self) -> Any:
        return self.source.births()

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        return self.source.gt_points()

    def frames(self) -> Iterator[np.ndarray]:
        trk, space = self.tracker, self.space
        action = space.to_action(trk.params)
        n = max(int(self.length or 0), 2)
        seen = None
        reset = getattr(self.policy, "reset", None)
        if callable(reset):  # a policy with a per-sequence memory (envs.scene_aware)
            reset()
        for t, frame in enumerate(self.source.frames()):
            if t >= 2:
                seen.frame()  # the consumer tracked frame t-1 before asking for frame t
            if t >= 1 and (t - 1) % self.k_frames == 0:
                # frames 0 .. t-1 are tracked: observe them and choose the next block's params
                if seen is None:
                    seen = StepStats(trk)  # the consumer initialised on frame 0
                obs = observe(
                    trk,
                    space,
                    action,
                    (t - 1) / (n - 1),
                    seen.confidences,
                    seen.iterations,
                    seen.frames,
                )
                act, _ = self.policy.predict(obs, deterministic=self.deterministic)
                action, _ = space.clip(act)
                self.actions.append(action)
                trk.set_params(space.to_params(action))
                seen.restart()
            yield frame
