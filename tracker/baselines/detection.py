"""Tracking-by-detection references: ByteTrack and OC-SORT from the ``trackers`` package.

The dense-crowd trackers of this project follow heads of *known* identity from frame-0
positions and births. ByteTrack and OC-SORT instead associate per-frame *detections* into
tracks they create themselves. These adapters put them behind the same :class:`Tracker`
face, so that ``run_tracker``, ``compare`` and the benchmarks treat them like any tracker.

How detections reach the tracker
    The tracker library never draws detections itself (it must not import ``synth_data``).
    A *detection feed* is given with :meth:`DetectionTracker.use_detections` (or the
    ``detections=`` constructor argument), before :meth:`Tracker.init`:

    * a sequence indexed by the 0-based frame index (one entry per frame), or
    * a mapping ``frame index -> detections`` (a missing frame: no detections), or
    * a callable ``feed(frame_index, frame) -> detections`` (a live detector);

    where *detections* is an object with ``xyxy (m, 4)`` px and ``confidence (m,)`` in
    ``[0, 1]`` (:class:`crowdsim.detections.Detections`, ``supervision.Detections``), or a
    tuple ``(xyxy, confidence)``. For the reference rows, the application layer calls
    :func:`synth_data.detections.attach_detections(tracker, source, params)`, which draws
    detections from the source's ground truth with the simulated detector ``params``
    (``synth_data.detections.DetectionParams``: miss rate, false alarms, jitter, ...).
    Tracking without a feed raises ``ValueError`` saying so.

Parameters
    Detection settings belong to the source that produces the detections (the simulated
    detector or a trained one), not to the tracker: :class:`DetectionTrackerParams` holds only
    association settings, so "ByteTrack at miss rate 0.3" is the same tracker fed by another
    detector (``crowdsim.lab.experiments.Row.detections``).

Targets given to ``init``/``step``
    The initial targets and births are validated but not used: a tracking-by-detection
    tracker discovers people from the detections (that is what it is measured for).

Ids
    The tracks keep the ids the library allocates (0, 1, 2, ... in order of confirmation;
    unconfirmed tracks, id ``-1`` in the library, are not reported). They do not correspond to
    ground-truth ids, so the class declares ``id_mapping = "majority"``: the runner asks
    :func:`tracker.metrics.evaluate` to map each track to the ground-truth id it lies within
    :data:`tracker.metrics.SIMILARITY_SCALE` px of in most frames (majority vote) for the
    papers' acc@T, while
    MOTA, IDF1 and HOTA need no correspondence and are computed on the tracks as they are.

Positions
    A track's position in a frame is the centre of the detection box the library matched to
    it; a track with no matched detection in a frame (coasting on its Kalman prediction) is
    not reported in that frame, as in the MOTChallenge output of both methods.

Requires the optional ``trackers`` package: ``pip install 'crowdsim[detect]'``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from crowdsim.checks import require_number
from tracker.base import Tracker, as_points


def _import_trackers() -> tuple[Any, Any]:
    from crowdsim.optional import require

    trackers = require("trackers", "detect", "ByteTrack / OC-SORT")
    return trackers, require("supervision", "detect", "ByteTrack / OC-SORT")


@dataclass(frozen=True, kw_only=True)
class DetectionTrackerParams:
    """Association settings shared by ByteTrack and OC-SORT.

    The detector that feeds them is configured where the detections are made
    (``synth_data.detections.DetectionParams`` for the simulated one), not here.

    Attributes
    ----------
    lost_track_buffer : int
        Frames a track survives without a matched detection before it ends.
    minimum_consecutive_frames : int
        Matched frames before a new track is confirmed (and reported with an id).
    minimum_iou_threshold : float
        Least box IoU for a detection-track match.
    high_conf_det_threshold : float
        Score separating high- from low-confidence detections.
    """

    lost_track_buffer: int = 30
    minimum_consecutive_frames: int = 2
    minimum_iou_threshold: float = 0.1
    high_conf_det_threshold: float = 0.6

    def __post_init__(self) -> None:
        own = type(self).__name__
        require_number(
            own, "lost_track_buffer", self.lost_track_buffer, lo=0, hi=100_000, integer=True
        )
        require_number(
            own, "minimum_consecutive_frames", self.minimum_consecutive_frames, lo=1, integer=True
        )
        require_number(own, "minimum_iou_threshold", self.minimum_iou_threshold, lo=0, hi=1)
        require_number(own, "high_conf_det_threshold", self.high_conf_det_threshold, lo=0, hi=1)


@dataclass(frozen=True, kw_only=True)
class ByteTrackParams(DetectionTrackerParams):
    """ByteTrack parameters (library defaults, except the IoU threshold above).

    Attributes
    ----------
    track_activation_threshold : float
        Least score for an unmatched detection to start a new track.
    """

    track_activation_threshold: float = 0.7

    def __post_init__(self) -> None:
        super().__post_init__()
        require_number(
            "ByteTrackParams",
            "track_activation_threshold",
            self.track_activation_threshold,
            lo=0,
            hi=1,
        )


@dataclass(frozen=True, kw_only=True)
class OCSORTParams(DetectionTrackerParams):
    """OC-SORT parameters (library defaults for its own knobs).

    Attributes
    ----------
    direction_consistency_weight : float
        Weight of the observation-centric momentum (direction consistency) in association.
    delta_t : int
        Frames back used for the velocity direction.
    """

    minimum_consecutive_frames: int = 3
    minimum_iou_threshold: float = 0.3
    direction_consistency_weight: float = 0.2
    delta_t: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        require_number(
            "OCSORTParams", "direction_consistency_weight", self.direction_consistency_weight, lo=0
        )
        require_number("OCSORTParams", "delta_t", self.delta_t, lo=1, hi=100, integer=True)


DetectionFeed = Sequence[Any] | Mapping[int, Any] | Callable[[int, np.ndarray], Any]


def as_detections(dets: Any, where: str = "detections") -> tuple[np.ndarray, np.ndarray]:
    """Validate one frame's detections: ``(xyxy (m, 4) float64, confidence (m,) float64)``.

    ``dets``: an object with ``xyxy`` and ``confidence``, a ``(xyxy, confidence)`` tuple, or
    ``None`` (no detections).
    """
    if dets is None:
        return np.zeros((0, 4)), np.zeros(0)
    if hasattr(dets, "xyxy"):
        xyxy, conf = dets.xyxy, getattr(dets, "confidence", None)
    else:
        xyxy, conf = dets
    xyxy = np.asarray(xyxy, dtype=np.float64)
    if xyxy.size == 0:
        xyxy = xyxy.reshape(0, 4)
    if xyxy.ndim != 2 or xyxy.shape[1] != 4:
        raise ValueError(f"{where}: xyxy must have shape (m, 4), got {xyxy.shape}")
    conf = np.ones(len(xyxy)) if conf is None else np.asarray(conf, dtype=np.float64)
    if conf.shape != (len(xyxy),):
        raise ValueError(f"{where}: confidence must have shape ({len(xyxy)},), got {conf.shape}")
    if not (np.isfinite(xyxy).all() and np.isfinite(conf).all()):
        raise ValueError(f"{where}: boxes and scores must be finite")
    if ((conf < 0) | (conf > 1)).any():
        raise ValueError(f"{where}: confidence must lie in [0, 1]")
    if (xyxy[:, 2:] < xyxy[:, :2]).any():
        raise ValueError(f"{where}: boxes must have x_max >= x_min and y_max >= y_min")
    return xyxy, conf


class DetectionTracker(Tracker):
    """A ``trackers`` library tracker fed with a detection feed (module docstring).

    Subclasses set :attr:`library_class` (attribute name in ``trackers``) and implement
    :meth:`_library_kwargs`.
    """

    library_class: ClassVar[str] = ""
    id_mapping: ClassVar[str] = "majority"
    """How the runner relates this tracker's ids to the ground truth (see module docstring)."""

    def __init__(
        self, params: DetectionTrackerParams | None = None, detections: DetectionFeed | None = None
    ) -> None:
        super().__init__()
        cls = self.params_class
        self.params = params if params is not None else cls()
        self.feed: DetectionFeed | None = None
        self._impl: Any = None
        self._sv: Any = None
        if detections is not None:
            self.use_detections(detections)

    # ------------------------------------------------------------------ detections
    def use_detections(self, feed: DetectionFeed) -> None:
        """Set the detection feed (module docstring) for the next sequence."""
        if not (callable(feed) or isinstance(feed, (Sequence, Mapping))) or isinstance(
            feed, (str, bytes)
        ):
            raise ValueError(
                "detections must be a sequence or mapping indexed by frame, or a "
                f"callable(frame_index, frame); got {type(feed).__name__}"
            )
        self.feed = feed

    def _frame_detections(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, feed = self.frame_index, self.feed
        if callable(feed) and not isinstance(feed, (Sequence, Mapping)):
            dets = feed(t, frame)
        elif isinstance(feed, Mapping):
            dets = feed.get(t)
        else:
            if t >= len(feed):
                raise ValueError(
                    f"{self.name}: the detections cover {len(feed)} frames; frame {t} has none"
                )
            dets = feed[t]
        return as_detections(dets, f"{self.name}: detections of frame {t}")

    # ------------------------------------------------------------------ Tracker face
    def init(self, frame: np.ndarray, ids, points, template_size: int) -> None:
        """Start a sequence at ``frame``; the given targets are validated, not used."""
        if self.feed is None:
            raise ValueError(
                f"tracker {self.name!r} needs detections: call "
                "synth_data.detections.attach_detections(tracker, source) or "
                "tracker.use_detections(feed) before tracking"
            )
        as_points(ids, points, "initial targets")
        super().init(frame, np.zeros(0, np.int64), np.zeros((0, 2)), template_size)
        self._update(frame)

    def step(self, frame: np.ndarray, births=None) -> tuple[np.ndarray, np.ndarray]:
        """Associate ``frame``'s detections; returns the tracks matched in this frame."""
        if self.frame_shape is None:
            raise ValueError("call init() before step()")
        frame = self._check_frame(frame)
        if births is not None:
            as_points(*births, what="births")
        self.frame_index += 1
        t0 = time.perf_counter()
        self._update(frame)
        self._tick("total", t0)
        return self.ids.copy(), self.points.copy()

    def _update(self, frame: np.ndarray) -> None:
        t0 = time.perf_counter()
        xyxy, conf = self._frame_detections(frame)
        t0 = self._tick("detections", t0)
        out = self._impl.update(self._sv.Detections(xyxy=xyxy, confidence=conf))
        self._tick("associate", t0)
        tid = np.asarray(out.tracker_id, dtype=np.int64).reshape(-1)
        ok = tid >= 0
        boxes = np.asarray(out.xyxy, dtype=np.float64).reshape(-1, 4)[ok]
        self.ids = tid[ok]
        self.points = 0.5 * (boxes[:, :2] + boxes[:, 2:])
        conf_out = out.confidence if out.confidence is not None else np.ones(len(tid))
        self.confidence = np.asarray(conf_out, dtype=np.float64).reshape(-1)[ok]
        self.lost = np.zeros(len(self.ids), np.int64)

    # ------------------------------------------------------------------ hooks
    def _library_kwargs(self) -> dict[str, Any]:
        raise NotImplementedError

    def _init(self, frame: np.ndarray) -> None:
        trackers, self._sv = _import_trackers()
        self._impl = getattr(trackers, self.library_class)(**self._library_kwargs())

    def _apply_params(self, old: Any, changed: frozenset[str]) -> None:
        # Rebuilding the library object would lose its tracks: set its attributes instead.
        kw = self._library_kwargs()
        for name in changed:
            if name == "lost_track_buffer":
                self._impl.maximum_frames_without_update = (
                    self._impl._compute_maximum_frames_without_update(
                        lost_track_buffer=kw["lost_track_buffer"], frame_rate=30.0
                    )
                )
                self._impl.maximum_time_without_update = kw["lost_track_buffer"] / 30.0
            elif name in kw:
                setattr(self._impl, name, kw[name])

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        """Given targets are not used (tracks come from detections)."""

    def _remove(self, keep: np.ndarray) -> None:
        """Tracks end inside the library (``lost_track_buffer``)."""

    def _step(self, frame: np.ndarray) -> np.ndarray:  # pragma: no cover - step() overrides
        raise NotImplementedError("detection trackers update in step()")


class ByteTrackTracker(DetectionTracker):
    """ByteTrack (Zhang et al., ECCV 2022) from ``trackers``, on a detection feed."""

    name = "bytetrack"
    params_class = ByteTrackParams
    library_class = "ByteTrackTracker"

    def _library_kwargs(self) -> dict[str, Any]:
        p = self.params
        return dict(
            lost_track_buffer=int(p.lost_track_buffer),
            frame_rate=30.0,
            track_activation_threshold=float(p.track_activation_threshold),
            minimum_consecutive_frames=int(p.minimum_consecutive_frames),
            minimum_iou_threshold=float(p.minimum_iou_threshold),
            high_conf_det_threshold=float(p.high_conf_det_threshold),
        )


class OCSORTTracker(DetectionTracker):
    """OC-SORT (Cao et al., CVPR 2023) from ``trackers``, on a detection feed."""

    name = "ocsort"
    params_class = OCSORTParams
    library_class = "OCSORTTracker"

    def _library_kwargs(self) -> dict[str, Any]:
        p = self.params
        return dict(
            lost_track_buffer=int(p.lost_track_buffer),
            frame_rate=30.0,
            minimum_consecutive_frames=int(p.minimum_consecutive_frames),
            minimum_iou_threshold=float(p.minimum_iou_threshold),
            direction_consistency_weight=float(p.direction_consistency_weight),
            high_conf_det_threshold=float(p.high_conf_det_threshold),
            delta_t=int(p.delta_t),
        )
