"""Simulated head detections drawn from ground truth (the tracking-by-detection reference).

A tracking-by-detection tracker (ByteTrack, OC-SORT: :mod:`tracker.baselines.detection`)
needs a detector. Instead of a learnt head detector, the reference feeds it detections drawn
from the ground truth with a controlled quality, so that the comparison isolates *association*
from *detection*:

* **misses**: every head in view is missed independently with probability ``miss_rate`` in
  every frame (``miss_rate = 0``: a perfect detector);
* **false alarms**: a Poisson number per frame with mean ``false_alarm_rate`` per 100 people
  in view in that frame (so clutter scales with the crowd), placed uniformly in the image;
* **jitter**: Gaussian noise of standard deviation ``jitter_px`` on each box centre (x and y
  independently);
* **boxes**: squares of side ``box_px`` (default: the sequence's template size) around the
  noisy centre, clipped to the image;
* **scores**: ``N(score_mean, score_std)`` for true detections and
  ``N(false_score_mean, score_std)`` for false alarms, clipped to ``[0.01, 1]`` (ByteTrack's
  two-stage association splits detections by score).

The result is one :class:`crowdsim.detections.Detections` per frame, a struct of arrays in the
``supervision`` style (``xyxy (m, 4)``, ``confidence (m,)``) plus, **for evaluation only**, the
gt id each detection came from (``-1`` for a false alarm). Trackers never read ``gt_id``.

These settings belong to the detector, not to the tracker that consumes its output: a
tracking-by-detection tracker's parameters hold only association settings, and
:func:`attach_detections` takes the detector's :class:`DetectionParams` explicitly.

Everything is vectorised over ``(T, N)`` and deterministic under ``DetectionParams.seed`` (or
an injected generator).

>>> pts = np.array([[[10.0, 10.0], [30.0, 20.0]], [[11.0, 10.0], [np.nan, np.nan]]])
>>> dets = simulate_detections([1, 2], pts, 64, 48, DetectionParams(miss_rate=0.0,
...     false_alarm_rate=0.0, jitter_px=0.0, box_px=4.0))
>>> [d.gt_id.tolist() for d in dets], dets[0].xyxy[0].tolist()
([[1, 2], [1]], [8.0, 8.0, 12.0, 12.0])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from crowdsim.checks import require_number
from crowdsim.detections import Detections

__all__ = ["DetectionParams", "Detections", "attach_detections", "simulate_detections"]


@dataclass(frozen=True, kw_only=True)
class DetectionParams:
    """Quality of the simulated head detector.

    Attributes
    ----------
    miss_rate : float
        Probability in ``[0, 1]`` that a head in view is not detected in a frame (independent
        per head and frame).
    false_alarm_rate : float
        Mean number of false alarms per frame **per 100 people in view** in that frame
        (Poisson), in ``[0, 1000]``.
    jitter_px : float
        Standard deviation (px) of the Gaussian noise on each detection's centre, in
        ``[0, 1000]``.
    box_px : float or None
        Side (px, ``[1, 4096]``) of the square boxes; ``None``: the ``template_size`` given to
        :func:`simulate_detections` (the sequence's head size).
    score_mean, score_std : float
        Mean and standard deviation of the confidence of true detections.
    false_score_mean : float
        Mean confidence of false alarms (same standard deviation).
    seed : int
        Seed of the detector's random draws (used when no generator is injected).
    """

    miss_rate: float = 0.1
    false_alarm_rate: float = 1.0
    jitter_px: float = 1.0
    box_px: float | None = None
    score_mean: float = 0.8
    score_std: float = 0.1
    false_score_mean: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        own = "DetectionParams"
        require_number(own, "miss_rate", self.miss_rate, lo=0, hi=1)
        require_number(own, "false_alarm_rate", self.false_alarm_rate, lo=0, hi=1000)
        require_number(own, "jitter_px", self.jitter_px, lo=0, hi=1000)
        if self.box_px is not None:
            require_number(own, "box_px", self.box_px, lo=1, hi=4096)
        require_number(own, "score_mean", self.score_mean, lo=0, hi=1)
        require_number(own, "score_std", self.score_std, lo=0)
        require_number(own, "false_score_mean", self.false_score_mean, lo=0, hi=1)
        require_number(own, "seed", self.seed, lo=0, hi=2**63, hi_open=True, integer=True)


def simulate_detections(
    gt_ids,
    gt_points,
    width: int,
    height: int,
    params: DetectionParams | None = None,
    *,
    template_size: float | None = None,
    rng: np.random.Generator | None = None,
) -> list[Detections]:
    """Draw simulated head detections for every frame of a ground truth.

    Parameters
    ----------
    gt_ids : (N,) int
        Ground-truth ids.
    gt_points : (T, N, 2) float
        Head centres, px, NaN where a person is absent. Only heads inside the
        ``width x height`` image can be detected.
    width, height : int
        Image size, px.
    params : DetectionParams, optional
        Detector quality (defaults: :class:`DetectionParams`).
    template_size : float, optional
        Head size (px), the box side when ``params.box_px`` is None.
    rng : numpy.random.Generator, optional
        Source of randomness; default ``numpy.random.default_rng(params.seed)``.

    Returns
    -------
    list of T :class:`Detections`
        True detections first (in gt column order), then false alarms.
    """
    p = params if params is not None else DetectionParams()
    ids = np.asarray(gt_ids, dtype=np.int64)
    pts = np.asarray(gt_points, dtype=np.float64)
    if ids.ndim != 1:
        raise ValueError(f"gt_ids must be 1-D, got shape {ids.shape}")
    if pts.ndim != 3 or pts.shape[1:] != (len(ids), 2):
        raise ValueError(f"gt_points must have shape (T, {len(ids)}, 2), got {pts.shape}")
    require_number("simulate_detections", "width", width, lo=1, integer=True)
    require_number("simulate_detections", "height", height, lo=1, integer=True)
    side = p.box_px if p.box_px is not None else template_size
    if side is None:
        raise ValueError("DetectionParams.box_px is None and no template_size was given")
    require_number("simulate_detections", "box side (box_px or template_size)", side, lo=1)
    rng = rng if rng is not None else np.random.default_rng(p.seed)
    t_len, n = pts.shape[:2]
    if t_len == 0:
        return []

    # Every draw has a fixed shape, so the stream is the same whatever the content.
    miss = rng.random((t_len, n)) < p.miss_rate
    noise = rng.normal(0.0, 1.0, (t_len, n, 2)) * p.jitter_px
    score = (
        rng.normal(p.score_mean, p.score_std, (t_len, n))
        if p.score_std > 0
        else np.full((t_len, n), float(p.score_mean))
    )
    with np.errstate(invalid="ignore"):
        inside = (
            np.isfinite(pts).all(-1)
            & (pts[..., 0] >= 0)
            & (pts[..., 0] <= width - 1)
            & (pts[..., 1] >= 0)
            & (pts[..., 1] <= height - 1)
        )
    n_fa = rng.poisson(p.false_alarm_rate * inside.sum(1) / 100.0)
    k = int(n_fa.sum())
    fa_xy = rng.uniform(0.0, 1.0, (k, 2)) * [width - 1, height - 1]
    fa_score = (
        rng.normal(p.false_score_mean, p.score_std, k)
        if p.score_std > 0
        else np.full(k, float(p.false_score_mean))
    )

    keep = inside & ~miss
    t_idx, col = np.nonzero(keep)  # row-major: grouped by frame, gt column order inside
    centres = np.concatenate([pts[t_idx, col] + noise[t_idx, col], fa_xy])
    conf = np.clip(np.concatenate([score[t_idx, col], fa_score]), 0.01, 1.0)
    gt = np.concatenate([ids[col], np.full(k, -1, np.int64)])
    frame = np.concatenate([t_idx, np.repeat(np.arange(t_len), n_fa)])
    every = Detections.from_points(centres, conf, float(side), width, height, gt_id=gt)

    order = np.argsort(frame, kind="stable")  # true detections of a frame before its alarms
    every = every[order]
    counts = np.bincount(frame, minlength=t_len)
    ends = np.cumsum(counts)
    return [every[int(e - c) : int(e)] for c, e in zip(counts, ends, strict=True)]


def attach_detections(
    tracker: Any,
    source: Any,
    params: DetectionParams | None = None,
    rng: np.random.Generator | None = None,
) -> list[Detections] | None:
    """Give a detection tracker its simulated detections for ``source``; returns them.

    The application layer calls this before :func:`tracker.runner.run_tracker` (the tracker
    library never imports this package). Trackers that take no detections (no
    ``use_detections`` method) are left alone and ``None`` is returned, so callers may call it
    for every tracker.

    Parameters
    ----------
    tracker : Tracker
        A tracker with ``use_detections(feed)`` (:mod:`tracker.baselines.detection`).
    source : sequence source
        Reads ``gt_points()``, ``width``, ``height`` and ``template_size``.
    params : DetectionParams, optional
        The simulated detector (default: ``DetectionParams()``). Detector settings belong to
        the detection source, never to the tracker's parameters.
    rng : numpy.random.Generator, optional
        Default ``numpy.random.default_rng(params.seed)``.
    """
    use = getattr(tracker, "use_detections", None)
    if use is None:
        return None
    if params is not None and not isinstance(params, DetectionParams):
        raise ValueError(
            f"attach_detections: params must be a DetectionParams, got {type(params).__name__}"
        )
    gt_ids, gt_pts = source.gt_points()
    if len(gt_ids) == 0:
        raise ValueError(
            f"sequence {getattr(source, 'name', '?')!r} has no ground truth to draw detections from"
        )
    dets = simulate_detections(
        gt_ids,
        gt_pts,
        int(source.width),
        int(source.height),
        params,
        template_size=float(source.template_size),
        rng=rng,
    )
    use(dets)
    return dets
