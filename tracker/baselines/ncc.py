"""Independent NCC template tracker: the simplest baseline of both papers.

Each target keeps a colour template of the template size, searches a window of
``search_factor`` template sizes around its previous position with normalised
cross-correlation (``cv2.matchTemplate``) and moves to the best score. Templates are refreshed
every ``update_every`` frames when the score is at least ``update_threshold`` (paper 1,
Sec. 7.1). No motion model, no interaction between targets.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from crowdsim.checks import require_number
from tracker.appearance import NCCAppearance
from tracker.base import Tracker
from tracker.candidates import grid_offsets, search_radius
from tracker.cmc import check_fields as check_cmc_fields


@functools.lru_cache(maxsize=8)
def _nearest_first(radius: int) -> np.ndarray:
    """The indices of :func:`tracker.candidates.grid_offsets`' offsets of ``radius``,
    nearest the centre first (ties in grid order): sorted once per radius, not each frame."""
    offsets = grid_offsets(radius)
    order = np.argsort((offsets**2).sum(1), kind="stable")
    order.flags.writeable = False  # shared by every call
    return order


@dataclass(frozen=True, kw_only=True)
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
    lost_ratio, max_lost : float, int
        The track ends when the NCC score of its match stays below ``lost_ratio`` times
        its usual score for ``max_lost`` frames in a row (0 = only when it leaves the image);
        as :class:`tracker.bqp.params.BQPParams`.
    cmc : bool
        Camera-motion compensation (:mod:`tracker.cmc`; neither paper has one): before each
        frame's search, the global motion since the previous frame, estimated from the frames
        alone, moves the points and with them the search windows
        (:class:`tracker.base.Tracker`). Off: the papers' static camera.
    cmc_method : str
        How that motion is estimated: ``"sparse"`` (BoT-SORT's sparse optical flow with a
        RANSAC similarity) or ``"ecc"`` (:data:`tracker.cmc.METHODS`).
    """

    search_factor: float = 2.0
    update_threshold: float = 0.6
    update_every: int = 10
    lost_ratio: float = 0.4
    max_lost: int = 5
    cmc: bool = False
    cmc_method: str = "sparse"

    def __post_init__(self) -> None:
        require_number("NCCParams", "search_factor", self.search_factor, lo=1, lo_open=True, hi=8)
        require_number("NCCParams", "update_threshold", self.update_threshold, lo=0, hi=1)
        require_number("NCCParams", "update_every", self.update_every, lo=1, integer=True)
        require_number("NCCParams", "lost_ratio", self.lost_ratio, lo=0, hi=1)
        require_number("NCCParams", "max_lost", self.max_lost, lo=0, integer=True)
        check_cmc_fields("NCCParams", self)


class NCCTracker(Tracker):
    """Independent template tracker (argmax of NCC per target)."""

    name = "ncc"
    params_class = NCCParams

    def __init__(self, params: NCCParams | None = None):
        super().__init__()
        self.params = params if params is not None else NCCParams()

    def _init(self, frame: np.ndarray) -> None:
        p = self.params
        self.model = NCCAppearance(
            self.template_size, 1, p.update_threshold, update_every=p.update_every
        )
        self._set_radius()
        self._last_motion = np.zeros((0, 2))  # each target's last displacement

    def _set_radius(self) -> None:
        self.radius = search_radius(self.template_size, self.params.search_factor)
        self.model.radius = self.radius
        self.model.window = self.template_size + 2 * self.radius
        self._offsets = grid_offsets(self.radius)

    def _apply_params(self, old: NCCParams, changed: frozenset[str]) -> None:
        self.model.update_threshold = float(self.params.update_threshold)
        self.model.update_every = int(self.params.update_every)
        self._set_radius()

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        self.model.add(frame, np.rint(points).astype(np.int64))
        self._last_motion = np.concatenate([self._last_motion, np.zeros((len(points), 2))])

    def _remove(self, keep: np.ndarray) -> None:
        self.model.keep(keep)
        self._last_motion = self._last_motion[keep]

    def _step(self, frame: np.ndarray) -> np.ndarray:
        h, w = self.frame_shape[:2]
        t0 = time.perf_counter()
        centers = np.rint(self.points).astype(np.int64)
        # inside the image, as BQP's and PNMC's: a point the camera's motion (cmc) carried
        # out of view would search a window wholly outside and take its first offset there
        centers[:, 0] = np.clip(centers[:, 0], 0, w - 1)
        centers[:, 1] = np.clip(centers[:, 1], 0, h - 1)
        scores = self.model.scores(frame, centers)
        n = len(centers)
        flat = scores.reshape(n, -1)
        pos = centers[:, None, :] + self._offsets[None]
        # the centre of a match must stay inside the image
        outside = (
            (pos[..., 0] < 0) | (pos[..., 0] > w - 1) | (pos[..., 1] < 0) | (pos[..., 1] > h - 1)
        )
        # nearest the centre first: among equal scores (a flat template or a blank frame
        # scores every window alike) the target stays, never steps to the window's corner
        order = _nearest_first(self.radius)
        best = order[np.where(outside, -np.inf, flat)[:, order].argmax(1)]
        new = pos[np.arange(n), best].astype(np.float64)
        conf = flat[np.arange(n), best]
        self.confidence = conf.astype(np.float64)
        self.model.update(frame, np.rint(new).astype(np.int64), conf)
        self._last_motion = new - self.points
        self._tick("appearance", t0)
        return new

    def _predicted(self) -> np.ndarray:
        # a target pinned to the border and still pushing outwards has left the image
        return self.points + self._last_motion
