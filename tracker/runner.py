"""Run any tracker over any sequence source, time it and score it: the one implementation.

``crowdsim track``, ``crowdsim demo``, ``crowdsim compare``, the benchmarks and the tuners all
call :func:`run_tracker`. A *source* is anything with the sequence face of
:mod:`synth_data.sequence` (a MOT folder, a video file, an in-memory sequence); this module
reads it only through that face, so the tracker library never imports the data layer:

* ``template_size`` (px), ``length`` (frames);
* ``frames()`` -- iterator of (H, W, 3) uint8 BGR frames, frame 0 first;
* ``births()`` -- ``((ids0, pts0), {t: (ids, pts)})``: targets at frame 0 and later births;
* ``gt_points()`` -- ``(ids (N,), points (T, N, 2))`` px, NaN where absent (empty if none).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, get_args

import numpy as np

from tracker.base import Tracker, TrackResult
from tracker.metrics import accuracy_curve, evaluate
from tracker.registry import make_tracker

Metrics = Literal["full", "accuracy", "none"]


class SequenceLike(Protocol):
    """What the runner reads of a sequence (see :class:`synth_data.sequence.SequenceSource`)."""

    template_size: int
    length: int

    def frames(self) -> Any: ...

    def births(self) -> Any: ...

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class TrackRun:
    """One tracker over one sequence.

    Attributes
    ----------
    tracker : str
        The tracker's name.
    result : TrackResult
        ``ids (N,)`` and ``positions (T, N, 2)`` px of every track.
    report : dict
        Metrics against the ground truth (keys of :func:`tracker.metrics.evaluate`; with
        ``metrics="accuracy"`` only ``acc@5``, ``acc@15`` and ``curve``); empty without
        ground truth or with ``metrics="none"``.
    fps : float
        Frames per second of the tracking loop (frame decoding excluded; frame 0, the
        initialisation, is not counted; 0 for a one-frame run: :attr:`TrackResult.fps`).
    stage_ms : dict[str, float]
        Milliseconds per frame of each stage the tracker times.
    wall_s : float
        Wall-clock seconds of the whole run, decoding included.
    """

    tracker: str
    result: TrackResult
    report: dict[str, Any] = field(default_factory=dict)
    fps: float = 0.0
    stage_ms: dict[str, float] = field(default_factory=dict)
    wall_s: float = 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures: the report without the curve, fps, stage ms, sizes."""
        out = {k: v for k, v in self.report.items() if k != "curve"}
        out.update(
            tracker=self.tracker,
            frames=int(self.result.n_frames),
            tracks=int(len(self.result.ids)),
            fps=float(self.fps),
            stage_ms=dict(self.stage_ms),
            wall_s=float(self.wall_s),
        )
        return out


def run_tracker(
    tracker: str | Tracker,
    source: SequenceLike,
    *,
    frames: int | None = None,
    params: Any = None,
    metrics: Metrics = "full",
    strict: bool = False,
    progress: bool = False,
    prepare: Callable[[Tracker, Any], Any] | None = None,
    template_size: int | None = None,
    start: Any = None,
    births: Callable[[int, np.ndarray, np.ndarray, np.ndarray], Any] | None = None,
) -> TrackRun:
    """Track ``source`` with ``tracker`` (a registry name or a :class:`Tracker`) and score it.

    Parameters
    ----------
    tracker : str or Tracker
        Registry name (:mod:`tracker.registry`) or a ready tracker.
    source : sequence source
        Frames, initial targets and births, and (optionally) ground truth.
    frames : int, optional
        Track only the first ``frames`` frames.
    params : optional
        Parameters for a tracker given by name.
    metrics : {"full", "accuracy", "none"}
        ``"full"``: every metric (TrackEval's CLEAR, IDF1, HOTA too); ``"accuracy"``: the
        papers' accuracy curve only (fast); ``"none"``: no scoring.
    strict : bool
        Refuse track ids unknown to the ground truth (they score as false positives otherwise).
    progress : bool
        Show a progress bar with frames/s.
    prepare : callable, optional
        ``prepare(tracker, source)`` before tracking: how the application layer hands a
        tracking-by-detection tracker its detections
        (:func:`synth_data.detections.attach_detections`) without this library importing
        the data layer.
    template_size : int, optional
        Template (head) size in px; default: the source's.
    start : ``((ids0, points0), {t: (ids, points)})``, optional
        Initial targets and scheduled births instead of ``source.births()`` (e.g. heads a
        detector found in the first frame: :func:`synth_data.births.births_from_detections`).
    births : callable, optional
        ``births(t, frame, ids, points) -> (ids, points) | None``: births found while
        tracking (:class:`synth_data.births.DetectionBirths`), which then also adds the
        scheduled births of ``start`` / the source.
    """
    from crowdsim.checks import require_number

    if not all(hasattr(source, a) for a in ("frames", "births", "length", "template_size")):
        raise ValueError(
            "source must be a sequence source (synth_data.sequence.open_sequence, "
            f"InMemorySequence), got {type(source).__name__}"
        )
    if frames is not None:
        require_number("run_tracker", "frames", frames, lo=1, integer=True)
        frames = int(frames)
    if template_size is not None:
        require_number("run_tracker", "template_size", template_size, lo=2, integer=True)
    _check_metrics(metrics)
    if start is not None and not (
        isinstance(start, tuple)
        and len(start) == 2
        and isinstance(start[0], (tuple, list))
        and len(start[0]) == 2
        and isinstance(start[1], Mapping)
    ):
        raise ValueError(
            f"start must be ((ids0, points0), {{frame: (ids, points)}}), got {start!r:.80}"
        )
    trk = make_tracker(tracker, params)
    if prepare is not None:
        prepare(trk, source)
    n = source.length if frames is None else min(frames, source.length or frames)
    (ids, pts), scheduled = start if start is not None else source.births()
    scheduled = {t: b for t, b in scheduled.items() if t < n}
    if births is None:
        births = scheduled
    t0 = time.perf_counter()
    size = int(source.template_size if template_size is None else template_size)
    res = trk.track(
        itertools.islice(source.frames(), n),
        ids,
        pts,
        size,
        births=births,
        n_frames=n,
        progress=progress,
    )
    wall = time.perf_counter() - t0
    steps = max(res.n_frames - 1, 1)
    run = TrackRun(
        tracker=trk.name,
        result=res,
        wall_s=wall,
        fps=res.fps,
        stage_ms={k: 1000.0 * v / steps for k, v in res.timings.items() if k != "total"},
    )
    run.report = score(res, source, metrics, strict, getattr(trk, "id_mapping", "same"))
    return run


def _check_metrics(metrics: Any) -> None:
    if metrics not in get_args(Metrics):
        raise ValueError(f"metrics must be 'full', 'accuracy' or 'none', got {metrics!r}")


def score(
    result: TrackResult,
    source: SequenceLike,
    metrics: Metrics = "full",
    strict: bool = False,
    id_mapping: str = "same",
) -> dict[str, Any]:
    """:attr:`TrackRun.report` of ``result`` against ``source``'s ground truth over the frames
    it tracked (empty without ground truth or with ``metrics="none"``; see
    :func:`run_tracker`)."""
    _check_metrics(metrics)
    if metrics == "none":
        return {}
    gt_ids, gt_pts = source.gt_points()
    if len(gt_ids) == 0:
        return {}
    gt_pts = gt_pts[: result.n_frames]
    if metrics == "full":
        return evaluate(
            gt_ids, gt_pts, result.ids, result.positions, strict=strict, id_mapping=id_mapping
        )
    curve = accuracy_curve(
        gt_ids, gt_pts, result.ids, result.positions, strict=strict, id_mapping=id_mapping
    )
    return {
        "acc@5": float(curve[5]),
        "acc@15": float(curve[15]),
        "curve": [{"T": t, "acc": float(a)} for t, a in enumerate(curve)],
    }
