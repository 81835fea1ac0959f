"""Classical head-point detector: scale-normalised Laplacian-of-Gaussian peaks (the baseline).

The learnt head detector of :mod:`tracker.detect` is compared against this one, on the same
annotated frames (:func:`fit_threshold` fits its one free setting on the learnt detector's
training data). Seen from above, a head is a disc of hair (dark, sometimes light grey, or a
coloured hat) with a skin crescent at the front, over shoulders in clothing colours and a
soft shadow to the lower right, on a mid-grey ground. The detector:

1. converts the BGR frame to grey (float32, grey levels 0..255);
2. computes the scale-normalised LoG response (Lindeberg 1998)::

       R = sigma^2 * Laplacian(G_sigma * I) / NORM,                                  (1)
       sigma = D / (2 sqrt 2),  D = head_fraction * template_px                      (2)

   ``sigma = r / sqrt 2`` is the scale at which the normalised LoG of a disc of radius
   ``r = D / 2`` peaks, ``D`` the head's diameter; ``NORM = 2 / e`` is that peak per grey
   level of contrast, so a head-sized disc ``c`` grey levels darker than its surround gives
   ``R ~ c`` at its centre (``cv2.GaussianBlur``, then the 4-neighbour ``cv2.Laplacian``);
3. applies the polarity (``"dark"``: ``R``, heads darker than their surround; ``"bright"``:
   ``-R``; ``"both"``: ``|R|``);
4. takes the local maxima over a ``(2d + 1)``-pixel square window, ``d = min_distance_px``
   (``cv2.dilate``), at or above ``threshold``; of exact ties inside one window (a
   plateau) the first in raster order is kept;
5. refines each peak to sub-pixel with a parabola through the 3 responses along x and the 3
   along y (offset clamped to +-0.5 px);
6. scores each peak ``s = R / (R + threshold)`` in ``[0.5, 1)``: 0.5 at the threshold,
   2/3 at twice the threshold, so a score reads as "how far above the fitted threshold".

Design choices, measured: F1 at 5 px, threshold fitted (:func:`fit_threshold`) on seeds
``seed + 100 .. 102`` of a spec, 8 frames each, evaluated on its first 20 frames at its own
seed (``camera_output=True`` frames); counts pooled over ``ucf9`` seq1-9, and over the same
nine scenes with the default appearance (``AppearanceParams(template_px=...)``, no shake):

==========================  ============  ======================
setting                     ``ucf9`` F1   default-look F1
==========================  ============  ======================
head scale, ``"both"``      0.722         0.854 (default setting)
head scale, ``"dark"``      0.711         0.801
template scale, ``"both"``  0.454         0.725
==========================  ============  ======================

Per sequence (head scale, ``"both"``): ``ucf9`` 0.53 (seq9) to 0.86 (seq2), default look
0.74 (seq2) to 0.97 (seq8); mean localisation error 0.5-3.3 px.

* **Scale.** ``template_px`` is a sequence's template size (shoulder width, the renderer's
  ``template_px``); the head's diameter is ``HEAD_FRACTION = 0.42`` of it (twice the
  renderer's head radius 0.21). At the template's scale the blob is the whole person with
  shoulders and shadow, whose centre is off the head (mean error ~3 px on ``ucf9``).
* **Polarity.** ``"both"``: hair is mostly dark, but the default look's hair colours include
  a light grey and hats are coloured; ``"bright"`` alone: F1 0.27 on ``ucf9`` seq6. At the
  head's scale the opposite-sign ring around a head is weaker than the head and inside its
  window, so ``|R|`` rarely adds a peak (it can beside two heads closer than a head's
  diameter).

Cost: :meth:`LogDetector.detect` on rendered 1280x720 frames (``synthetic_crowd``, 1500
people) runs at 60-80 frames/s for ``template_px`` 8-16 on 2 cores shared with a training
job and another process (load 4.8), 90-115 frames/s with the training job alone: well above
the 10 frames/s target. Everything is whole-image OpenCV/NumPy; Python loops only over
frames.

>>> frame = np.full((40, 60, 3), 128, np.uint8)
>>> _ = cv2.circle(frame, (20, 15), 3, (40, 40, 40), -1)
>>> pts, scores = LogDetector(LogParams(template_px=16, threshold=20.0)).detect_points(frame)
>>> pts.round(1).tolist(), bool(scores[0] > 0.5)
([[20.0, 15.0]], True)
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from scipy.spatial import cKDTree

from crowdsim.checks import require_choice, require_number
from crowdsim.detections import Detections
from tracker.detect.matching import DEFAULT_RADIUS_PX, DetectionScore, score_frame

Polarity = Literal["dark", "bright", "both"]
POLARITIES: tuple[str, ...] = ("dark", "bright", "both")
LOG_PEAK: float = 2.0 / math.e
"""``NORM`` of Eq. 1: the scale-normalised LoG of a unit-contrast disc at its centre and best
scale, so that responses read as grey levels of contrast."""
HEAD_FRACTION: float = 0.42
"""Head diameter / template size of the renderer (twice its head radius, 0.21 template)."""
FIT_FLOOR: float = 1e-3
"""Threshold at which :func:`fit_threshold` collects every peak once before sweeping."""


@dataclass(frozen=True, kw_only=True)
class LogParams:
    """Parameters of the LoG head detector.

    Attributes
    ----------
    template_px : float
        Template size of the sequence, px, in ``[2, 256]`` (shoulder width; a sequence's
        ``template_size``). The head's diameter is ``D = head_fraction * template_px``,
        which sets the scale ``sigma = D / (2 sqrt 2)`` (Eq. 2).
    threshold : float
        Smallest response kept, ``> 0``, in grey levels of contrast of a head-sized disc
        against its surround (Eq. 1). Default: typical of the values :func:`fit_threshold`
        chose on ``ucf9`` and default-look sequences (19-34, once 72); fit it on annotated
        frames.
    min_distance_px : float or None
        Half-side ``d`` (px, ``>= 1``, rounded down) of the square window in which a peak must
        be the largest: two detections are more than ``d`` px apart along x or y. ``None``:
        ``template_px / 2`` (the heads of people shoulder to shoulder are one template apart).
    polarity : {"dark", "bright", "both"}
        Which blobs are heads: darker than their surround (``R``), lighter (``-R``) or either
        (``|R|``, default; see the module docstring for the measurement).
    head_fraction : float
        Head diameter as a fraction of ``template_px``, in ``(0, 2]`` (Eq. 2); default
        :data:`HEAD_FRACTION`, the renderer's.
    """

    template_px: float
    threshold: float = 22.0
    min_distance_px: float | None = None
    polarity: Polarity = "both"
    head_fraction: float = HEAD_FRACTION

    def __post_init__(self) -> None:
        own = "LogParams"
        require_number(own, "template_px", self.template_px, lo=2, hi=256)
        require_number(own, "threshold", self.threshold, lo=0, lo_open=True)
        if self.min_distance_px is not None:
            require_number(own, "min_distance_px", self.min_distance_px, lo=1)
        require_choice(own, "polarity", self.polarity, POLARITIES)
        require_number(own, "head_fraction", self.head_fraction, lo=0, hi=2, lo_open=True)

    @property
    def sigma(self) -> float:
        """Scale of the Gaussian, px (Eq. 2)."""
        return self.head_fraction * self.template_px / (2.0 * math.sqrt(2.0))

    @property
    def window_half_px(self) -> int:
        """Half-side ``d`` of the local-maximum window, px."""
        d = self.template_px / 2.0 if self.min_distance_px is None else self.min_distance_px
        return max(1, int(d))


def _grey(frame: np.ndarray) -> np.ndarray:
    f = np.asarray(frame)
    if f.ndim == 2:
        return f.astype(np.float32)
    if f.ndim != 3 or f.shape[2] != 3:
        raise ValueError(f"frame must have shape (H, W, 3) (BGR) or (H, W), got {f.shape}")
    return cv2.cvtColor(np.ascontiguousarray(f, dtype=np.uint8), cv2.COLOR_BGR2GRAY).astype(
        np.float32
    )


class LogDetector:
    """Head points as scale-normalised LoG peaks (module docstring, steps 1-6).

    Parameters
    ----------
    params : LogParams
    """

    def __init__(self, params: LogParams) -> None:
        if not isinstance(params, LogParams):
            raise ValueError(f"params must be a LogParams, got {type(params).__name__}")
        self.params = params
        d = params.window_half_px
        self._kernel = np.ones((2 * d + 1, 2 * d + 1), np.uint8)

    def response(self, frame: np.ndarray) -> np.ndarray:
        """Signed head response (Eq. 1 with the polarity applied).

        Parameters
        ----------
        frame : (H, W, 3) uint8 BGR, or (H, W) grey

        Returns
        -------
        (H, W) float32
            Grey levels of contrast; heads are positive peaks.
        """
        p = self.params
        g = _grey(frame)
        s = p.sigma
        smooth = cv2.GaussianBlur(g, (0, 0), sigmaX=s, sigmaY=s)
        r = cv2.Laplacian(smooth, cv2.CV_32F, ksize=1, scale=s * s / LOG_PEAK)
        if p.polarity == "bright":
            np.negative(r, out=r)
        elif p.polarity == "both":
            np.abs(r, out=r)
        return r

    def peaks(self, response: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """Local maxima of a response map at or above ``threshold``, refined to sub-pixel.

        Parameters
        ----------
        response : (H, W) float32
            From :meth:`response`.
        threshold : float
            Smallest response kept, ``> 0``.

        Returns
        -------
        points : (m, 2) float64
            Peak positions ``(x, y)``, px, in raster order of their pixels.
        values : (m,) float64
            Response at each peak's pixel.
        """
        r = response
        is_max = (r >= cv2.dilate(r, self._kernel)) & (r >= threshold)
        y, x = np.nonzero(is_max)
        if len(x) > 1:
            # Maxima of the same window are exact ties: keep the first (raster order).
            d = self.params.window_half_px
            pairs = cKDTree(np.stack([x, y], 1)).query_pairs(d, p=np.inf, output_type="ndarray")
            if len(pairs):
                drop = np.zeros(len(x), bool)
                drop[pairs.max(1)] = True
                x, y = x[~drop], y[~drop]
        values = r[y, x].astype(np.float64)
        h, w = r.shape
        # A peak on the image border repeats its own value outside (offset towards inside).
        x0, x1 = np.maximum(x - 1, 0), np.minimum(x + 1, w - 1)
        y0, y1 = np.maximum(y - 1, 0), np.minimum(y + 1, h - 1)
        pts = np.stack([x, y], 1).astype(np.float64)
        for axis, (lo, hi) in enumerate(((r[y, x0], r[y, x1]), (r[y0, x], r[y1, x]))):
            lo, hi = lo.astype(np.float64), hi.astype(np.float64)
            curv = lo - 2.0 * values + hi
            with np.errstate(divide="ignore", invalid="ignore"):
                off = np.where(curv < 0, 0.5 * (lo - hi) / curv, 0.0)
            pts[:, axis] += np.clip(off, -0.5, 0.5)
        return pts, values

    def detect_points(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Head points of one frame.

        Parameters
        ----------
        frame : (H, W, 3) uint8 BGR

        Returns
        -------
        points : (m, 2) float64
            Head centres ``(x, y)``, px (``m = 0`` possible).
        scores : (m,) float64
            ``R / (R + threshold)`` in ``[0.5, 1)``.
        """
        t = self.params.threshold
        pts, values = self.peaks(self.response(frame), t)
        return pts, values / (values + t)

    def detect(self, frame: np.ndarray) -> Detections:
        """Head detections of one frame: :meth:`detect_points` as a
        :class:`crowdsim.detections.Detections` of square boxes of side ``template_px``."""
        pts, scores = self.detect_points(frame)
        h, w = np.asarray(frame).shape[:2]
        return Detections.from_points(
            pts, confidence=scores, box_px=float(self.params.template_px), width=w, height=h
        )


def fit_threshold(
    frames: Iterable[np.ndarray],
    gt_points_per_frame: Iterable[np.ndarray],
    template_px: float,
    radius: float = DEFAULT_RADIUS_PX,
    *,
    polarity: Polarity = "both",
    min_distance_px: float | None = None,
    head_fraction: float = HEAD_FRACTION,
    n_candidates: int = 64,
) -> float:
    """The detection threshold that maximises F1 at ``radius`` px over annotated frames.

    Fair to the learnt detector: give it the same training frames. The response and its peaks
    are computed once per frame at :data:`FIT_FLOOR`; the sweep then only filters the peaks
    by response and re-matches them. Candidates: ``n_candidates`` thresholds spaced
    geometrically between the weakest and the strongest peak, then ``n_candidates`` more
    between the best one's two neighbours. F1 is that of the counts summed over all frames.

    Parameters
    ----------
    frames : iterable of (H, W, 3) uint8 BGR
    gt_points_per_frame : iterable of (n_t, 2) float
        Head centres of each frame, px, NaN rows for absent people (e.g. the rows of a
        ``(T, N, 2)`` ground truth).
    template_px : float
        Template size, px (:class:`LogParams`).
    radius : float
        Matching radius, px (:func:`~tracker.detect.matching.match_points`).
    polarity, min_distance_px, head_fraction
        As in :class:`LogParams`.
    n_candidates : int
        Thresholds per sweep stage, ``>= 2``.

    Returns
    -------
    float
        The threshold (``> 0``) for ``LogParams(threshold=...)``; of equal F1s the middle
        one (in candidate order).
        :data:`FIT_FLOOR` when no frame has a peak.

    Raises
    ------
    ValueError
        No frames, or not as many ground-truth frames as frames.
    """
    require_number("fit_threshold", "n_candidates", n_candidates, lo=2, integer=True)
    det = LogDetector(
        LogParams(
            template_px=template_px,
            threshold=FIT_FLOOR,
            min_distance_px=min_distance_px,
            polarity=polarity,
            head_fraction=head_fraction,
        )
    )
    frames = list(frames)
    gts = [np.asarray(g, dtype=np.float64).reshape(-1, 2) for g in gt_points_per_frame]
    if not frames:
        raise ValueError("fit_threshold needs at least one frame")
    if len(frames) != len(gts):
        raise ValueError(f"fit_threshold: {len(frames)} frames but {len(gts)} ground truths")
    found = [det.peaks(det.response(f), FIT_FLOOR) for f in frames]
    pooled = np.concatenate([v for _, v in found])
    if len(pooled) == 0:
        return FIT_FLOOR

    def best(cands: np.ndarray) -> int:
        f1 = [
            sum(
                (score_frame(p[v >= t], g, radius) for (p, v), g in zip(found, gts, strict=True)),
                DetectionScore(),
            ).f1
            for t in cands
        ]
        # Of equal F1s the middle one: the widest margin on both sides of a plateau.
        top = np.flatnonzero(np.asarray(f1) == max(f1))
        return int(top[len(top) // 2])

    coarse = np.geomspace(pooled.min(), pooled.max(), int(n_candidates))
    i = best(coarse)
    lo, hi = coarse[max(i - 1, 0)], coarse[min(i + 1, len(coarse) - 1)]
    fine = np.geomspace(lo, hi, int(n_candidates))
    return float(fine[best(fine)])
