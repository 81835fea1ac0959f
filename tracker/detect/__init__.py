"""Head-point detection: a learnt detector, a classical baseline and their evaluation.

* :class:`HeadDetector` (:mod:`tracker.detect.inference`) runs the small fully convolutional
  network of :mod:`tracker.detect.model` on a frame and returns head points with a
  confidence, or :class:`crowdsim.detections.Detections`. Its weights ship in the package
  (``weights/head_points.pt``, made by ``crowdsim detector train``; the command and data are in
  ``weights/head_points.json``); nothing is downloaded. Needs torch (the ``detect`` extra).
* :class:`LogDetector` (:mod:`tracker.detect.classical`): scale-normalised Laplacian-of-Gaussian
  peaks, the classical baseline.
* :func:`match_points` / :func:`score_frame` (:mod:`tracker.detect.matching`): one-to-one
  matching within a radius, precision, recall, F1 and localisation error.
"""

from tracker.detect.classical import LogDetector, LogParams, fit_threshold
from tracker.detect.inference import (
    DEFAULT_WEIGHTS,
    DetectorParams,
    HeadDetector,
    WeightsError,
    load_weights,
)
from tracker.detect.matching import DetectionScore, match_points, score_frame

__all__ = [
    "DEFAULT_WEIGHTS",
    "DetectionScore",
    "DetectorParams",
    "HeadDetector",
    "LogDetector",
    "LogParams",
    "WeightsError",
    "fit_threshold",
    "load_weights",
    "match_points",
    "score_frame",
]
