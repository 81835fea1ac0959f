"""The contract every point tracker implements (SPEC §2, "Tracker I/O").

A tracker follows head points of known identity through a sequence of frames:

* :meth:`Tracker.init` -- first frame, initial targets ``(id, x, y)`` and the template size;
* :meth:`Tracker.step` -- one more frame, optionally with *births* (targets that enter the
  scene in this frame, given with their position in it); returns the active targets;
* :meth:`Tracker.track` -- the whole sequence, returning a :class:`TrackResult` with
  ``(T, N, 2)`` pixel tracks;
* :meth:`Tracker.set_params` -- new parameters between frames (what the tuning environments
  and adaptive policies do); every changed field takes effect from the next frame, and fields
  listed in :attr:`Tracker.fixed_params` are refused once a sequence has started.

Tracks end in two ways (people leave the view, and real annotated trajectories also end
inside it):

* **leaving**: the target's next-frame prediction lies outside the image;
* **lost evidence**: the tracker's confidence in the target (``confidence``, set by each
  tracker's ``_step``: the appearance score of the chosen location) stayed below
  ``params.lost_ratio`` times the target's own usual confidence (``conf_ref``, a running mean
  of its confident frames) for ``params.max_lost`` frames in a row (``max_lost = 0``:
  never). Relative, because how confident a tracker is depends on the sequence: on the
  calibrated ucf9 seq9 an absolute floor of 0.3 ended most of BQP's correct tracks (acc@15
  24.3 -> 6.1 %), a ratio of 0.4 costs 0.6 points there and still ends the tracks of people
  who vanish (MOTA on the uncalibrated seq8: 96.4 -> 98.1 %).
  Without this, a track runs on where its person vanished and every such frame counts as a
  false positive in MOTA, IDF1 and HOTA (the papers' accuracy metric is unaffected).

Camera-motion compensation (beyond both papers, whose cameras are static): when a tracker's
parameters say ``cmc = True``, :meth:`Tracker.step` first estimates the global motion ``A``
(a 2x3 similarity, :class:`tracker.cmc.MotionCompensator`) from the previous frame to this
one, then moves the tracker's state with the camera before the tracker's own ``_step``
searches: ``points -> A p`` (so every search window and constant-velocity prediction built on
them moves too) and each attribute named in :attr:`Tracker.camera_state` (velocities and
other motion state). A velocity a tracker then measures as ``new - points`` is the motion
relative to the ground. A frame that gives no estimate (blank, constant) moves nothing and is
counted in :meth:`Tracker.stats`. The estimate's seconds are the ``"cmc"`` stage of
``timings``. With ``cmc = False`` nothing of this runs.

One contract check (:func:`tracker.testing.check_tracker_contract`) runs over every
registered implementation.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from crowdsim.checks import whole_numbers
from tracker.cmc import IDENTITY, CMCParams, MotionCompensator, warp_points, warp_vectors
from tracker.threads import check_threads, using_threads

CONF_REF_RATE: float = 0.1
"""Weight of the newest frame in a target's running-mean confidence ``conf_ref``."""

Births = tuple[np.ndarray, np.ndarray]
"""``(ids (m,) int, points (m, 2) float px)`` of targets entering in a frame."""
LiveBirths = Callable[[int, np.ndarray, np.ndarray, np.ndarray], "Births | None"]
"""``births(t, frame, ids, points) -> (ids, points) | None``: births found while tracking."""


MAX_TEMPLATE_PX = 256
"""Largest template (head) size a tracker takes, px: the appearance models hold
``(n, 3, w, w)`` arrays per target with ``w`` about twice the template; at 256 px (BQP's
default search region, ``w = 512``) the KCF models alone take 4.2 MB a target, 3.9 GiB for
1000 targets (heads in crowd footage span 6-40 px)."""


@dataclass
class TrackResult:
    """Tracks of a whole sequence.

    Attributes
    ----------
    ids : (N,) int64
        Every target id ever tracked, in order of first appearance.
    positions : (T, N, 2) float64
        Pixel position of target ``ids[n]`` in frame ``t`` (0-based), NaN where not tracked.
    timings : dict[str, float]
        Total seconds per stage (tracker-specific keys, plus ``"total"``).
    """

    ids: np.ndarray
    positions: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def fps(self) -> float:
        """Frames per second of the tracking loop: the frames after the first (the
        initialisation) over the seconds their steps took, frame decoding excluded, as
        :attr:`tracker.runner.TrackRun.fps`; 0 when no frame was tracked."""
        total = self.timings.get("total", 0.0)
        return (self.n_frames - 1) / total if self.n_frames > 1 and total > 0 else 0.0


def as_points(ids, points, what: str = "targets") -> tuple[np.ndarray, np.ndarray]:
    """Validate ``ids (n,)`` and ``points (n, 2)``: unique integers, finite pixels."""
    ids = np.asarray(ids)
    points = np.asarray(points, dtype=np.float64)
    if ids.size == 0:
        if points.size:  # points without ids would be dropped in silence
            raise ValueError(f"{what}: {len(points)} points but no ids")
        return np.zeros(0, np.int64), np.zeros((0, 2))
    if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
        if ids.ndim == 1 and np.issubdtype(ids.dtype, np.floating) and whole_numbers(ids):
            if (np.abs(ids) >= 2.0**63).any():  # would wrap to another id
                raise ValueError(f"{what}: id {ids[np.abs(ids) >= 2.0**63][0]:g} is beyond int64")
            ids = ids.astype(np.int64)
        else:
            raise ValueError(
                f"{what}: ids must be a 1-D integer array, got {ids.dtype} {ids.shape}"
            )
    if ids.dtype.kind == "u" and (ids > np.iinfo(np.int64).max).any():
        raise ValueError(f"{what}: id {ids[ids > np.iinfo(np.int64).max][0]} is beyond int64")
    if points.shape != (len(ids), 2):
        raise ValueError(f"{what}: points must have shape ({len(ids)}, 2), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError(f"{what}: points must be finite pixels")
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"{what}: duplicate ids {uniq[counts > 1][:5].tolist()}")
    return ids.astype(np.int64), points.copy()  # never the caller's array: _add may keep it


def _checked_births(births: Any, n_frames: int | None) -> dict[int, Births]:
    """``births`` as ``{frame: (ids, points)}``, each checked: frames whole numbers from 0
    (below ``n_frames`` when given), values pairs of ids and points (:func:`as_points`)."""
    if births is None:
        return {}
    if not isinstance(births, Mapping):
        raise ValueError(
            f"births must be a mapping frame -> (ids, points) or a callable, got "
            f"{type(births).__name__}"
        )
    out: dict[int, Births] = {}
    for t, b in births.items():
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or t < 0:
            raise ValueError(f"births: frame {t!r} is not a frame index (0, 1, 2, ...)")
        if n_frames is not None and t >= n_frames:
            raise ValueError(f"births: frame {t} is beyond the sequence's {n_frames} frames")
        if not (isinstance(b, (tuple, list)) and len(b) == 2):
            raise ValueError(f"births at frame {t}: expected (ids, points), got {b!r:.60}")
        out[int(t)] = as_points(*b, what=f"births at frame {t}")
    return out


class Tracker(ABC):
    """Point tracker of many targets (struct of arrays: one row per active target).

    Subclasses implement :meth:`_init`, :meth:`_step`, :meth:`_add` and :meth:`_remove`; the
    base class checks inputs, handles births and terminations and keeps ``ids``/``points``.

    What a tracker of your own needs besides those four, to pass
    :func:`tracker.testing.check_tracker_contract` (``tracker/baselines/ncc.py`` is a short
    example of all of it):

    * a constructor ``__init__(self, params=None)`` that calls ``super().__init__()`` and
      sets ``self.params`` (an instance of :attr:`params_class`, defaults when ``None``);
    * ``max_lost`` and ``lost_ratio`` fields in the params: the base class ends a track after
      ``max_lost`` frames whose confidence stays below ``lost_ratio`` times the target's usual
      one, which is how tracks of people who vanish in view end;
    * ``self.confidence`` (``(n,)``) set by :meth:`_step` for the targets it moved;
    * :meth:`_predicted` with a motion model when the tracker has one: a track ends when its
      predicted point leaves the image (the default predicts no motion, so a target at the
      edge that walks out is ended by its confidence instead).

    Attributes
    ----------
    ids : (n,) int64
        Active target ids.
    points : (n, 2) float64
        Their current positions, pixels.
    confidence : (n,) float64
        Confidence of the last update of each target (tracker-specific scale; 1 at birth).
    lost : (n,) int64
        Frames in a row each target's confidence has been below ``params.lost_ratio`` times
        its ``conf_ref``.
    conf_ref : (n,) float64
        Each target's usual confidence: a running mean (weight :data:`CONF_REF_RATE`) over
        the frames it was not low in; NaN until its first tracked frame.
    timings : dict[str, float]
        Seconds spent per stage since :meth:`init`.
    threads : int or None
        Threads of the tracker's parallel kernels and FFTs during :meth:`init` and
        :meth:`step` (:mod:`tracker.threads`); ``None`` (default) keeps numba's setting.
        Tracks do not depend on it. An execution setting, not a parameter: it is never
        tuned, recorded in params files or changed by :meth:`set_params`.
    compensator : MotionCompensator or None
        The camera-motion estimate while ``params.cmc`` is on (:mod:`tracker.cmc`).
    cmc_settings : CMCParams or None
        Its settings besides the method (``params.cmc_method`` wins); ``None`` (default): the
        defaults. Set before :meth:`init` (``benchmarks/cmc_fps.py`` compares corner counts).
        Not a parameter: never tuned or recorded in params files, though it changes the
        estimate (and so the tracks).
    """

    name: str = "tracker"
    params_class: ClassVar[type | None] = None
    """The frozen parameter dataclass of this tracker (``None``: it has no parameters)."""
    fixed_params: ClassVar[frozenset[str]] = frozenset()
    """Fields of :attr:`params_class` that cannot change once a sequence has started."""
    id_mapping: ClassVar[str] = "same"
    """How the runner relates this tracker's ids to the ground truth: ``"same"`` (it follows
    the given targets) or ``"majority"`` (it names its own tracks; :mod:`tracker.metrics`)."""
    position_tolerance_px: ClassVar[float] = 0.0
    """How far a tracked point may lie from the truth on the contract's exact scenes
    (:func:`tracker.testing.check_tracker_contract`); 0 for a tracker that recovers integer
    motion on textured ground exactly."""
    _threads: int | None = None
    parallel_min_targets: ClassVar[int] = 300
    """Below this many active targets a frame runs on one thread whatever ``threads`` says:
    on small frames starting the threads costs more than they gain (100 targets: 180 frames/s
    on one thread, 143 on two). Tracks do not depend on it."""
    camera_state: ClassVar[Mapping[str, str]] = MappingProxyType({})
    """Attributes moved with the camera when ``params.cmc`` is on, besides ``points``: name ->
    ``"points"`` (``(..., 2)`` pixel positions, ``p -> A p``), ``"vectors"`` (``(..., 2)``
    displacements, turned and scaled by ``A``'s linear part) or ``"lengths"`` (``(...)``
    distances, scaled by ``A``'s zoom)."""

    def __init__(self) -> None:
        self.params: Any = None
        self.ids = np.zeros(0, np.int64)
        self.points = np.zeros((0, 2))
        self.confidence = np.zeros(0)
        self.lost = np.zeros(0, np.int64)
        self.conf_ref = np.zeros(0)
        self.template_size = 0
        self.frame_shape: tuple[int, ...] | None = None
        self.frame_index = 0
        self.timings: dict[str, float] = {}
        self._seen: set[int] = set()
        self.compensator: MotionCompensator | None = None
        self.cmc_settings: CMCParams | None = None
        self._last_frame: np.ndarray | None = None
        self._threads: int | None = None

    @property
    def threads(self) -> int | None:
        return self._threads

    @threads.setter
    def threads(self, value: int | None) -> None:
        self._threads = None if value is None else check_threads(value, "threads")

    # ------------------------------------------------------------------ public API
    def init(self, frame: np.ndarray, ids, points, template_size: int) -> None:
        """Start tracking ``ids`` at ``points`` ``(n, 2)`` px in ``frame`` (H, W, 3) uint8."""
        cls = self.params_class
        if cls is not None and not isinstance(self.params, cls):
            raise ValueError(
                f"tracker {self.name!r} takes {cls.__name__}, got {type(self.params).__name__} "
                "(build the parameters with tracker.registry.make_tracker or the dataclass)"
            )
        frame = self._check_frame(frame, first=True)
        if not (
            isinstance(template_size, (int, np.integer)) and 2 <= template_size <= MAX_TEMPLATE_PX
        ):
            raise ValueError(
                f"template_size must be an integer in [2, {MAX_TEMPLATE_PX}] px, got "
                f"{template_size!r}"
            )
        ids, points = as_points(ids, points, "initial targets")
        small = len(ids) < self.parallel_min_targets
        with using_threads(1 if small else self._threads):
            self._start(frame, ids, points, int(template_size))

    def _start(self, frame: np.ndarray, ids: np.ndarray, points: np.ndarray, size: int) -> None:
        self.template_size = size
        self.frame_index = 0
        self.timings = {}
        self._seen = set()
        self.ids = np.zeros(0, np.int64)
        self.points = np.zeros((0, 2))
        self.confidence = np.zeros(0)
        self.lost = np.zeros(0, np.int64)
        self.conf_ref = np.zeros(0)
        self._last_frame = frame
        self._start_compensator()
        self._init(frame)
        self._add_targets(frame, ids, points)

    def step(
        self, frame: np.ndarray, births: Births | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Track the active targets into ``frame``, then add ``births``.

        Returns
        -------
        ids : (n,) int64 and points : (n, 2) float64 of the targets active after the frame.
        """
        if self.frame_shape is None:
            raise ValueError("call init() before step()")
        frame = self._check_frame(frame)
        if births is not None:
            b_ids, b_pts = as_points(*births, what="births")
            self._check_new_targets(b_ids, b_pts)  # before the frame changes any state
        self.frame_index += 1
        t0 = time.perf_counter()
        small = len(self.ids) < self.parallel_min_targets
        with using_threads(1 if small else self._threads):
            if self.compensator is not None:
                self._compensate(frame)
            if len(self.ids):
                self.points = self._stepped(frame)
                self._terminate()
            if births is not None and len(b_ids):
                self._add_targets(frame, b_ids, b_pts)
        self._last_frame = frame
        self._tick("total", t0)
        return self.ids.copy(), self.points.copy()

    def track(
        self,
        frames: Iterable[np.ndarray],
        ids,
        points,
        template_size: int,
        births: Mapping[int, Births] | LiveBirths | None = None,
        n_frames: int | None = None,
        progress: bool = False,
    ) -> TrackResult:
        """Track a whole sequence.

        Parameters
        ----------
        frames : iterable of (H, W, 3) uint8
            Frame 0 is the initialisation frame.
        ids, points : (n,) int, (n, 2) float
            Targets at frame 0.
        template_size : int
            Template (head) size, px.
        births : mapping frame index (0-based) -> (ids, points), or callable, optional
            Targets entering at that frame, at their position in that frame. A callable
            ``births(t, frame, ids, points)`` is asked at every frame ``t >= 1`` with the
            targets' ids and positions in frame ``t - 1`` (births found while tracking, e.g.
            by a head detector: :class:`synth_data.births.DetectionBirths`); it returns
            ``(ids, points)`` or ``None``.
        n_frames : int, optional
            Number of frames (for the progress bar and to preallocate).
        progress : bool
            Show a tqdm progress bar with frames/s.
        """
        live = births if callable(births) else None
        births = {} if live is not None else _checked_births(births, n_frames)
        rows: list[tuple[np.ndarray, np.ndarray]] = []
        it = iter(frames)
        bar = None
        if progress:
            from crowdsim.progress import progress_bar

            bar = progress_bar(total=n_frames, unit="frame", desc=self.name)
        try:
            first = next(it)
        except StopIteration:
            raise ValueError("the sequence has no frames") from None
        b0 = births.pop(0, None)
        if b0 is not None:
            b_ids, b_pts = as_points(*b0, what="births at frame 0")
            ids, points = as_points(ids, points, "initial targets")
            ids = np.concatenate([ids, b_ids])
            points = np.concatenate([points, b_pts])
        self.init(first, ids, points, template_size)
        rows.append((self.ids.copy(), self.points.copy()))
        if bar is not None:
            bar.update(1)
        for t, frame in enumerate(it, start=1):
            born = live(t, frame, self.ids, self.points) if live is not None else births.get(t)
            rows.append(self.step(frame, born))
            if bar is not None:
                bar.update(1)
                total = self.timings.get("total", 0.0)
                if total > 0:
                    bar.set_postfix(fps=f"{t / total:.1f}", targets=len(self.ids), refresh=False)
        if bar is not None:
            bar.close()
        late = sorted(t for t in births if t >= len(rows))
        if late:  # never reached: the sequence was shorter than its births say
            raise ValueError(
                f"births at frames {late[:5]} are beyond the sequence's {len(rows)} frames"
            )
        result = self._assemble(rows)
        result.timings = dict(self.timings)
        return result

    def set_params(self, params: Any) -> None:
        """Replace the tracker's parameters; changes take effect from the next frame.

        Before :meth:`init` any change is accepted. During a sequence, a change of a field in
        :attr:`fixed_params` raises ``ValueError`` naming the fields; every other changed
        field is applied through :meth:`_apply_params`.

        Parameters
        ----------
        params : instance of :attr:`params_class`
        """
        cls = self.params_class
        if cls is None:
            raise ValueError(f"tracker {self.name!r} has no parameters to set")
        if not isinstance(params, cls):
            raise ValueError(
                f"tracker {self.name!r} takes {cls.__name__}, got {type(params).__name__}"
            )
        old = self.params
        changed = [
            f.name for f in fields(params) if getattr(params, f.name) != getattr(old, f.name)
        ]
        if self.frame_shape is None or not changed:
            self.params = params
            return
        fixed = [n for n in changed if n in self.fixed_params]
        if fixed:
            raise ValueError(
                f"tracker {self.name!r}: {', '.join(fixed)} cannot change in the "
                "middle of a sequence (set it before init())"
            )
        self.params = params
        self._apply_params(old, frozenset(changed))
        if {"cmc", "cmc_method"} & set(changed):
            self._start_compensator()

    def stats(self) -> dict[str, float]:
        """Counters of the sequence so far, for reports and tuners (``{}`` when none).

        With ``params.cmc``: ``cmc_frames``, ``cmc_failures`` (frames whose camera motion
        fell back to the identity) and ``cmc_ms`` (ms per frame of the estimate), from
        :meth:`tracker.cmc.MotionCompensator.stats`.
        """
        return {} if self.compensator is None else self.compensator.stats()

    # ------------------------------------------------------------------ subclass hooks
    def _apply_params(self, old: Any, changed: frozenset[str]) -> None:  # noqa: B027
        """Make the ``changed`` fields of ``self.params`` (was ``old``) take effect.

        The default does nothing: right for trackers that read ``self.params`` every frame.
        Trackers that copied a parameter into their state at :meth:`init` override this.
        """

    @abstractmethod
    def _init(self, frame: np.ndarray) -> None:
        """Reset the tracker's state for a new sequence (no targets yet)."""

    @abstractmethod
    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        """Append models for new targets at ``points`` ``(m, 2)`` (``ids`` not yet extended)."""

    @abstractmethod
    def _remove(self, keep: np.ndarray) -> None:
        """Keep only the targets with indices ``keep`` (``ids``/``points`` handled by base)."""

    @abstractmethod
    def _step(self, frame: np.ndarray) -> np.ndarray:
        """Return the new ``(n, 2)`` positions of the active targets in ``frame``."""

    def _predicted(self) -> np.ndarray:
        """``(n, 2)`` next-frame prediction used to decide that a target leaves the image."""
        return self.points

    def motion(self) -> np.ndarray:
        """``(n, 2)`` each active target's motion, px per frame, as the tracker models it:
        what its prediction adds to the points (:meth:`_predicted`; zeros without a motion
        model). The tuning environment's speed and flow observations read it."""
        return np.asarray(self._predicted(), np.float64) - self.points

    def _stepped(self, frame: np.ndarray) -> np.ndarray:
        """:meth:`_step`'s positions, checked: ``(n, 2)`` real numbers, as float64."""
        new = self._step(frame)
        n = len(self.ids)
        got = np.asarray(new) if new is not None else None
        if got is None or got.shape != (n, 2) or got.dtype.kind not in "iuf":
            what = "None" if got is None else f"{got.dtype} {got.shape}"
            raise ValueError(
                f"{type(self).__name__}._step returned {what}; expected ({n}, 2) positions of "
                "the active targets, pixels"
            )
        return got.astype(np.float64, copy=False)

    # ------------------------------------------------------------------ camera motion
    def _start_compensator(self) -> None:
        """A fresh :class:`MotionCompensator` when ``params.cmc`` (else none), shown the last
        frame, so that switching it on mid-sequence acts as if it had been on from the start."""
        self.compensator = None
        if not getattr(self.params, "cmc", False):
            return
        base = self.cmc_settings if self.cmc_settings is not None else CMCParams()
        self.compensator = MotionCompensator(replace(base, method=self.params.cmc_method))
        if self._last_frame is not None:
            self.compensator.estimate(self._last_frame)

    def _compensate(self, frame: np.ndarray) -> None:
        """Estimate the camera's motion into ``frame`` and move the state with it."""
        t0 = time.perf_counter()
        cmc = self.compensator
        a = cmc.estimate(
            frame, exclude=self.points, exclude_px=cmc.params.exclude * self.template_size
        )
        if not np.array_equal(a, IDENTITY):
            self.points = warp_points(a, self.points)
            zoom = float(np.sqrt(abs(np.linalg.det(a[:, :2]))))
            for name, kind in self.camera_state.items():
                v = np.asarray(getattr(self, name), dtype=np.float64)
                if kind == "points":
                    v = warp_points(a, v).reshape(v.shape)
                elif kind == "vectors":
                    v = warp_vectors(a, v).reshape(v.shape)
                else:
                    v = v * zoom
                setattr(self, name, v)
        self._camera_moved(a)
        self._tick("cmc", t0)

    def _camera_moved(self, a: np.ndarray) -> None:  # noqa: B027
        """Hook after the state moved with the camera (``a``: the ``(2, 3)`` transform, the
        identity on a failed estimate); the default does nothing."""

    # ------------------------------------------------------------------ helpers
    def _tick(self, stage: str, t0: float) -> float:
        now = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + (now - t0)
        return now

    def _check_frame(self, frame: np.ndarray, first: bool = False) -> np.ndarray:
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(
                f"frames must be (H, W, 3) uint8 BGR images, got {frame.shape} {frame.dtype}"
            )
        if first:
            self.frame_shape = frame.shape
        elif frame.shape != self.frame_shape:
            raise ValueError(
                f"frame {self.frame_index + 1} has size {frame.shape[1]}x"
                f"{frame.shape[0]}, expected {self.frame_shape[1]}x"
                f"{self.frame_shape[0]} (mismatched frame sizes)"
            )
        return frame

    def _add_targets(self, frame: np.ndarray, ids: np.ndarray, points: np.ndarray) -> None:
        if len(ids) == 0:
            return
        self._check_new_targets(ids, points)
        self._seen.update(int(i) for i in ids)
        self._add(frame, points)
        self.ids = np.concatenate([self.ids, ids])
        self.points = np.concatenate([self.points, points])
        self.confidence = np.concatenate([self.confidence, np.ones(len(ids))])
        self.lost = np.concatenate([self.lost, np.zeros(len(ids), np.int64)])
        self.conf_ref = np.concatenate([self.conf_ref, np.full(len(ids), np.nan)])

    def _check_new_targets(self, ids: np.ndarray, points: np.ndarray) -> None:
        """``ValueError`` for ids used before in this sequence or points outside the image."""
        again = [int(i) for i in ids if int(i) in self._seen]
        if again:
            raise ValueError(
                f"target ids {again[:5]} were already used in this sequence (ids are never reused)"
            )
        h, w = self.frame_shape[:2]
        inside = (
            (points[:, 0] >= 0)
            & (points[:, 0] <= w - 1)
            & (points[:, 1] >= 0)
            & (points[:, 1] <= h - 1)
        )
        if not inside.all():
            bad = np.flatnonzero(~inside)[0]
            raise ValueError(
                f"target id {int(ids[bad])} starts outside the {w}x{h} image at "
                f"({points[bad, 0]:.1f}, {points[bad, 1]:.1f})"
            )

    def _terminate(self) -> None:
        """End the tracks that leave the image or whose evidence is gone (module docstring)."""
        h, w = self.frame_shape[:2]
        p = self._predicted()
        keep = (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
        max_lost = int(getattr(self.params, "max_lost", 0) or 0)
        if max_lost > 0:
            conf = np.asarray(self.confidence, np.float64)
            ref = np.where(np.isnan(self.conf_ref), conf, self.conf_ref)
            low = conf < self.params.lost_ratio * ref
            self.lost = np.where(low, self.lost + 1, 0)
            keep &= self.lost < max_lost
            self.conf_ref = np.where(low, ref, (1 - CONF_REF_RATE) * ref + CONF_REF_RATE * conf)
        if keep.all():
            return
        keep = np.flatnonzero(keep)
        self._remove(keep)
        self.ids = self.ids[keep]
        self.points = self.points[keep]
        self.confidence = self.confidence[keep]
        self.lost = self.lost[keep]
        self.conf_ref = self.conf_ref[keep]

    @staticmethod
    def _assemble(rows: list[tuple[np.ndarray, np.ndarray]]) -> TrackResult:
        all_ids = np.concatenate([r[0] for r in rows]) if rows else np.zeros(0, np.int64)
        uniq, first = np.unique(all_ids, return_index=True)
        ids = uniq[np.argsort(first)]
        col_of_sorted = np.argsort(np.argsort(first))  # column of uniq[j]
        pos = np.full((len(rows), len(ids), 2), np.nan)
        for t, (r_ids, r_pts) in enumerate(rows):
            if len(r_ids):
                pos[t, col_of_sorted[np.searchsorted(uniq, r_ids)]] = r_pts
        return TrackResult(ids=ids.astype(np.int64), positions=pos)
