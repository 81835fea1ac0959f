"""One frame's detections as a struct of arrays: the seam between detectors and trackers.

Every detection source (the simulated head detector of :mod:`synth_data.detections`, a trained
detector) produces :class:`Detections`, and the tracking-by-detection trackers
(:mod:`tracker.baselines.detection`) consume them. The type lives on the ground floor so that
both sides may import it: the tracker library imports only ``crowdsim`` base modules, and
``synth_data`` never imports ``tracker``. Detection *settings* (miss rate, thresholds, model)
belong to the source, never to this type or to the tracker.

The layout follows ``supervision.Detections``: a frozen dataclass of ``(m, ...)`` arrays where
indexing (an int, a slice, a boolean mask or an integer index array) returns a new
:class:`Detections`, with :meth:`Detections.empty` and :meth:`Detections.merge`.

>>> d = Detections.from_points([[10.0, 10.0], [1.0, 30.0]], [0.9, 0.4], box_px=4.0,
...                            width=64, height=32)
>>> d.xyxy.tolist(), len(d), d.gt_id.tolist()
([[8.0, 8.0, 12.0, 12.0], [0.0, 28.0, 3.0, 32.0]], 2, [-1, -1])
>>> strong = d[d.confidence > 0.5]
>>> strong.centers.tolist(), len(Detections.merge([Detections.empty(), strong, d]))
([[10.0, 10.0]], 3)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from crowdsim.checks import require_number


@dataclass(frozen=True)
class Detections:
    """Detections of one frame (struct of arrays, ``supervision.Detections`` style).

    Attributes
    ----------
    xyxy : (m, 4) float64
        Boxes ``(x_min, y_min, x_max, y_max)``, px.
    confidence : (m,) float64
        Detector scores, ``[0, 1]``.
    gt_id : (m,) int64
        Ground-truth id each detection was drawn from, ``-1`` for a false alarm or where
        unknown (the default: all ``-1``). For evaluation only: trackers must not read it.

    Inputs are converted to these dtypes; a wrong shape raises ``ValueError`` naming the
    field. ``m = 0`` is a valid (empty) frame.
    """

    xyxy: np.ndarray
    confidence: np.ndarray
    gt_id: np.ndarray | None = None

    def __post_init__(self) -> None:
        xyxy = np.asarray(self.xyxy, dtype=np.float64)
        if xyxy.ndim != 2 or xyxy.shape[1] != 4:
            raise ValueError(f"Detections.xyxy must have shape (m, 4), got {xyxy.shape}")
        m = len(xyxy)
        conf = np.asarray(self.confidence, dtype=np.float64)
        if conf.shape != (m,):
            raise ValueError(f"Detections.confidence must have shape ({m},), got {conf.shape}")
        if self.gt_id is None:
            gt = np.full(m, -1, np.int64)
        else:
            raw = np.asarray(self.gt_id)
            if raw.size and raw.dtype.kind not in "iu":
                raise ValueError(f"Detections.gt_id must hold integers, got dtype {raw.dtype}")
            gt = raw.astype(np.int64, copy=False)
            if gt.shape != (m,):
                raise ValueError(f"Detections.gt_id must have shape ({m},), got {gt.shape}")
        # frozen: the converted arrays replace the inputs once, here
        object.__setattr__(self, "xyxy", xyxy)
        object.__setattr__(self, "confidence", conf)
        object.__setattr__(self, "gt_id", gt)

    def __len__(self) -> int:
        return len(self.confidence)

    def __getitem__(self, index: Any) -> Detections:
        """The detections selected by ``index``, as a new :class:`Detections`.

        ``index``: an int (a one-detection result, as in ``supervision``), a slice, a boolean
        mask of length ``m``, or an integer index array.
        """
        if isinstance(index, (int, np.integer)) and not isinstance(index, (bool, np.bool_)):
            index = [index]
        if not isinstance(index, slice):
            index = np.asarray(index)
            if index.dtype == bool:
                if index.shape != (len(self),):
                    raise IndexError(
                        f"boolean mask of shape {index.shape} for {len(self)} detections"
                    )
            elif index.size == 0:
                index = index.astype(np.int64)
            elif index.dtype.kind not in "iu" or index.ndim != 1:
                raise IndexError(
                    "Detections take an int, a slice, a boolean mask or a 1-D integer index "
                    f"array, got {index.dtype} of shape {index.shape}"
                )
        return Detections(self.xyxy[index], self.confidence[index], self.gt_id[index])

    @property
    def centers(self) -> np.ndarray:
        """``(m, 2)`` box centres, px."""
        return 0.5 * (self.xyxy[:, :2] + self.xyxy[:, 2:])

    @property
    def points(self) -> np.ndarray:
        """``(m, 2)`` head points, px: the box centres (:attr:`centers`), in the trackers'
        vocabulary."""
        return self.centers

    @classmethod
    def empty(cls) -> Detections:
        """No detections: ``m = 0``."""
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64))

    @classmethod
    def merge(cls, detections: Sequence[Detections]) -> Detections:
        """One :class:`Detections` holding all of ``detections`` in order (:meth:`empty` for
        none)."""
        items = list(detections)
        for i, d in enumerate(items):
            if not isinstance(d, Detections):
                raise ValueError(
                    f"Detections.merge takes Detections, got {type(d).__name__} at position {i}"
                )
        if not items:
            return cls.empty()
        return cls(
            np.concatenate([d.xyxy for d in items]),
            np.concatenate([d.confidence for d in items]),
            np.concatenate([d.gt_id for d in items]),
        )

    @classmethod
    def from_points(
        cls,
        points: Any,
        confidence: Any,
        box_px: float,
        width: float | None = None,
        height: float | None = None,
        *,
        gt_id: Any = None,
    ) -> Detections:
        """Square boxes of side ``box_px`` centred on ``points``.

        Parameters
        ----------
        points : (m, 2) float
            Box centres ``(x, y)``, px.
        confidence : (m,) float
            Scores.
        box_px : float
            Box side, px, ``> 0``.
        width, height : float, optional
            Image size, px: boxes are clipped to ``[0, width]`` in x and ``[0, height]`` in y
            (no clipping along an axis whose size is not given).
        gt_id : (m,) int, optional
            Ground-truth ids (default all ``-1``).
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.size == 0 and pts.ndim < 2:
            pts = pts.reshape(0, 2)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ValueError(
                f"Detections.from_points: points must have shape (m, 2), got {pts.shape}"
            )
        require_number("Detections.from_points", "box_px", box_px, lo=0, lo_open=True)
        half = 0.5 * float(box_px)
        xyxy = np.concatenate([pts - half, pts + half], axis=1)
        for size, name, cols in ((width, "width", [0, 2]), (height, "height", [1, 3])):
            if size is not None:
                require_number("Detections.from_points", name, size, lo=0, lo_open=True)
                xyxy[:, cols] = np.clip(xyxy[:, cols], 0.0, float(size))
        return cls(xyxy, confidence, gt_id)
