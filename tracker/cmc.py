"""Camera-motion compensation: the global 2-D motion between consecutive frames.

Both papers track from static cameras. Drone and hand-held footage of crowds shakes, drifts,
turns and zooms, and a tracker that predicts with constant velocity in image coordinates then
searches in the wrong place. :class:`MotionCompensator` estimates, from the frames alone, the
2-D similarity (or affine) transform ``A`` that maps the previous frame's pixels onto the
current frame's, so a tracker can move its points, velocities and search windows with the
camera before it searches (:meth:`tracker.base.Tracker.step` does this when its parameters say
``cmc = True``).

The estimate follows BoT-SORT's global motion compensation (GMC, Aharon et al. 2022,
``sparseOptFlow``): on a downscaled grey frame, Shi-Tomasi corners of the previous frame are
tracked into the current one by pyramidal Lucas-Kanade, and RANSAC fits a 4-parameter
similarity (``cv2.estimateAffinePartial2D``) or a 6-parameter affine transform to the
matches. Corners on the people themselves move with the crowd, not the camera: the caller may
pass the tracked points, and corners within ``CMCParams.exclude`` templates of them are left
out (BoT-SORT masks its detections the same way). ``method="ecc"`` instead maximises the
enhanced correlation coefficient (``cv2.findTransformECC``, Evangelidis & Psarakis 2008) over
the frame, with the same discs masked out.

A frame that gives no estimate (a blank or constant frame, too few corners or inliers, ECC not
converging) falls back to the identity, never to an exception mid-sequence, and is counted in
:attr:`MotionCompensator.failures`.

>>> import cv2, numpy as np
>>> rng = np.random.default_rng(0)
>>> ground = cv2.GaussianBlur((rng.random((140, 180, 3)) * 255).astype(np.uint8), (0, 0), 1.5)
>>> cmc = MotionCompensator(CMCParams())
>>> cmc.estimate(ground[10:130, 10:170]).round(2).tolist()  # the first frame: identity
[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
>>> a = cmc.estimate(ground[13:133, 8:168])  # the camera moved 2 px left and 3 px up
>>> a[:, 2].round(0).tolist()  # the scene moves 2 px right and 3 px up in the image
[2.0, -3.0]
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from crowdsim.checks import require_choice, require_number

METHODS: tuple[str, ...] = ("sparse", "ecc")
MODELS: tuple[str, ...] = ("similarity", "affine", "translation", "auto")
AUTO_P: float = 1e-8
"""``model="auto"`` keeps the similarity only when a shift leaves its inliers' residuals larger
than chance would at this level (an F-test of the similarity's 2 extra parameters). The
test's Gaussian, independent residuals are not what Lucas-Kanade's corners have, so the level
was chosen by the estimate's error against the planted motion (``benchmarks/cmc_error.py``,
first 80 frames of every ``ucf9-shake`` and ``ucf9-drone`` spec, mean over the frame): 0.202,
0.197, 0.185 and 0.178 px a frame on ``ucf9-shake`` at 1e-2, 1e-3, 1e-5 and 1e-8, and
0.126-0.124 on ``ucf9-drone`` at all four (the similarity alone: 0.211 and 0.125; a shift
alone: 0.173 and 0.202)."""
IDENTITY: np.ndarray = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""The 2x3 identity transform (read-only)."""
IDENTITY.setflags(write=False)


@dataclass(frozen=True, kw_only=True)
class CMCParams:
    """Settings of the global motion estimate.

    Attributes
    ----------
    method : {"sparse", "ecc"}
        Sparse optical flow with RANSAC (BoT-SORT's GMC), or ECC over the whole frame,
        started from the phase-correlation peak. ECC is about 8x slower at 1280x720 (170
        against 21 ms per frame on a loaded 2-core machine) and, on texture as fine as a
        pixel of the downscaled frame, less accurate (0.6 against 0.06 px at the frame's
        corners on a test scene); it needs no corners.
    model : {"similarity", "affine", "translation", "auto"}
        4 degrees of freedom (shift, rotation, uniform zoom), 6 (affine), 2 (a shift: a
        camera that shakes but neither turns nor zooms), or ``"auto"``: the similarity,
        unless a shift explains its RANSAC inliers about as well (an F-test at
        :data:`AUTO_P` of what its rotation and zoom add), then that shift. Where the camera
        only shakes, rotation and zoom fitted to noisy corners move the frame's edges for
        nothing. Measured on the first 80 frames of each spec (``benchmarks/cmc_error.py``,
        error averaged over the frame, mean of the nine): on ``ucf9-shake`` 0.211 px a frame
        for the similarity, 0.173 for the shift, 0.178 for ``"auto"``; on ``ucf9-drone``,
        where the view also turns and zooms, 0.125, 0.202 and 0.124. ``"auto"`` errs least
        on both, but BQP tracked no better with it (within one run's noise, 10 sequences of
        the two suites; ``docs/camera-motion.md``), so the similarity stays the default. ECC
        fits a Euclidean transform for ``"similarity"`` and ``"auto"`` (its closest model:
        no zoom) and a shift for ``"translation"``.
    downscale : int
        The estimate runs on frames shrunk by this factor (BoT-SORT: 2); 1 on small frames.
    max_corners : int
        Shi-Tomasi corners of the previous frame to track. BoT-SORT takes 1000. On the
        shaken ucf9 specs (first 80 frames each, ``benchmarks/cmc_error.py``) 100 gave the
        error of 400 (mean 0.228 against 0.231 px a frame; per sequence within 0.04 px either
        way) in up to half the time: Lucas-Kanade, whose cost grows with the corners, is
        most of the estimate's.
    lk_window : int
        Side of Lucas-Kanade's search window, pixels at the downscaled size (OpenCV's
        default: 21). On the same specs a 15 px window on 2 levels lost 2 to 5 frames each
        (identity fallbacks) on the noisiest three, seq5, seq6 and seq9.
    lk_levels : int
        Pyramid levels above the frame for Lucas-Kanade (OpenCV's default: 3). The motion
        it can follow grows as ``lk_window / 2 * 2**lk_levels``.
    min_inliers : int
        Fewer RANSAC inliers than this, and the frame falls back to the identity.
    ransac_px : float
        RANSAC reprojection threshold, pixels at the downscaled size.
    max_shift_px : float
        An estimated translation larger than this (full-size pixels) is taken as a failure
        (identity): no camera moves that far between two frames of a tracking sequence.
    exclude : float
        Radius, in template sizes, of the disc around each tracked point whose corners are
        left out (0: none); :meth:`tracker.base.Tracker.step` passes it to :meth:`estimate`.
        Corners on people move with the crowd, and where a crowd walks one way and covers
        much of the frame, RANSAC's consensus is the crowd's motion. Measured on the
        shaken ucf9 specs (first 30 frames, sparse method, error of the estimated shift
        against the ground's): with 0, 1, 2 and 3 templates the x bias on the marathon seq3
        (2.7 px/frame crowd flow) was 1.26, 0.69, 0.12 and 0.04 px, on seq6 (people cover
        nearly the whole frame) 0.75, 0.79, 0.44 and -0.08 px but with 6 of 29 frames
        failing at 3; 2 is the largest radius that failed on no sequence.
    min_contrast : float
        A frame whose grey levels' standard deviation is below this is blank or constant: the
        estimate into it (and out of it) falls back to the identity.
    redetect : float
        1 (the default) detects corners on every frame, as BoT-SORT does. Below 1, corners
        are tracked forward, as a KLT tracker does: an estimate's RANSAC inliers, where
        Lucas-Kanade found them in the current frame, are the next estimate's corners, less
        those in the people's discs (``exclude``) or off the frame. Shi-Tomasi detects afresh
        only when fewer than ``redetect * max_corners`` (and ``min_inliers``) are left, after
        a frame without an estimate, after a view motion beyond ``redetect_px``, or when the
        kept corners give no estimate. Measured with 0.5 against 1 (``benchmarks/cmc_error.py``,
        first 80 frames of each spec; error averaged over the frame, mean of the nine):
        ``ucf9-shake`` 0.212 against 0.211 px a frame, ``ucf9-drone`` 0.121 against 0.125,
        the static ``ucf9`` 0.114 against 0.116 (spurious motion), the rendered crowd of
        ``tests/tracker/test_cmc.py`` under a shake of up to 17 px steps 0.095 against
        0.095, in 38-55 % less time (summed over the nine: 9 against 15 ms a frame on
        ``ucf9``, 10 against 17 on ``ucf9-drone``). But its worst frames are worse: a spec's
        worst frame erred more than 0.05 px more on 6 of the 27 specs (seq6 of
        ``ucf9-shake`` 2.03 against 1.16 px, its seq9 1.42 against 0.98 and seq1 0.27
        against 0.20, seq5 of all three suites by 0.18-0.27 px) and less on 2 (by 0.05 and
        0.06); 0.7, 0.8 and 0.9 likewise. So it stays an option.
    redetect_px : float
        With ``redetect`` below 1, a view motion larger than this (full-size pixels: the
        largest displacement the last estimate gives a corner of the frame) makes the next
        estimate detect afresh: corners carried over are Lucas-Kanade's positions, not
        corners of the new frame, and after a long step they follow less well. Without it,
        on the 17 px shake above, the error of the estimated shift at the frame's origin was
        0.148 px a frame against 0.130 when detecting on every frame; with it, 0.132. 1, 2
        and 4 px gave the same error within 0.006 px on the mean of each suite above.
    """

    method: str = "sparse"
    model: str = "similarity"
    downscale: int = 2
    max_corners: int = 100
    lk_window: int = 21
    lk_levels: int = 3
    min_inliers: int = 12
    ransac_px: float = 1.5
    max_shift_px: float = 64.0
    exclude: float = 2.0
    min_contrast: float = 1.0
    redetect: float = 1.0
    redetect_px: float = 2.0

    def __post_init__(self) -> None:
        own = "cmc"
        require_choice(own, "method", self.method, METHODS)
        require_choice(own, "model", self.model, MODELS)
        require_number(own, "downscale", self.downscale, lo=1, hi=8, integer=True)
        require_number(own, "max_corners", self.max_corners, lo=8, hi=20_000, integer=True)
        require_number(own, "lk_window", self.lk_window, lo=5, hi=101, integer=True)
        require_number(own, "lk_levels", self.lk_levels, lo=0, hi=6, integer=True)
        require_number(own, "min_inliers", self.min_inliers, lo=3, hi=10_000, integer=True)
        require_number(own, "ransac_px", self.ransac_px, lo=0.1, hi=20)
        require_number(own, "max_shift_px", self.max_shift_px, lo=1, hi=10_000)
        require_number(own, "exclude", self.exclude, lo=0, hi=20)
        require_number(own, "min_contrast", self.min_contrast, lo=0, hi=128)
        require_number(own, "redetect", self.redetect, lo=0, hi=1)
        require_number(own, "redetect_px", self.redetect_px, lo=0, hi=10_000)


def check_fields(owner: str, params: Any) -> None:
    """Validate the ``cmc`` and ``cmc_method`` fields of a tracker's parameter dataclass.

    Every detection-free tracker's parameters carry the two (``cmc: bool = False`` and
    ``cmc_method: str = "sparse"``); :class:`tracker.base.Tracker` reads them.

    >>> from types import SimpleNamespace
    >>> check_fields("P", SimpleNamespace(cmc=True, cmc_method="flow"))
    Traceback (most recent call last):
    ...
    ValueError: P.cmc_method must be one of ('sparse', 'ecc'), got 'flow'
    """
    require_choice(owner, "cmc", params.cmc, (True, False))
    require_choice(owner, "cmc_method", params.cmc_method, METHODS)


@functools.cache
def _disc_spans(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row ``dy = -r .. r`` of ``cv2.circle``'s filled disc of radius ``r``, the first
    and last ``dx`` it covers (``lo > hi``: none). Drawn once per radius by OpenCV itself, so
    stamping these spans marks exactly the pixels ``cv2.circle`` would at any integer centre."""
    import cv2

    stamp = np.zeros((2 * r + 1, 2 * r + 1), np.uint8)
    cv2.circle(stamp, (r, r), r, 1, -1)
    lo = np.full(2 * r + 1, 1, np.int64)
    hi = np.zeros(2 * r + 1, np.int64)
    for row in range(2 * r + 1):
        on = np.flatnonzero(stamp[row])
        if len(on):
            assert on[-1] - on[0] + 1 == len(on), "a filled circle's rows are spans"
            lo[row], hi[row] = on[0] - r, on[-1] - r
    return lo, hi


@njit(cache=True, nogil=True)
def _stamp_discs(mask, centres, lo, hi):
    """Zero the disc spans ``lo, hi`` (:func:`_disc_spans`) around every centre, clipped to
    ``mask``: the corner mask of all tracked people in one compiled pass."""
    h, w = mask.shape
    r = (lo.shape[0] - 1) // 2
    for i in range(centres.shape[0]):
        cx = centres[i, 0]
        cy = centres[i, 1]
        for row in range(lo.shape[0]):
            y = cy + row - r
            if y < 0 or y >= h or lo[row] > hi[row]:
                continue
            x0 = max(cx + lo[row], 0)
            x1 = min(cx + hi[row], w - 1)
            for x in range(x0, x1 + 1):
                mask[y, x] = 0


def fit_shift(
    src: np.ndarray, dst: np.ndarray, threshold: float, rounds: int = 3
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The shift that moves ``src`` onto ``dst`` ``(n, 2)``, robustly: from the median
    displacement, ``rounds`` times the mean of the displacements within ``threshold`` px of
    the last estimate (each axis). Returns the ``(2, 3)`` transform and the ``(n, 1)`` uint8
    inlier flags (``None, None`` when none is left).

    >>> src = np.array([[0.0, 0], [5, 5], [9, 1], [3, 7]])
    >>> a, inl = fit_shift(src, src + [[2.0, -1], [2.1, -1], [1.9, -1], [30, 30]], 1.0)
    >>> a.round(6).tolist(), inl.ravel().tolist()
    ([[1.0, 0.0, 2.0], [0.0, 1.0, -1.0]], [1, 1, 1, 0])
    """
    d = np.asarray(dst, np.float64).reshape(-1, 2) - np.asarray(src, np.float64).reshape(-1, 2)
    if len(d) == 0:
        return None, None
    shift = np.median(d, axis=0)
    keep = np.ones(len(d), bool)
    for _ in range(rounds):
        keep = (np.abs(d - shift) < threshold).all(axis=1)
        if not keep.any():
            return None, None
        shift = d[keep].mean(axis=0)
    a = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    return a, keep.astype(np.uint8)[:, None]


def prefer_shift(a: np.ndarray, src: np.ndarray, dst: np.ndarray, p: float) -> np.ndarray:
    """``a`` (a similarity fitted to the inliers ``src -> dst``), or the inliers' mean shift
    when the similarity's rotation and zoom do not reduce the residuals significantly: the F
    statistic of their 2 parameters against ``2n - 4`` residual degrees of freedom stays below
    its upper ``p`` quantile (``F(2, m)``'s is ``m / 2 * (p ** (-2 / m) - 1)``).

    >>> src = np.array([[0.0, 0], [100, 0], [0, 100], [100, 100], [50, 50], [20, 80]])
    >>> noise = np.array([[0.1, 0], [-0.1, 0.1], [0, -0.1], [0.1, 0.1], [0, 0], [-0.1, 0]])
    >>> prefer_shift(np.eye(2, 3), src, src + 3 + noise, 0.01)[:, :2].tolist()  # a shift
    [[1.0, 0.0], [0.0, 1.0]]
    >>> zoomed = np.array([[1.05, 0, 0], [0, 1.05, 0]])
    >>> bool((prefer_shift(zoomed, src, src * 1.05 + noise, 0.01) == zoomed).all())  # kept
    True
    """
    n = len(src)
    m = 2 * n - 4
    if m <= 0:
        return a
    shift = (dst - src).mean(axis=0)
    rss_shift = float(((src + shift - dst) ** 2).sum())
    rss_sim = float(((src @ a[:, :2].T + a[:, 2] - dst) ** 2).sum())
    if rss_sim <= 0.0:  # an exact fit: the rotation and zoom matter if the shift misses
        significant = rss_shift > 0.0
    else:
        f = (rss_shift - rss_sim) / 2.0 / (rss_sim / m)
        significant = f >= m / 2.0 * (p ** (-2.0 / m) - 1.0)
    return a if significant else np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])


def warp_points(a: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(n, 2)`` points moved by the 2x3 transform ``a`` (``p -> A [p; 1]``)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return pts @ a[:, :2].T + a[:, 2]


def warp_vectors(a: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``(n, 2)`` displacement vectors (velocities) turned and scaled by ``a``'s linear part."""
    vec = np.asarray(vectors, dtype=np.float64).reshape(-1, 2)
    return vec @ a[:, :2].T


class MotionCompensator:
    """Global motion between consecutive frames (module docstring).

    Call :meth:`estimate` once per frame, in order. The first frame (and the first after
    :meth:`reset`) gives the identity.

    Attributes
    ----------
    frames : int
        Frames given to :meth:`estimate`.
    failures : int
        Frames after the first whose estimate fell back to the identity.
    seconds : float
        Time spent estimating.
    last : (2, 3) float64
        The last transform returned.
    """

    def __init__(self, params: CMCParams | None = None) -> None:
        self.params = params if params is not None else CMCParams()
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame (the next estimate is the identity)."""
        self._prev: np.ndarray | None = None
        self._prev_contrast = 0.0
        # the last estimate's inlier corners, in the previous frame (downscaled pixels)
        self._corners: np.ndarray | None = None
        self.frames = 0
        self.failures = 0
        self.seconds = 0.0
        self.last = IDENTITY.copy()

    def stats(self) -> dict[str, float]:
        """``{"cmc_frames", "cmc_failures", "cmc_ms"}``: the counts and ms per frame."""
        return {
            "cmc_frames": self.frames,
            "cmc_failures": self.failures,
            "cmc_ms": 1e3 * self.seconds / max(self.frames, 1),
        }

    def estimate(
        self, frame: np.ndarray, exclude: np.ndarray | None = None, exclude_px: float = 0.0
    ) -> np.ndarray:
        """The ``(2, 3)`` transform from the previous frame's pixels to ``frame``'s.

        Parameters
        ----------
        frame : (H, W, 3) or (H, W) uint8
            The current frame.
        exclude : (n, 2) float, optional
            Points in the *previous* frame (the tracked people) whose surroundings hold no
            camera motion: corners within ``exclude_px`` of them are not used.
        exclude_px : float
            Radius of the excluded discs, full-size pixels.
        """
        import cv2

        t0 = time.perf_counter()
        p = self.params
        grey = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        if p.downscale > 1:
            h, w = grey.shape
            size = (max(1, w // p.downscale), max(1, h // p.downscale))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        prev, self._prev = self._prev, grey
        # each frame's contrast once, kept for the next estimate (numpy's std of both frames
        # took 0.07 ms of seq8's 1.0-1.4 ms estimate; OpenCV's of one, 0.006)
        contrast = float(cv2.meanStdDev(grey)[1][0, 0])
        prev_contrast, self._prev_contrast = self._prev_contrast, contrast
        # corners carry over only from an estimate into the frame before this one
        kept, self._corners = self._corners, None
        self.frames += 1
        a = IDENTITY.copy()
        if prev is not None:
            if prev.shape != grey.shape:
                raise ValueError(
                    f"cmc: frame size changed from {prev.shape[::-1]} to {grey.shape[::-1]}"
                )
            found = None
            # a blank or constant frame (either of the two) holds no motion to measure
            if min(prev_contrast, contrast) >= p.min_contrast:
                mask = self._mask(prev.shape, exclude, exclude_px)
                if p.method == "sparse":
                    kept = self._still_usable(kept, mask, prev.shape)
                    found = self._sparse(prev, grey, mask, kept)
                    if found is None and kept is not None:  # the kept corners failed: detect
                        found = self._sparse(prev, grey, mask)
                else:
                    found = self._ecc(prev, grey, mask)
            if found is None or not np.isfinite(found).all():
                self.failures += 1
                self._corners = None
            else:
                found[:, 2] *= p.downscale
                if np.abs(found[:, 2]).max() > p.max_shift_px:
                    self.failures += 1
                    self._corners = None
                else:
                    a = found
        self.last = a
        self.seconds += time.perf_counter() - t0
        return a

    def _mask(
        self, shape: tuple[int, ...], exclude: np.ndarray | None, exclude_px: float
    ) -> np.ndarray | None:
        """``(h, w)`` uint8 mask of the downscaled previous frame, 0 within ``exclude_px`` of
        the ``exclude`` points; ``None`` when nothing is excluded or nothing would be left."""
        p = self.params
        if exclude is None or len(exclude) == 0 or exclude_px <= 0:
            return None
        mask = np.full(shape, 255, np.uint8)
        r = max(1, int(round(exclude_px / p.downscale)))
        pts = np.asarray(exclude, dtype=np.float64).reshape(-1, 2) / p.downscale
        pts = pts[np.isfinite(pts).all(axis=1)]
        # far outside the frame a disc leaves no mark (and int64 must hold the centre)
        h, w = shape[:2]
        near = (np.abs(pts[:, 0]) < w + r + 1) & (np.abs(pts[:, 1]) < h + r + 1)
        _stamp_discs(mask, np.rint(pts[near]).astype(np.int64), *_disc_spans(r))
        return mask if mask.any() else None

    def _still_usable(
        self, kept: np.ndarray | None, mask: np.ndarray | None, shape: tuple[int, ...]
    ) -> np.ndarray | None:
        """The tracked-forward corners ``kept`` that lie on the frame and outside the
        people's discs; ``None`` when fewer than ``redetect * max_corners`` are left, or when
        the last estimate moved a corner of the frame more than ``redetect_px``."""
        p = self.params
        if kept is None or p.redetect >= 1.0:
            return None
        h, w = shape[:2]
        box = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]) * p.downscale
        if np.abs(warp_points(self.last, box) - box).max() > p.redetect_px:
            return None
        xy = np.rint(kept.reshape(-1, 2)).astype(np.int64)
        ok = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
        if mask is not None:
            ok[ok] = mask[xy[ok, 1], xy[ok, 0]] != 0
        n = int(ok.sum())
        if n < max(p.min_inliers, p.redetect * p.max_corners):
            return None
        return np.ascontiguousarray(kept[ok])

    def _sparse(
        self,
        prev: np.ndarray,
        grey: np.ndarray,
        mask: np.ndarray | None,
        kept: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """The fit from ``kept`` corners (:meth:`_still_usable`), or from corners detected
        in ``prev`` outside ``mask``; keeps its inliers, moved into ``grey``, for the next."""
        import cv2

        p = self.params
        corners = kept
        if corners is None:
            corners = cv2.goodFeaturesToTrack(
                prev,
                maxCorners=p.max_corners,
                qualityLevel=0.01,
                minDistance=1,
                blockSize=3,
                mask=mask,
            )
        if corners is None or len(corners) < p.min_inliers:
            return None
        win = (p.lk_window, p.lk_window)
        moved, status, _ = cv2.calcOpticalFlowPyrLK(
            prev, grey, corners, None, winSize=win, maxLevel=p.lk_levels
        )
        ok = status.ravel() == 1
        src, dst = corners[ok].reshape(-1, 2), moved[ok].reshape(-1, 2)
        if len(src) < p.min_inliers:
            return None
        if p.model == "translation":
            a, inliers = fit_shift(src, dst, p.ransac_px)
        else:
            fit = cv2.estimateAffine2D if p.model == "affine" else cv2.estimateAffinePartial2D
            a, inliers = fit(src, dst, method=cv2.RANSAC, ransacReprojThreshold=p.ransac_px)
        if a is None or inliers is None or int(inliers.sum()) < p.min_inliers:
            return None
        keep = inliers.ravel() == 1
        a = a.astype(np.float64)
        if p.model == "auto":
            a = prefer_shift(a, src[keep], dst[keep], AUTO_P)
        self._corners = dst[keep].reshape(-1, 1, 2)
        return a

    def _ecc(
        self, prev: np.ndarray, grey: np.ndarray, mask: np.ndarray | None
    ) -> np.ndarray | None:
        import cv2

        p = self.params
        mode = {"affine": cv2.MOTION_AFFINE, "translation": cv2.MOTION_TRANSLATION}.get(
            p.model, cv2.MOTION_EUCLIDEAN
        )
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-5)
        # ECC converges only within a pixel or two of its start and the camera may move
        # several: start from the translation of the phase correlation peak (from the
        # identity it did not converge on a test scene with 7 px camera steps)
        window = cv2.createHanningWindow((prev.shape[1], prev.shape[0]), cv2.CV_32F)
        (dx, dy), _ = cv2.phaseCorrelate(prev.astype(np.float32), grey.astype(np.float32), window)
        warp = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]], np.float32)
        try:
            _, warp = cv2.findTransformECC(prev, grey, warp, mode, criteria, mask, 1)
        except cv2.error:  # did not converge
            return None
        # grey(warp(x)) ~ prev(x): the warp maps the previous frame's pixels onto this one's
        return warp.astype(np.float64)
