"""Mean-shift baseline (paper 2's "MS" column): OpenCV ``cv2.meanShift`` per target.

Each target keeps a colour histogram of its template (B, G, R by default; the
hue-saturation histogram of OpenCV's CamShift tutorial is an option). Every frame, the
histogram is back-projected over a region of ``search_factor`` template sizes around the
target's previous position, and ``cv2.meanShift`` moves a window of the template size to the
local mode of that back-projection. The update confidence is the Bhattacharyya coefficient
``sum_b sqrt(p_b q_b)`` between the target's histogram and the histogram under the final
window; the histogram is rebuilt from the current window every ``update_every`` frames when
that confidence reaches ``update_threshold``. No motion model and no interaction between targets.

Histograms and back-projections are computed in numpy for all targets at once (OpenCV
4.x's ``calcBackProject`` returned all zeros for 3-D B, G, R histograms in this build);
``cv2.meanShift`` runs one target at a time on its back-projected crop (a few microseconds
each).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from crowdsim.checks import require_choice, require_number
from tracker.appearance import extract_patches
from tracker.base import Tracker
from tracker.candidates import search_radius
from tracker.cmc import check_fields as check_cmc_fields

COLOR_SPACES: tuple[str, ...] = ("hsv", "hue", "bgr")
"""Histogram features: hue-saturation (2-D), hue only (1-D), or B, G, R (3-D)."""

_SPACE = {  # colour conversion, channels, value range of each channel
    "hsv": (cv2.COLOR_BGR2HSV, (0, 1), (180, 256)),
    "hue": (cv2.COLOR_BGR2HSV, (0,), (180,)),
    "bgr": (None, (0, 1, 2), (256, 256, 256)),
}


def bin_index(image: np.ndarray, color_space: str, bins: int) -> np.ndarray:
    """Histogram bin of every pixel: ``(..., 3)`` uint8 (converted) -> ``(...)`` int64.

    >>> bin_index(np.array([[0, 128, 255]], np.uint8), "bgr", 2).tolist()
    [3]
    """
    _, channels, ranges = _SPACE[color_space]
    idx = np.zeros(image.shape[:-1], np.int64)
    for c, top in zip(channels, ranges, strict=True):
        q = np.minimum(image[..., c].astype(np.int64) * bins // top, bins - 1)
        idx = idx * bins + q
    return idx


def histograms(idx: np.ndarray, n_bins: int) -> np.ndarray:
    """``(n, n_bins)`` float64 normalised (sum 1) histograms of ``idx`` ``(n, ...)`` bins."""
    n = idx.shape[0]
    flat = idx.reshape(n, -1)
    counts = (
        np.bincount((flat + np.arange(n)[:, None] * n_bins).ravel(), minlength=n * n_bins)
        .reshape(n, n_bins)
        .astype(np.float64)
    )
    return counts / np.maximum(counts.sum(1, keepdims=True), 1.0)


@dataclass(frozen=True, kw_only=True)
class MeanShiftParams:
    """Parameters of the mean-shift baseline.

    Attributes
    ----------
    color_space : str
        Histogram features, one of :data:`COLOR_SPACES`. B, G, R with 8 bins is the default:
        on the bench crowd (``crowdsim bench track``'s 100 people, 30 frames) it scored
        35 % at 15 px against 16 % for OpenCV's classic hue-saturation histogram, whose hue is
        noise on the dark, unsaturated heads seen from above.
    bins : int
        Histogram bins per channel.
    search_factor : float
        Side of the back-projected search region, template sizes (as the NCC baseline: 2).
    max_iter : int
        Mean-shift iterations per frame (``cv2.TermCriteria`` count).
    epsilon : float
        Mean-shift stops when the window moves less than this, px.
    update_every : int
        Frames between histogram refreshes (paper 2: templates every 10 frames).
    update_threshold : float
        Histograms are refreshed only when the Bhattacharyya coefficient reaches this.
    lost_ratio, max_lost : float, int
        The track ends when the Bhattacharyya coefficient stays below ``lost_ratio`` times
        its usual value for ``max_lost`` frames in a row (0 = only when it leaves the image).
        The coefficient is compressed (a vanished person on textured ground still scores
        about half of its usual 0.9), hence 0.6 where the template trackers use 0.4.
    cmc : bool
        Camera-motion compensation (:mod:`tracker.cmc`; neither paper has one): before each
        frame's search, the global motion since the previous frame, estimated from the frames
        alone, moves the points and with them the back-projected search regions
        (:class:`tracker.base.Tracker`). Off: the papers' static camera.
    cmc_method : str
        How that motion is estimated: ``"sparse"`` (BoT-SORT's sparse optical flow with a
        RANSAC similarity) or ``"ecc"`` (:data:`tracker.cmc.METHODS`).
    """

    color_space: str = "bgr"
    bins: int = 8
    search_factor: float = 2.0
    max_iter: int = 10
    epsilon: float = 1.0
    update_every: int = 10
    update_threshold: float = 0.5
    lost_ratio: float = 0.6
    max_lost: int = 5
    cmc: bool = False
    cmc_method: str = "sparse"

    def __post_init__(self) -> None:
        o = "MeanShiftParams"
        require_choice(o, "color_space", self.color_space, COLOR_SPACES)
        # bins^3 floats per target in colour: 32 bins and 1,000 people are 262 MB already
        require_number(o, "bins", self.bins, lo=2, hi=32, integer=True)
        require_number(o, "search_factor", self.search_factor, lo=1, lo_open=True, hi=8)
        require_number(o, "max_iter", self.max_iter, lo=1, hi=1000, integer=True)
        require_number(o, "epsilon", self.epsilon, lo=0, lo_open=True)
        require_number(o, "update_every", self.update_every, lo=1, integer=True)
        require_number(o, "update_threshold", self.update_threshold, lo=0, hi=1)
        require_number(o, "lost_ratio", self.lost_ratio, lo=0, hi=1)
        require_number(o, "max_lost", self.max_lost, lo=0, integer=True)
        check_cmc_fields(o, self)


class MeanShiftTracker(Tracker):
    """Independent mean-shift tracker on colour-histogram back-projections.

    Attributes (besides the base class's)
    ----------
    templates : (n, s, s, 3) uint8
        BGR patch each histogram was built from (kept so that a new ``color_space`` or
        ``bins`` rebuilds the histograms).
    hists : (n, B) float64
        Normalised (sum 1) histogram of each target, ``B = bins^d`` for ``d`` channels.
    age : (n,) int64
        Frames since each histogram was built.
    """

    name = "meanshift"
    params_class = MeanShiftParams
    position_tolerance_px = 3.0
    """cv2.meanShift's integer search window stops 1-2 px short of a blob's centre by design,
    so it lags a moving one by up to 3 px. The same lag keeps its window inside the image when
    a person walks out, so its track ends on lost evidence (``max_lost`` frames later)."""

    def __init__(self, params: MeanShiftParams | None = None):
        super().__init__()
        self.params = params if params is not None else MeanShiftParams()

    @property
    def n_bins(self) -> int:
        """``B``: bins of one histogram."""
        return self.params.bins ** len(_SPACE[self.params.color_space][1])

    def _init(self, frame: np.ndarray) -> None:
        s = self.template_size
        self.templates = np.zeros((0, s, s, 3), np.uint8)
        self.hists = np.zeros((0, self.n_bins))
        self.age = np.zeros(0, np.int64)
        self.radius = search_radius(s, self.params.search_factor)

    def _apply_params(self, old: MeanShiftParams, changed: frozenset[str]) -> None:
        self.radius = search_radius(self.template_size, self.params.search_factor)
        if changed & {"color_space", "bins"}:
            self.hists = self._hists(self.templates)

    # ------------------------------------------------------------------ histograms
    def _convert(self, image: np.ndarray) -> np.ndarray:
        code = _SPACE[self.params.color_space][0]
        return image if code is None else cv2.cvtColor(image, code)

    def _hists(self, patches_bgr: np.ndarray) -> np.ndarray:
        """``(m, B)`` histograms of ``(m, s, s, 3)`` BGR patches."""
        if len(patches_bgr) == 0:
            return np.zeros((0, self.n_bins))
        s = patches_bgr.shape[1]
        conv = self._convert(np.ascontiguousarray(patches_bgr.reshape(-1, s, 3)))
        idx = bin_index(conv.reshape(patches_bgr.shape), self.params.color_space, self.params.bins)
        return histograms(idx, self.n_bins)

    def _patches(self, frame: np.ndarray, points: np.ndarray) -> np.ndarray:
        s = self.template_size
        tl = np.rint(points).astype(np.int64) - s // 2
        return np.ascontiguousarray(extract_patches(frame, tl, s).transpose(0, 2, 3, 1))

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        patches = self._patches(frame, points)
        self.templates = np.concatenate([self.templates, patches])
        self.hists = np.concatenate([self.hists, self._hists(patches)])
        self.age = np.concatenate([self.age, np.zeros(len(points), np.int64)])

    def _remove(self, keep: np.ndarray) -> None:
        self.templates = self.templates[keep]
        self.hists = self.hists[keep]
        self.age = self.age[keep]

    def _predicted(self) -> np.ndarray:
        return self.points + getattr(self, "_last_motion", np.zeros_like(self.points))

    # ------------------------------------------------------------------ one frame
    def _step(self, frame: np.ndarray) -> np.ndarray:
        p = self.params
        h, w = self.frame_shape[:2]
        s, r = self.template_size, self.radius
        side = s + 2 * r
        n = len(self.points)
        t0 = time.perf_counter()
        centers = np.rint(self.points).astype(np.int64)
        crop_tl = centers - s // 2 - r
        crops = extract_patches(self._convert(frame), crop_tl, side).transpose(0, 2, 3, 1)
        idx = bin_index(crops, p.color_space, p.bins)  # (n, side, side)
        # back-projection: each pixel scores its bin in the target's histogram (max 255)
        top = np.maximum(self.hists.max(1, keepdims=True), 1e-12)
        back = np.rint(255.0 * np.take_along_axis(self.hists / top, idx.reshape(n, -1), 1))
        back = back.reshape(n, side, side).astype(np.uint8)
        criteria = (
            cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
            int(p.max_iter),
            float(p.epsilon),
        )
        win_tl = np.empty((n, 2), np.int64)
        for i in range(n):  # OpenCV moves one window at a time
            _, (x, y, _, _) = cv2.meanShift(back[i], (r, r, s, s), criteria)
            win_tl[i] = (x, y)
        new = (crop_tl + win_tl + s // 2).astype(np.float64)
        new[:, 0] = np.clip(new[:, 0], 0, w - 1)
        new[:, 1] = np.clip(new[:, 1], 0, h - 1)
        # Bhattacharyya coefficient between the model and the histogram under the window
        d = np.arange(s)
        rows = (win_tl[:, 1:2] + d)[:, :, None]
        cols = (win_tl[:, 0:1] + d)[:, None, :]
        under = histograms(idx[np.arange(n)[:, None, None], rows, cols], self.n_bins)
        conf = np.sqrt(self.hists * under).sum(1)
        self.age += 1
        sel = np.flatnonzero((self.age >= p.update_every) & (conf >= p.update_threshold))
        if len(sel):
            patches = self._patches(frame, new[sel])
            self.templates[sel] = patches
            self.hists[sel] = self._hists(patches)
            self.age[sel] = 0
        self.confidence = conf
        self._last_motion = new - self.points
        self._tick("appearance", t0)
        return new
