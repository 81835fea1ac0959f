"""Run the head-point network on frames: :class:`HeadDetector` and its weights files.

A weights file is one ``torch.save`` of a plain dictionary (loaded with
``torch.load(weights_only=True)``, so a file can never run code):

* ``format``: ``"crowdsim-head-points"``, ``version``: 1;
* ``architecture``: :class:`tracker.detect.model.Architecture` as a dictionary;
* ``state_dict``: the network's tensors;
* ``meta``: how the weights were made (the command, the data, the seed; ``crowdsim detector
  train`` writes it, and a JSON copy beside the file for people).

The default weights ship inside the package (:data:`DEFAULT_WEIGHTS`); nothing is downloaded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.checks import require_number
from tracker.detect.model import STRIDE, Architecture, build_net, decode, padded_size, standardise

FORMAT = "crowdsim-head-points"
VERSION = 1
DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "head_points.pt"
"""The shipped weights (``crowdsim detector train``; the command and data are in the JSON
beside them)."""
MIN_SIDE = 2 * STRIDE
"""The smallest frame side the network takes, px (two output cells)."""


class WeightsError(ValueError):
    """A weights file that is missing, damaged or not a head-detector's."""


@dataclass(frozen=True, kw_only=True)
class DetectorParams:
    """Settings of the trained head detector (they belong to the detector, not the tracker).

    Attributes
    ----------
    weights : str or None
        Weights file; ``None``: the shipped :data:`DEFAULT_WEIGHTS`.
    threshold : float
        Least heat-map peak (the detection's confidence) kept, in ``(0, 1)``.
    box_px : float or None
        Side of the square boxes around each point (for tracking by detection); ``None``: the
        template size given to :meth:`HeadDetector.detect`.
    """

    weights: str | None = None
    threshold: float = 0.4
    box_px: float | None = None

    def __post_init__(self) -> None:
        own = "DetectorParams"
        require_number(own, "threshold", self.threshold, lo=0, hi=1, lo_open=True, hi_open=True)
        if self.box_px is not None:
            require_number(own, "box_px", self.box_px, lo=1, hi=4096)
        if self.weights is not None and not isinstance(self.weights, (str, os.PathLike)):
            raise ValueError(f"{own}.weights must be a file path, got {self.weights!r}")

    @classmethod
    def given(cls, weights: str | None = None, threshold: float | None = None) -> DetectorParams:
        """The defaults, with the weights file and threshold that are given (not ``None``)."""
        return cls(weights=weights, **({} if threshold is None else {"threshold": threshold}))

    @property
    def weights_path(self) -> Path:
        """The weights file: :attr:`weights`, or the shipped :data:`DEFAULT_WEIGHTS`."""
        return Path(self.weights) if self.weights is not None else DEFAULT_WEIGHTS


def save_weights(path: str | os.PathLike[str], net: Any, arch: Architecture, meta: dict) -> Path:
    """Write a weights file atomically (temporary file, then rename)."""
    from crowdsim.atomic import atomic_path, torch_save
    from crowdsim.optional import require

    require("torch", "detect", "the head detector")
    blob = {
        "format": FORMAT,
        "version": VERSION,
        "architecture": arch.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
        "meta": meta,
    }
    with atomic_path(path) as tmp:
        torch_save(blob, tmp, path)
    return Path(path)


def load_failure(exc: BaseException) -> str:
    """Why ``torch.load(..., weights_only=True)`` failed, in one line of at most 200
    characters; never torch's advice to load the file unsafely."""
    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if reason.startswith("Weights only load failed"):
        reason = "it holds objects that a safe load refuses"
    return reason[:200]


def load_weights(path: str | os.PathLike[str] | None = None) -> tuple[Any, dict]:
    """``(net in eval mode, meta)`` from a weights file; :class:`WeightsError` names the file
    when it is missing, damaged or foreign."""
    from crowdsim.optional import require

    torch = require("torch", "detect", "the head detector")
    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise WeightsError(f"{path}: no such weights file")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a damaged file
        raise WeightsError(f"{path}: not a readable weights file ({load_failure(exc)})") from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise WeightsError(f"{path}: not a crowdsim head-detector weights file")
    if blob.get("version") != VERSION:
        raise WeightsError(
            f"{path}: weights format version {blob.get('version')!r}, need {VERSION}"
        )
    try:
        arch = Architecture.from_dict(blob["architecture"])
        net = build_net(arch)
        net.load_state_dict(blob["state_dict"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise WeightsError(f"{path}: weights do not fit the network ({reason[:200]})") from None
    meta = blob.get("meta", {})
    if not isinstance(meta, dict):
        raise WeightsError(f"{path}: its 'meta' is not a table of how the weights were made")
    net.eval()
    return net.to(memory_format=torch.channels_last), dict(meta)


def weights_digest(params: DetectorParams | None = None) -> str:
    """The SHA-256 (first 16 hex digits) of the weights file ``params`` names."""
    import hashlib

    path = (params or DetectorParams()).weights_path
    if not path.is_file():
        raise WeightsError(f"{path}: no such weights file")
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


@lru_cache(maxsize=4)
def _cached(path: str, mtime_ns: int, size: int) -> tuple[Any, dict]:
    return load_weights(path)


TRAINED_HEAD_PX: tuple[int, int] = (8, 16)
"""Head sizes, px, of the sequences the shipped weights learnt from
(``crowdsim.lab.detector.TEMPLATES``)."""
SCALE_TO_PX: float = 12.0
"""Head size, px, that larger heads are shrunk to before detection (the middle of
:data:`TRAINED_HEAD_PX`)."""
MAX_ENLARGE: float = 3.0
"""Most a frame of heads below :data:`TRAINED_HEAD_PX` is enlarged before detection."""


def content_box(frame: np.ndarray, tol: float = 16.0) -> tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)`` of ``frame`` without flat bars of one colour along its edges (a
    letterbox or pillarbox: rows / columns whose every pixel is within ``tol`` of the line's
    first pixel, codec ringing included); the whole frame when no bar is found or too
    little would be left."""
    h, w = frame.shape[:2]

    def flat(lines: np.ndarray) -> np.ndarray:  # (n, k, 3): is each line one colour?
        lines = lines.astype(np.int16)
        return np.abs(lines - lines[:, :1]).max(axis=(1, 2)) <= tol

    edges = frame[[0, h - 1]], frame[:, [0, w - 1]].transpose(1, 0, 2)
    if not (flat(edges[0]).any() or flat(edges[1]).any()):
        return 0, h, 0, w  # no bar (nearly every frame): the four edge lines alone are read
    rows, cols = flat(frame), flat(frame.transpose(1, 0, 2))
    y0 = int(np.argmin(rows)) if not rows.all() else 0
    y1 = h - int(np.argmin(rows[::-1])) if not rows.all() else h
    x0 = int(np.argmin(cols)) if not cols.all() else 0
    x1 = w - int(np.argmin(cols[::-1])) if not cols.all() else w
    if min(y1 - y0, x1 - x0) < MIN_SIDE:
        return 0, h, 0, w
    return y0, y1, x0, x1


class HeadDetector:
    """Head points of a frame from the trained network::

        det = HeadDetector()                        # the shipped weights, threshold 0.4
        points, scores = det.detect_points(frame)   # (m, 2) px, (m,) in (0, 1), best first

    It is also a detection feed for the tracking-by-detection trackers: ``det(t, frame)``
    returns the frame's :class:`crowdsim.detections.Detections`.
    """

    def __init__(self, params: DetectorParams | None = None, *, template_size: float = 12) -> None:
        self.params = params if params is not None else DetectorParams()
        require_number("HeadDetector", "template_size", template_size, lo=1)
        self.template_size = float(template_size)
        path = self.params.weights_path
        if not path.is_file():
            raise WeightsError(f"{path}: no such weights file")
        st = path.stat()
        self.path = path
        self.net, self.meta = _cached(str(path.resolve()), st.st_mtime_ns, st.st_size)

    def __repr__(self) -> str:
        return f"HeadDetector({self.path.name}, threshold={self.params.threshold:g})"

    def heatmap(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(heat (h, w) probabilities, offsets (2, h, w))`` of one ``(H, W, 3)`` uint8 frame."""
        import torch

        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(
                f"a frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype} array"
            )
        h, w = frame.shape[:2]
        if min(h, w) < MIN_SIDE:
            raise ValueError(
                f"frame {w}x{h} is smaller than the detector's smallest input "
                f"({MIN_SIDE} px a side)"
            )
        x = standardise(frame[None])
        ph, pw = padded_size(h, w)
        if (ph, pw) != (h, w):  # zeros are the mean colour after standardisation
            x = np.pad(x, ((0, 0), (0, 0), (0, ph - h), (0, pw - w)))
        with torch.inference_mode():
            t = torch.from_numpy(x).contiguous(memory_format=torch.channels_last)
            out = self.net(t)[0].float().numpy()
        heat = 1.0 / (1.0 + np.exp(-out[0]))
        return heat, out[1:3]

    def detect_points(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Head centres ``(m, 2)`` px and confidences ``(m,)`` in one frame, best first.

        The network learnt heads of :data:`TRAINED_HEAD_PX` px. Larger heads (a
        :attr:`template_size` above that range: high-resolution or close-up footage) are
        found on the frame shrunk to :data:`SCALE_TO_PX` px heads, and their points scaled
        back (at full size a head three times too large was found 2.2 times over)."""
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            self.heatmap(frame)  # names what is wrong with it
        y0, y1, x0, x1 = content_box(frame)
        if (y0, y1, x0, x1) != (0, frame.shape[0], 0, frame.shape[1]):
            # letterbox / pillarbox bars: the network standardises over the whole frame, and
            # a flat black or white bar of a fifth of the frame took its recall to 0.06
            pts, scores = self.detect_points(frame[y0:y1, x0:x1])
            return pts + [x0, y0], scores
        h, w = frame.shape[:2]
        lo, hi = TRAINED_HEAD_PX
        scale = 1.0
        if self.template_size > hi:
            scale = SCALE_TO_PX / self.template_size
        elif self.template_size < lo:  # heads smaller than it learnt: enlarged, at most 3x
            scale = min(SCALE_TO_PX / self.template_size, MAX_ENLARGE)
        if min(h, w) < MIN_SIDE:  # too small already: the network says so at full size
            scale = 1
        elif scale < 1:  # never below the network's smallest input
            scale = max(scale, MIN_SIDE / min(h, w))
        small = frame
        if scale != 1:
            import cv2

            size = (max(1, round(w * scale)), max(1, round(h * scale)))
            how = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
            small = cv2.resize(frame, size, interpolation=how)
        heat, offsets = self.heatmap(small)
        pts, scores = decode(heat, offsets, self.params.threshold)
        if scale != 1:  # pixel centres: x_full + 0.5 = (x_small + 0.5) * w / w_small
            ratio = np.array([w / small.shape[1], h / small.shape[0]])
            pts = (pts + 0.5) * ratio - 0.5
        inside = (pts[:, 0] <= w - 1) & (pts[:, 1] <= h - 1) & (pts >= 0).all(1)
        return pts[inside], scores[inside]

    def detect(self, frame: np.ndarray, template_size: float | None = None) -> Any:
        """One frame's :class:`crowdsim.detections.Detections` (square boxes of ``box_px``, or
        of the template size, around each point)."""
        from crowdsim.detections import Detections

        pts, scores = self.detect_points(frame)
        side = self.params.box_px or template_size or self.template_size
        h, w = np.asarray(frame).shape[:2]
        return Detections.from_points(pts, scores, float(side), width=w, height=h)

    def __call__(self, t: int, frame: np.ndarray) -> Any:
        """A detection feed: the detections of frame ``t``."""
        return self.detect(frame)
