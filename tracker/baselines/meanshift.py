"""Mean-shift baseline (paper 2's "MS" column): OpenCV's mean-shift search, per target.

Each target keeps a colour histogram of its template (B, G, R by default; the
hue-saturation histogram of OpenCV's CamShift tutorial is an option). Every frame, the
histogram is back-projected over a region of ``search_factor`` template sizes around the
target's previous position, and a window of the template size moves to the local mode of that
back-projection as ``cv2.meanShift`` moves it (the window's centroid, rounded to whole pixels,
until it stops moving or after ``max_iter`` moves). The update confidence is the Bhattacharyya
coefficient ``sum_b sqrt(p_b q_b)`` between the target's histogram and the histogram under the
final window; the histogram is rebuilt from the current window every ``update_every`` frames
when that confidence reaches ``update_threshold``. No motion model and no interaction between
targets.

One compiled pass (:func:`shift_windows`, a numba loop over the targets on numba's threads)
bins each search region, back-projects it, runs the mean-shift search and counts the histogram
under the final window, reading the regions in place from the bordered frame. It finds the
windows ``cv2.meanShift`` finds (tests compare the two on random back-projections), 2.1-2.4
times faster at 1,000 targets than binning in numpy and calling ``cv2.meanShift`` one target at
a time from Python, as this module did before (OpenCV 4.x's ``calcBackProject`` also returned
all zeros for 3-D B, G, R histograms in this build).

It keeps ``cv2.meanShift``'s bias, as paper 2's MS column would have it: the window moves by
the rounded ``centroid - w / 2``, while the centre of a window's pixels is ``(w - 1) / 2``, so
on a flat back-projection every move is pulled up and left (500 calls on flat noisy
back-projections: a mean move of (-2.2, -2.1) px, 78 % up-left, none down or right; an audit,
2026-11-27). On the planted crowd of ``tests/tracker/test_tracker_contract.py`` (grey
look-alike heads, 7 % of a template's pixels) the back-projection is nearly flat and the
drift decides: 10.3 / 33.6 % acc@5 / acc@15 (a per-target ``cv2.meanShift`` reference: 10.3 /
33.7), below a tracker that never moves (16.0 / 40.0); the window centred on its pixels
(not OpenCV's) gave 18.1 / 43.6. So the contract test's floor for mean-shift is below a static
tracker's. The hue options do not mask low saturation and value as OpenCV's CamShift
tutorial does (S >= 60, V >= 32): grey ground then has random hue.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from crowdsim.checks import require_choice, require_number
from tracker.appearance import extract_patches, padded_origins
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
    channels = _SPACE[color_space][1]
    lut = channel_bins(color_space, bins)
    idx = np.zeros(image.shape[:-1], np.int64)
    for c, q in zip(channels, lut, strict=True):
        idx = idx * bins + q[image[..., c]]
    return idx


def channel_bins(color_space: str, bins: int) -> np.ndarray:
    """``(d, 256)`` int64: the bin of every 8-bit value of each of the ``d`` channels that
    :func:`bin_index` combines (a channel of range ``top`` has bin ``v bins // top``).

    >>> channel_bins("hue", 4)[0, [0, 44, 45, 179, 255]].tolist()
    [0, 0, 1, 3, 3]
    """
    ranges = np.array(_SPACE[color_space][2], np.int64)
    return np.minimum(np.arange(256) * bins // ranges[:, None], bins - 1)


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


@njit(cache=True, nogil=True, parallel=True)
def shift_windows(padded, ox, oy, scale, channels, lut, bins, s, r, max_iter, eps2):
    """Mean-shift search of every target in its back-projected search region, in one pass.

    Parameters
    ----------
    padded : (H', W', C) uint8
        The (colour-converted) frame with a replicated border (:func:`padded_origins`).
    ox, oy : (n,) int64
        Top-left corner of each search region, ``side = s + 2 r`` pixels square, in ``padded``.
    scale : (n, B) float64
        Each target's histogram divided by its largest bin: a pixel of bin ``b`` scores
        ``rint(255 scale[i, b])`` in the back-projection.
    channels : (d,) int64
        The channels that bin a pixel (:func:`bin_index`).
    lut : (d, 256) int64
        Each channel's bin of each value (:func:`channel_bins`).
    bins : int
        Bins per channel.
    s, r : int
        Window side (the template size) and the search radius, px.
    max_iter : int
        Most window moves.
    eps2 : int
        The search stops when a move's squared length is below this
        (``cv2.meanShift``: ``cvRound(epsilon^2)``).

    Returns
    -------
    win : (n, 2) int64
        Each final window's top-left ``(x, y)`` in its search region (``(r, r)``: no move).
    under : (n, B) float64
        The normalised histogram of the pixels under each final window.

    The search is ``cv2.meanShift``'s (OpenCV ``camshift.cpp``): the window moves by its
    back-projection's centroid minus half its side, rounded half to even (``cvRound``), clamped
    into the region, and stays where its back-projection is all 0. Integer moments make the
    centroid exact, so the windows are OpenCV's.
    """
    n = ox.shape[0]
    n_bins = scale.shape[1]
    side = s + 2 * r
    win = np.empty((n, 2), np.int64)
    under = np.zeros((n, n_bins))
    for i in prange(n):
        idx = np.empty((side, side), np.int64)
        back = np.empty((side, side), np.int64)
        for y in range(side):
            for x in range(side):
                b = 0
                for c in range(channels.shape[0]):
                    b = b * bins + lut[c, padded[oy[i] + y, ox[i] + x, channels[c]]]
                idx[y, x] = b
                back[y, x] = np.int64(np.rint(255.0 * scale[i, b]))
        wx = r
        wy = r
        for _ in range(max_iter):
            m00 = 0
            m10 = 0
            m01 = 0
            for y in range(s):
                for x in range(s):
                    v = back[wy + y, wx + x]
                    m00 += v
                    m10 += x * v
                    m01 += y * v
            if m00 == 0:
                break
            nx = min(max(wx + np.int64(np.rint(m10 / m00 - s * 0.5)), 0), side - s)
            ny = min(max(wy + np.int64(np.rint(m01 / m00 - s * 0.5)), 0), side - s)
            dx = nx - wx
            dy = ny - wy
            wx = nx
            wy = ny
            if dx * dx + dy * dy < eps2:
                break
        win[i, 0] = wx
        win[i, 1] = wy
        for y in range(s):
            for x in range(s):
                under[i, idx[wy + y, wx + x]] += 1.0
        for b in range(n_bins):
            under[i, b] /= s * s
    return win, under


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
        self._last_motion = np.zeros((0, 2))  # each target's last displacement
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
        self._last_motion = np.concatenate([self._last_motion, np.zeros((len(points), 2))])

    def _remove(self, keep: np.ndarray) -> None:
        self.templates = self.templates[keep]
        self.hists = self.hists[keep]
        self.age = self.age[keep]
        self._last_motion = self._last_motion[keep]

    def _predicted(self) -> np.ndarray:
        return self.points + self._last_motion

    # ------------------------------------------------------------------ one frame
    def _step(self, frame: np.ndarray) -> np.ndarray:
        p = self.params
        h, w = self.frame_shape[:2]
        s, r = self.template_size, self.radius
        side = s + 2 * r
        t0 = time.perf_counter()
        centers = np.rint(self.points).astype(np.int64)
        crop_tl = centers - s // 2 - r
        padded, ox, oy = padded_origins(self._convert(frame), crop_tl, side)
        channels = np.array(_SPACE[p.color_space][1], np.int64)
        # back-projection: each pixel scores its bin in the target's histogram (max 255)
        top = np.maximum(self.hists.max(1, keepdims=True), 1e-12)
        win_tl, under = shift_windows(
            padded,
            ox,
            oy,
            self.hists / top,
            channels,
            channel_bins(p.color_space, p.bins),
            p.bins,
            s,
            r,
            p.max_iter,
            int(np.rint(p.epsilon * p.epsilon)),
        )
        new = (crop_tl + win_tl + s // 2).astype(np.float64)
        new[:, 0] = np.clip(new[:, 0], 0, w - 1)
        new[:, 1] = np.clip(new[:, 1], 0, h - 1)
        # Bhattacharyya coefficient between the model and the histogram under the window
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
