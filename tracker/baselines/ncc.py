"""Independent NCC template tracker: the simplest baseline of both papers.

Each target keeps a colour template of the template size, searches a window of
``search_factor`` template sizes around its previous position with normalised
cross-correlation (``cv2.matchTemplate``) and moves to the best score. Templates are refreshed
every ``update_every`` frames when the score is at least ``update_threshold`` (paper 1,
Sec. 7.1). No motion model, no interaction between targets.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tracker.appearance import NCCAppearance
from tracker.base import Tracker
from tracker.candidates import grid_offsets, search_radius


@dataclass(frozen=True)
class NCCParams:
    """Parameters of the independent NCC tracker.

    Attributes
    ----------
    search_factor : float
        Side of the search region in template sizes (as the BQP tracker: 2).
    update_threshold : float
        Templates are refreshed only when the NCC score of the match is at least this.
    update_every : int
        Frames between template refreshes (paper: 10).
    """

    search_factor: float = 2.0
    update_threshold: float = 0.6
    update_every: int = 10

    def __post_init__(self) -> None:
        if not self.search_factor > 1.0:
            raise ValueError(f"NCCParams.search_factor must be > 1, got {self.search_factor!r}")
        if not 0.0 <= self.update_threshold <= 1.0:
            raise ValueError("NCCParams.update_threshold must be in [0, 1], "
                             f"got {self.update_threshold!r}")
        if not isinstance(self.update_every, int) or self.update_every < 1:
            raise ValueError(f"NCCParams.update_every must be an integer >= 1, "
                             f"got {self.update_every!r}")


class NCCTracker(Tracker):
    """Independent template tracker (argmax of NCC per target)."""

    name = "ncc"

    def __init__(self, params: NCCParams | None = None):
        super().__init__()
        self.params = params if params is not None else NCCParams()

    def _init(self, frame: np.ndarray) -> None:
        p = self.params
        self.radius = search_radius(self.template_size, p.search_factor)
        self.model = NCCAppearance(self.template_size, self.radius, p.update_threshold,
                                   update_every=p.update_every)
        self._offsets = grid_offsets(self.radius)

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        self.model.add(frame, np.rint(points).astype(np.int64))

    def _remove(self, keep: np.ndarray) -> None:
        self.model.keep(keep)

    def _step(self, frame: np.ndarray) -> np.ndarray:
        h, w = self.frame_shape[:2]
        t0 = time.perf_counter()
        centers = np.rint(self.points).astype(np.int64)
        scores = self.model.scores(frame, centers)
        n = len(centers)
        flat = scores.reshape(n, -1)
        pos = centers[:, None, :] + self._offsets[None]
        # the centre of a match must stay inside the image
        outside = (pos[..., 0] < 0) | (pos[..., 0] > w - 1) | (pos[..., 1] < 0) | \
            (pos[..., 1] > h - 1)
        best = np.where(outside, -np.inf, flat).argmax(1)
        new = pos[np.arange(n), best].astype(np.float64)
        conf = flat[np.arange(n), best]
        self.model.update(frame, np.rint(new).astype(np.int64), conf)
        self._last_motion = new - self.points
        self._tick("appearance", t0)
        return new

    def _predicted(self) -> np.ndarray:
        # a target pinned to the border and still pushing outwards has left the image
        return self.points + getattr(self, "_last_motion", np.zeros_like(self.points))
