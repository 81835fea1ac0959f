"""Appearance models: score every candidate centre of every target at once.

Two interchangeable models share the :class:`AppearanceModel` contract:

* :class:`KCFAppearance` -- one multi-channel (BGR) correlation filter per target, trained in
  the Fourier domain by ridge regression (paper 1, Eq. 4-5, after Henriques et al.'s KCF with a
  linear kernel). All targets are handled as one stacked ``(n, C, W, W)`` array and one batched
  real FFT; there is no per-target loop.
* :class:`NCCAppearance` -- a colour template per target scored with ``cv2.matchTemplate``
  (normalised cross-correlation), the appearance model of the papers' NCC baselines.

Geometry. With template size ``s`` px and candidate radius ``r`` px the search window has side
``W = s + 2 r`` and is centred on the integer search centre ``c``. A score map has shape
``(n, 2r+1, 2r+1)``; ``scores[i, r + dy, r + dx]`` scores the candidate centre
``c_i + (dx, dy)``. Higher is better; scores are about 1 at a perfect match.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod

import cv2
import numpy as np
import scipy.fft
from numba import njit, prange
from numpy.lib.stride_tricks import sliding_window_view

from crowdsim.checks import require_memory
from tracker.threads import current_threads, in_chunks

KCF_KERNELS: tuple[str, ...] = ("gaussian", "linear")


ROWS_PER_THREAD: int = 256
"""The KCF model's numpy passes over its targets (the training division, the responses'
crop) run in chunks of at least this many targets on the tracker's threads
(:func:`tracker.threads.in_chunks`; numpy releases the GIL): one chunk per row range, the
same numpy loop on each, so the values are those of one call. At 7,850 targets the complex
division of training took 23 ms on one thread, 11 on two."""


def _check_frame(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(
            f"frame must be an (H, W, 3) uint8 BGR image, got {frame.shape} {frame.dtype}"
        )
    return frame


def extract_patches(frame: np.ndarray, top_left: np.ndarray, size: int) -> np.ndarray:
    """Gather square patches, replicating the border for parts outside the image.

    Parameters
    ----------
    frame : (H, W, C) array
    top_left : (n, 2) int
        ``(x, y)`` pixel of each patch's top-left corner; may lie outside the image.
    size : int
        Patch side in pixels.

    Returns
    -------
    (n, C, size, size) array of ``frame.dtype`` (a fresh copy).

    >>> f = np.arange(16, dtype=np.uint8).reshape(4, 4, 1)
    >>> extract_patches(f, np.array([[-1, 0]]), 2)[0, 0]
    array([[0, 0],
           [4, 4]], dtype=uint8)
    """
    padded, x, y = padded_origins(frame, top_left, size)
    view = sliding_window_view(padded, (size, size), axis=(0, 1))  # (H', W', C, size, size)
    return view[y, x]


def padded_origins(
    frame: np.ndarray, top_left: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`extract_patches` gathers from, for kernels that read the patches in place.

    Returns the frame with ``size`` replicated border pixels on every side, ``(H + 2 size,
    W + 2 size, C)``, and the ``x`` and ``y`` ``(n,)`` int64 of each patch's top-left corner
    in it (clipped so that every patch lies inside): patch ``i`` is
    ``padded[y[i]:y[i] + size, x[i]:x[i] + size]``.
    """
    top_left = np.asarray(top_left, dtype=np.int64).reshape(-1, 2)
    h, w = frame.shape[:2]
    pad = size
    padded = cv2.copyMakeBorder(frame, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    if padded.ndim == 2:
        padded = padded[:, :, None]
    x = np.clip(top_left[:, 0] + pad, 0, w + 2 * pad - size)
    y = np.clip(top_left[:, 1] + pad, 0, h + 2 * pad - size)
    return padded, x, y


@functools.cache
def pairwise_plan(n: int) -> tuple[np.ndarray, np.ndarray]:
    """How numpy's ``add.reduce`` sums ``n`` contiguous float32 values (``pairwise_sum``):
    halves (each a multiple of 8) down to blocks of at most 128, each block summed by
    :func:`_block_sum`, the halves' sums then added pairwise. Returns the blocks ``(L, 2)``
    (start, length) in order and the additions ``(K, 3)`` (node, left, right) in the order
    numpy makes them; nodes ``0..L-1`` are the blocks, the last node is the sum. A plan
    instead of the recursion: numba's cache cannot hold recursive functions a parallel
    kernel calls (the cached kernel crashed).

    >>> blocks, adds = pairwise_plan(400)
    >>> blocks.tolist(), adds.tolist()
    ([[0, 96], [96, 104], [200, 96], [296, 104]], [[4, 0, 1], [5, 2, 3], [6, 4, 5]])
    """
    blocks: list[tuple[int, int]] = []
    adds: list[tuple[int, int, int]] = []

    def split(lo: int, m: int) -> int:
        if m <= 128:
            blocks.append((lo, m))
            return -len(blocks)  # numbered once every block is known
        half = m // 2
        half -= half % 8
        left, right = split(lo, half), split(lo + half, m - half)
        adds.append((len(adds), left, right))
        return len(adds) - 1

    split(0, int(n))
    nb = len(blocks)

    def node(v: int) -> int:  # blocks 0..nb-1, then the additions
        return -v - 1 if v < 0 else nb + v

    plan = [(nb + d, node(a), node(b)) for d, a, b in adds]
    out = np.array(blocks, np.int64).reshape(-1, 2), np.array(plan, np.int64).reshape(-1, 3)
    for a in out:
        a.flags.writeable = False  # shared by every caller (cached)
    return out


@njit(cache=True, nogil=True, inline="always")
def _block_sum(a, lo, n):
    """numpy's sum of one block of ``pairwise_sum`` (``n <= 128``), in ``a``'s float type: in
    order under 8 values, else eight interleaved accumulators, then the rest in order."""
    if n < 8:
        res = a.dtype.type(0.0)
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    end = n - n % 8
    while i < end:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, nogil=True, inline="always")
def _planned_sum(a, blocks, adds, work):
    """The sum of ``a`` by :func:`pairwise_plan`'s ``(blocks, adds)``; ``work`` holds a
    value per node."""
    for b in range(blocks.shape[0]):
        work[b] = _block_sum(a, blocks[b, 0], blocks[b, 1])
    for d in range(adds.shape[0]):
        work[adds[d, 0]] = work[adds[d, 1]] + work[adds[d, 2]]
    return work[blocks.shape[0] + adds.shape[0] - 1]


@njit(cache=True, nogil=True)
def numpy_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` bit for bit as numpy sums a contiguous float array (its
    ``pairwise_sum``: halves, each a multiple of 8, down to blocks of at most 128 values,
    :func:`_block_sum`), for compiled code that must give numpy's value; one segment's plan
    walked with a stack instead of :func:`pairwise_plan`'s table."""
    if n <= 128:
        return _block_sum(a, lo, n)
    depth = 64  # each level halves n: far more than an int64 length needs
    start = np.empty(depth, np.int64)
    size = np.empty(depth, np.int64)
    stage = np.zeros(depth, np.int64)  # 0: left half next, 1: right half next, 2: add
    sums = np.empty(depth, a.dtype)
    start[0], size[0] = lo, n
    top = 0
    held = 0
    while top >= 0:
        m = size[top]
        if m <= 128:
            sums[held] = _block_sum(a, start[top], m)
            held += 1
            top -= 1
            continue
        half = m // 2
        half -= half % 8
        if stage[top] == 2:  # both halves summed: numpy adds left + right
            sums[held - 2] = sums[held - 2] + sums[held - 1]
            held -= 1
            top -= 1
            continue
        first = stage[top] == 0
        stage[top] += 1
        top += 1
        start[top] = start[top - 1] if first else start[top - 1] + half
        size[top] = half if first else m - half
        stage[top] = 0
    return sums[0]


@njit(cache=True, nogil=True)
def _pairwise_sum(a, blocks, adds):
    """``a``'s float32 sum as numpy's (``pairwise_plan(len(a))``)."""
    return _planned_sum(a, blocks, adds, np.empty(blocks.shape[0] + adds.shape[0], np.float32))


@njit(cache=True, nogil=True, parallel=True)
def _window_patches(frame, top_left, size, window, blocks, adds, work, out):
    """The KCF windows, one patch per loop iteration: ``out[i, c]`` is
    ``float32(frame[y0 + v, x0 + u, c])`` with coordinates clamped to the image
    (:func:`extract_patches`: corners clipped as there, border replicated), less its mean,
    times ``window``, written into the C-order float32 array the FFT takes.

    Each patch is centred and windowed while it is still in the cache: the same values, bit
    for bit, as numpy's ``x.reshape(n, c, -1).mean(axis=2)`` (``blocks`` and ``adds`` are
    :func:`pairwise_plan` ``(size * size)``, ``work`` a row of node values per patch) and
    ``x -= mean; x *= window`` (two roundings per value), which were two more passes over
    all the patches (at 7,850 windows of 20 px, 38 MB each).
    """
    h, w, nc = frame.shape
    area = size * size
    for i in prange(top_left.shape[0]):
        x0 = min(max(top_left[i, 0], -size), w)
        y0 = min(max(top_left[i, 1], -size), h)
        if nc == 3:
            # colour frames: each pixel's three bytes read once, into the three planes (half
            # the time of a pass per channel at 7,845 windows of 24 px)
            for v in range(size):
                y = min(max(y0 + v, 0), h - 1)
                for u in range(size):
                    x = min(max(x0 + u, 0), w - 1)
                    out[i, 0, v, u] = np.float32(frame[y, x, 0])
                    out[i, 1, v, u] = np.float32(frame[y, x, 1])
                    out[i, 2, v, u] = np.float32(frame[y, x, 2])
        else:
            inside = x0 >= 0 and x0 + size <= w  # the columns need no clamping
            for c in range(nc):
                for v in range(size):
                    y = min(max(y0 + v, 0), h - 1)
                    if inside:
                        for u in range(size):
                            out[i, c, v, u] = np.float32(frame[y, x0 + u, c])
                    else:
                        for u in range(size):
                            out[i, c, v, u] = np.float32(frame[y, min(max(x0 + u, 0), w - 1), c])
        for c in range(nc):
            m = _planned_sum(out[i, c].reshape(area), blocks, adds, work[i]) / np.float32(area)
            for v in range(size):
                for u in range(size):
                    out[i, c, v, u] = (out[i, c, v, u] - m) * window[v, u]


def hann2d(size: int) -> np.ndarray:
    """``(size, size)`` float32 cosine (Hann) window, as KCF multiplies its patches by."""
    win = np.hanning(size + 2)[1:-1]
    return np.outer(win, win).astype(np.float32)


def gaussian_label(size: int, sigma: float) -> np.ndarray:
    """``(size, size)`` Gaussian regression target ``y`` of Eq. 4, peak 1 at ``size // 2``."""
    d = np.arange(size) - size // 2
    g = np.exp(-0.5 * (d / sigma) ** 2)
    return np.outer(g, g).astype(np.float32)


@njit(cache=True, nogil=True, parallel=True)
def _cross_spectrum(xf, zf, out, scale):
    """``out[i] = sum_c conj(xf[i, c]) zf[i, c]`` over ``(n, C, F)`` spectra, one target per
    loop iteration (the same result for any number of threads); then, with ``scale > 0``,
    divided by the float32 ``scale`` exactly as numpy divides a complex64 array by a float32
    number (its complex division with a zero imaginary part: ``(re + im * 0) * (1 / scale)``
    and ``(im - re * 0) * (1 / scale)`` in float32), without a second pass over the array."""
    zero = np.float32(0.0)
    inv = np.float32(1.0) / scale if scale > 0 else np.float32(1.0)
    for i in prange(xf.shape[0]):
        # channel by channel over contiguous rows (vectorised), each frequency still summed
        # in channel order
        for f in range(xf.shape[2]):
            out[i, f] = np.conj(xf[i, 0, f]) * zf[i, 0, f]
        for c in range(1, xf.shape[1]):
            for f in range(xf.shape[2]):
                out[i, f] += np.conj(xf[i, c, f]) * zf[i, c, f]
        if scale > 0:
            for f in range(xf.shape[2]):
                re = out[i, f].real
                im = out[i, f].imag
                out[i, f] = complex((re + im * zero) * inv, (im - re * zero) * inv)


@njit(cache=True, nogil=True, parallel=True)
def _blend_rows(dst, rows, src, rate):
    """``dst[rows[q]] = (1 - rate) dst[rows[q]] + rate src[q]`` in place, one row per loop
    iteration (the running-average model update of :meth:`KCFAppearance.update`)."""
    keep = 1 - rate
    for q in prange(rows.shape[0]):
        r = rows[q]
        for e in range(dst.shape[1]):
            dst[r, e] = keep * dst[r, e] + rate * src[q, e]


@njit(cache=True, nogil=True)
def _compact_rows(a, index):
    """``a[q] = a[index[q]]`` for a strictly ascending ``index``, in place: a row only ever
    moves towards the front, over rows already moved or dropped (:meth:`KCFAppearance.keep`
    without a copy of the models)."""
    for q in range(index.shape[0]):
        r = index[q]
        if r != q:
            for e in range(a.shape[1]):
                a[q, e] = a[r, e]


def _appended(buf: np.ndarray | None, rows: np.ndarray, new: np.ndarray):
    """``rows`` with ``new`` appended, as the leading rows of ``buf`` (grown by a quarter when
    full, so appending a few targets a frame does not copy every model each time): returns
    ``(rows, buf)``. ``rows`` must be ``buf``'s leading rows (a view); anything else (a copy
    of the tracker, say) starts a new buffer."""
    n, m = rows.shape[0], new.shape[0]
    leading = buf is not None and rows.base is buf and rows.ctypes.data == buf.ctypes.data
    if not leading or buf.shape[0] < n + m:
        grown = np.empty((n + m + (n + m) // 4 + 16,) + rows.shape[1:], rows.dtype)
        grown[:n] = rows
        buf = grown
    buf[n : n + m] = new
    return buf[: n + m], buf


def _channel_sum(a: np.ndarray) -> np.ndarray:
    """Sum over axis 1 of an ``(n, C, ...)`` array (faster than ``sum`` for small ``C``)."""
    out = a[:, 0].copy()
    for c in range(1, a.shape[1]):
        out += a[:, c]
    return out


class AppearanceModel(ABC):
    """Per-target appearance models kept as stacked arrays (one row per target).

    Targets are appended with :meth:`add`, dropped with :meth:`keep`, scored with
    :meth:`scores` and refreshed with :meth:`update`. ``n`` is the number of targets.
    """

    def __init__(self, template_size: int, radius: int, update_threshold: float = 0.6):
        if template_size < 2:
            raise ValueError(f"template_size must be >= 2 px, got {template_size!r}")
        if radius < 1:
            raise ValueError(f"radius must be >= 1 px, got {radius!r}")
        self.template_size = int(template_size)
        self.radius = int(radius)
        self.window = self.template_size + 2 * self.radius
        self.update_threshold = float(update_threshold)

    @property
    @abstractmethod
    def n(self) -> int:
        """Number of targets currently modelled."""

    @abstractmethod
    def add(self, frame: np.ndarray, centers: np.ndarray) -> None:
        """Train models for new targets centred at ``centers`` ``(m, 2)`` int px; appended."""

    @abstractmethod
    def keep(self, index: np.ndarray) -> None:
        """Keep only the targets ``index`` ``(n',)`` (in that order)."""

    @abstractmethod
    def scores(self, frame: np.ndarray, centers: np.ndarray) -> np.ndarray:
        """``(n, 2r+1, 2r+1)`` float32 scores of the candidates around ``centers`` ``(n, 2)``."""

    @abstractmethod
    def update(self, frame: np.ndarray, centers: np.ndarray, confidence: np.ndarray) -> None:
        """Refresh the models at the selected ``centers`` where ``confidence >= threshold``."""


KCF_WORKING_SET = 3.5
"""A KCF tracker's working set over its models' own bytes (``xf`` and ``alphaf``): the peak
that ``tracemalloc`` saw during a BQP tracker's first step, models included, was 3.0-3.5
times the models (50-400 targets, 64-256 px templates, 1920x1080 frames)."""


class KCFAppearance(AppearanceModel):
    """Multi-channel linear correlation filter per target, batched in the Fourier domain.

    Eq. 4 with a linear kernel has the closed form (Henriques et al., KCF)
    ``alpha_hat = y_hat / (k_hat^{xx} + lambda)``, ``k_hat^{xz} = sum_c conj(x_hat_c) z_hat_c / N``
    and the response over every cyclic shift of the search window is
    ``f(z) = IFFT(alpha_hat * k_hat^{xz})`` (Eq. 5 gives ``c_a = -f``). Features are the B, G, R
    channels scaled to [0, 1], mean-removed per patch and channel, times a Hann window.
    ``kernel="gaussian"`` uses KCF's Gaussian kernel correlation instead of the linear one
    (``k^{xz} = exp(-max(0, |x|^2 + |z|^2 - 2 x*z) / (sigma^2 N))``); on our synthetic crowds
    it was no more accurate and costs two more FFTs, so linear (Eq. 4 as written) is default.

    Stored per target: ``xf (n, C, W, W//2+1)`` complex64 model patch spectrum and
    ``alphaf (n, W, W//2+1)`` complex64 dual coefficients.
    """

    def __init__(
        self,
        template_size: int,
        radius: int,
        update_threshold: float = 0.6,
        lam: float = 1e-4,
        learning_rate: float = 0.05,
        label_sigma: float = 0.1,
        kernel: str = "linear",
        kernel_sigma: float = 0.2,
        target_window: float = 0.0,
        workers: int | None = None,
    ):
        super().__init__(template_size, radius, update_threshold)
        if not lam > 0:
            raise ValueError(f"lam must be > 0, got {lam!r}")
        if not 0 < learning_rate <= 1:
            raise ValueError(f"learning_rate must be in (0, 1], got {learning_rate!r}")
        if kernel not in KCF_KERNELS:
            raise ValueError(f"kernel must be one of {KCF_KERNELS}, got {kernel!r}")
        if not kernel_sigma > 0:
            raise ValueError(f"kernel_sigma must be > 0, got {kernel_sigma!r}")
        self.lam = float(lam)
        self.learning_rate = float(learning_rate)
        self.kernel = kernel
        self.kernel_sigma = float(kernel_sigma)
        self.workers = None if workers is None else int(workers)
        w = self.window
        self._hann_scaled = hann2d(w) * np.float32(1.0 / 255.0)
        self._train_window = self._hann_scaled
        if target_window > 0:
            # Hann window of ~target_window template sizes, zero outside: the filter learns the
            # person, not the static ground around it (which a wide window would track)
            tw = min(w, max(3, int(round(target_window * self.template_size))))
            inner = np.zeros((w, w), np.float32)
            o = (w - tw) // 2
            inner[o : o + tw, o : o + tw] = hann2d(tw)
            self._train_window = inner * np.float32(1.0 / 255.0)
        sigma = max(0.5, label_sigma * self.template_size)
        self._yf = scipy.fft.rfft2(gaussian_label(w, sigma)).astype(np.complex64)
        wf = w // 2 + 1
        # Parseval weights of the half spectrum: interior columns stand for two
        colw = np.full(wf, 2.0, np.float32)
        colw[0] = 1.0
        if w % 2 == 0:
            colw[-1] = 1.0
        self._colw = colw
        self.xf = np.zeros((0, 3, w, wf), np.complex64)
        self.alphaf = np.zeros((0, w, wf), np.complex64)
        # the models are the leading rows of these (see _appended)
        self._xf_buf: np.ndarray | None = None
        self._alphaf_buf: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.xf.shape[0]

    def _workers(self) -> int:
        """FFT threads: ``workers``, or the tracker's threads (:mod:`tracker.threads`)."""
        return self.workers if self.workers is not None else current_threads()

    def _features(self, frame: np.ndarray, centers: np.ndarray, train: bool = False) -> np.ndarray:
        """``(n, C, W, W//2+1)`` spectra of the windows centred at ``centers``.

        Training windows use the narrower target window (see ``target_window``).
        """
        centers = np.asarray(centers, dtype=np.int64).reshape(-1, 2)
        w = self.window
        n, c = len(centers), frame.shape[2]
        # channels first, C order: the reductions and FFTs below are ~10x faster on it
        x = np.empty((n, c, w, w), np.float32)
        window = self._train_window if train else self._hann_scaled
        blocks, adds = pairwise_plan(w * w)
        work = np.empty((n, len(blocks) + len(adds)), np.float32)
        tl = np.ascontiguousarray(centers - w // 2)
        _window_patches(frame, tl, w, window, blocks, adds, work, x)
        return scipy.fft.rfft2(x, axes=(-2, -1), workers=self._workers())

    def _energy(self, xf: np.ndarray) -> np.ndarray:
        """``(n,)`` squared norm of the windows from their half spectra (Parseval)."""
        p = _channel_sum(xf.real**2 + xf.imag**2)
        return (p * self._colw).sum(axis=(1, 2)) / np.float32(self.window**2)

    def _kernel_f(self, xf: np.ndarray, zf: np.ndarray) -> np.ndarray:
        """Spectrum ``k_hat^{xz}`` of the kernel correlation over all cyclic shifts."""
        w = self.window
        numel = np.float32(w * w * xf.shape[1])
        n, c = xf.shape[:2]
        cross = np.empty((n,) + xf.shape[2:], np.complex64)
        linear = self.kernel == "linear"
        _cross_spectrum(
            xf.reshape(n, c, -1),
            np.ascontiguousarray(zf).reshape(n, c, -1),
            cross.reshape(n, -1),
            numel if linear else np.float32(0.0),
        )
        if linear:  # divided by numel in the pass above
            return cross
        xz = scipy.fft.irfft2(cross, s=(w, w), axes=(-2, -1), workers=self._workers())
        d = self._energy(xf)[:, None, None] + self._energy(zf)[:, None, None] - 2.0 * xz
        k = np.exp(-np.maximum(d, 0.0) / (numel * np.float32(self.kernel_sigma**2)))
        return scipy.fft.rfft2(k.astype(np.float32), axes=(-2, -1), workers=self._workers())

    def _train(self, xf: np.ndarray) -> np.ndarray:
        """``yf / (k_hat^{xx} + lambda)``: the model's dual coefficients (complex64)."""
        alphaf = self._kernel_f(xf, xf).astype(np.complex64, copy=False)
        lam = np.float32(self.lam)

        def divide(lo: int, hi: int) -> None:  # numpy's complex division, in place
            np.add(alphaf[lo:hi], lam, out=alphaf[lo:hi])
            np.divide(self._yf, alphaf[lo:hi], out=alphaf[lo:hi])

        in_chunks(len(alphaf), divide, ROWS_PER_THREAD)
        return alphaf

    def add(self, frame: np.ndarray, centers: np.ndarray) -> None:
        frame = _check_frame(frame)
        centers = np.asarray(centers).reshape(-1, 2)
        if len(centers) == 0:
            return
        n, w = self.n + len(centers), self.window
        # xf (3 channels) and alphaf, complex64 half spectra: refused before the first one
        # (1,000 targets at 256 px take 3.9 GiB of models, and their steps about 12-14 GiB)
        model = 4 * w * (w // 2 + 1) * np.dtype(np.complex64).itemsize
        require_memory(
            f"KCF appearance models of {n} targets ({w} px windows)", KCF_WORKING_SET * n * model
        )
        xf = self._features(frame, centers, train=True)
        alphaf = self._train(xf)
        self.xf, self._xf_buf = _appended(self._xf_buf, self.xf, xf)
        self.alphaf, self._alphaf_buf = _appended(self._alphaf_buf, self.alphaf, alphaf)

    def keep(self, index: np.ndarray) -> None:
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        n, m = self.n, len(index)
        ascending = (
            m > 0 and index[0] >= 0 and index[-1] < n and bool((index[1:] > index[:-1]).all())
        )
        if not ascending:  # any other order (or none kept): a copy
            self.xf = self.xf[index]
            self.alphaf = self.alphaf[index]
            return
        # the usual case, tracks ending: the kept rows move forward in place
        self.xf = np.ascontiguousarray(self.xf)
        self.alphaf = np.ascontiguousarray(self.alphaf)
        _compact_rows(self.xf.reshape(n, -1), index)
        _compact_rows(self.alphaf.reshape(n, -1), index)
        self.xf = self.xf[:m]
        self.alphaf = self.alphaf[:m]

    def scores(self, frame: np.ndarray, centers: np.ndarray) -> np.ndarray:
        frame = _check_frame(frame)
        centers = np.asarray(centers).reshape(-1, 2)
        k = 2 * self.radius + 1
        if len(centers) != self.n:
            raise ValueError(f"got {len(centers)} centres for {self.n} targets")
        if self.n == 0:
            return np.zeros((0, k, k), np.float32)
        zf = self._features(frame, centers)
        w = self.window
        # one expression, as ever: numpy multiplies into the temporary kernel spectrum
        # ("temporary elision", from 256 KiB), and with FMA complex products are not
        # commutative bit for bit, so a chunked product would change the responses
        resp = scipy.fft.irfft2(
            self.alphaf * self._kernel_f(self.xf, zf),
            s=(w, w),
            axes=(-2, -1),
            workers=self._workers(),
        )
        c, r = w // 2, self.radius
        out = np.empty((self.n, k, k), np.float32)

        def crop(lo: int, hi: int) -> None:
            out[lo:hi] = resp[lo:hi, c - r : c + r + 1, c - r : c + r + 1]

        in_chunks(self.n, crop, ROWS_PER_THREAD)
        return out

    def update(self, frame: np.ndarray, centers: np.ndarray, confidence: np.ndarray) -> None:
        frame = _check_frame(frame)
        confidence = np.asarray(confidence, dtype=np.float64).reshape(-1)
        if len(confidence) != self.n:
            raise ValueError(f"got {len(confidence)} confidences for {self.n} targets")
        sel = np.flatnonzero(confidence >= self.update_threshold)
        if len(sel) == 0:
            return
        xf = self._features(frame, np.asarray(centers).reshape(-1, 2)[sel], train=True)
        lr = np.float32(self.learning_rate)
        n, m = self.n, len(sel)
        alphaf = self._train(xf)
        # in place: the models must be C-contiguous for their (n, -1) reshape to be a view
        self.xf = np.ascontiguousarray(self.xf)
        self.alphaf = np.ascontiguousarray(self.alphaf)
        _blend_rows(
            self.xf.reshape(n, -1), sel, xf.astype(np.complex64, copy=False).reshape(m, -1), lr
        )
        _blend_rows(self.alphaf.reshape(n, -1), sel, alphaf.reshape(m, -1), lr)


NCC_MEANS: tuple[str, ...] = ("channel", "joint")
"""What :class:`NCCAppearance` takes off before it correlates: each colour channel's own mean
(OpenCV's ``TM_CCOEFF_NORMED``), or one mean over the patch's pixels and colours together (a
colour patch as one signal, paper 2's Eq. 7)."""


FLAT_TOLERANCE: float = 1e-5
"""When a patch counts as *flat* for normalised cross-correlation, which is ``0 / 0`` where
the template or the window does not vary: the root-mean-square deviation of its values from
their mean (each channel's own mean, or one mean over all, as the NCC takes it off) is at most
this fraction of the data's full scale (255 for 8-bit frames), 0.00255 grey levels. That is
below the least spread an 8-bit patch of up to 100 px can have (one value one level off:
``1 / sqrt(3 s^2)``, 0.0058 at 100 px), so on 8-bit frames exactly the constant patches are
flat. A flat side is no evidence: every NCC score here is 0 there (as
:func:`tracker.pnmc.flow.batched_ncc`'s), where OpenCV's ``TM_CCOEFF_NORMED`` scores a flat
template 1 at every offset and a flat window 0, NaN or inf depending on its version."""


def _flat(spread: np.ndarray, values: int) -> np.ndarray:
    """Whether sums of squared deviations ``spread`` of 8-bit patches of ``values`` values
    each are flat (:data:`FLAT_TOLERANCE`).

    >>> _flat(np.array([0.0, 0.99]), 12 * 12 * 3).tolist()
    [True, False]
    """
    return spread <= (FLAT_TOLERANCE * 255.0) ** 2 * values


def template_spread(templates: np.ndarray, per_channel: bool) -> np.ndarray:
    """``(n,)`` float64 sum of squared deviations of each template ``(n, s, s, C)`` uint8 from
    its mean: each channel's own (``per_channel``) or one over pixels and colours. Exact
    (from whole-number sums) up to the final division.

    A constant colour is flat for the per-channel means, not for the joint one:

    >>> t = np.zeros((2, 2, 2, 3), np.uint8); t[1] = (0, 0, 6)
    >>> template_spread(t, True).tolist(), template_spread(t, False).tolist()
    ([0.0, 0.0], [0.0, 96.0])
    """
    out = np.empty(len(templates), np.float64)
    _template_spread(np.ascontiguousarray(templates), per_channel, out)
    return out


@njit(cache=True, nogil=True)
def _template_spread(templates, per_channel, out):
    """:func:`template_spread`'s loop: one pass, whole-number sums (a few microseconds for
    hundreds of 12 px templates; serial, as numpy's temporaries cost more than the sums)."""
    n, h, w, nc = templates.shape
    g = nc if per_channel else 1
    m = h * w * (1 if per_channel else nc)
    s1 = np.zeros(g, np.int64)
    for t in range(n):
        s1[:] = 0
        s2 = 0
        for y in range(h):
            for x in range(w):
                for z in range(nc):
                    v = np.int64(templates[t, y, x, z])
                    s1[z if per_channel else 0] += v
                    s2 += v * v
        sq = 0.0
        for q in range(g):
            sq += np.float64(s1[q]) * np.float64(s1[q])
        out[t] = np.float64(s2) - sq / m


class NCCAppearance(AppearanceModel):
    """Colour template per target, scored by ``cv2.matchTemplate`` (``TM_CCOEFF_NORMED``).

    Templates ``(n, s, s, 3)`` uint8 are refreshed every ``update_every`` frames when the
    confidence (the NCC score of the selected candidate) reaches the threshold (paper 1,
    Sec. 7.1). OpenCV scores one template at a time, so :meth:`scores` loops over targets; each
    call is a few microseconds on these small windows.

    ``mean`` (:data:`NCC_MEANS`): ``"channel"`` (default) takes each channel's mean off the
    template and the window, so a window that differs from the template by a constant in one
    channel scores 1; ``"joint"`` takes one mean over pixels and colours (``sum (T - mean T)
    I / sqrt(sum (T - mean T)^2 (sum I^2 - (sum I)^2 / 3 s^2))``), so it does not.

    Either way a candidate scores 0 (no evidence) where the template or its window is flat
    (:data:`FLAT_TOLERANCE`): a constant template, a blank frame; scores are finite, in
    ``[-1, 1]``.
    """

    def __init__(
        self,
        template_size: int,
        radius: int,
        update_threshold: float = 0.6,
        update_every: int = 10,
        mean: str = "channel",
    ):
        super().__init__(template_size, radius, update_threshold)
        if update_every < 1:
            raise ValueError(f"update_every must be >= 1, got {update_every!r}")
        if mean not in NCC_MEANS:
            raise ValueError(f"mean must be one of {', '.join(NCC_MEANS)}, got {mean!r}")
        self.update_every = int(update_every)
        self.mean = mean
        s = self.template_size
        self.templates = np.zeros((0, s, s, 3), np.uint8)
        self.age = np.zeros(0, np.int64)

    @property
    def n(self) -> int:
        return self.templates.shape[0]

    def _templates(self, frame: np.ndarray, centers: np.ndarray) -> np.ndarray:
        s = self.template_size
        p = extract_patches(frame, np.asarray(centers, np.int64).reshape(-1, 2) - s // 2, s)
        return np.ascontiguousarray(p.transpose(0, 2, 3, 1))

    def add(self, frame: np.ndarray, centers: np.ndarray) -> None:
        frame = _check_frame(frame)
        centers = np.asarray(centers).reshape(-1, 2)
        if len(centers) == 0:
            return
        self.templates = np.concatenate([self.templates, self._templates(frame, centers)])
        self.age = np.concatenate([self.age, np.zeros(len(centers), np.int64)])

    def keep(self, index: np.ndarray) -> None:
        index = np.asarray(index, dtype=np.int64)
        self.templates = self.templates[index]
        self.age = self.age[index]

    def scores(self, frame: np.ndarray, centers: np.ndarray) -> np.ndarray:
        frame = _check_frame(frame)
        centers = np.asarray(centers, dtype=np.int64).reshape(-1, 2)
        k = 2 * self.radius + 1
        if len(centers) != self.n:
            raise ValueError(f"got {len(centers)} centres for {self.n} targets")
        out = np.zeros((self.n, k, k), np.float32)
        if self.n == 0:
            return out
        s, r = self.template_size, self.radius
        windows = extract_patches(frame, centers - r - s // 2, self.window).transpose(0, 2, 3, 1)

        if self.mean == "joint":
            _joint_ncc(windows, self.templates, out)
            return out

        def match(lo: int, hi: int) -> None:  # OpenCV releases the GIL: chunks on threads
            for i in range(lo, hi):
                out[i] = cv2.matchTemplate(
                    np.ascontiguousarray(windows[i]), self.templates[i], cv2.TM_CCOEFF_NORMED
                )

        in_chunks(self.n, match)
        # both 0 / 0, no evidence, 0 as in the joint path: OpenCV scores a flat template 1 at
        # every offset, and a flat window 0 (5.0, as measured: its spread is exact, from integral
        # images of whole numbers, and 0 takes its "no match" branch) or NaN or inf (by
        # version and backend)
        flat = _flat(template_spread(self.templates, True), 3 * s * s)
        out[flat] = 0.0
        np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        np.clip(out, -1.0, 1.0, out=out)
        return out

    def update(self, frame: np.ndarray, centers: np.ndarray, confidence: np.ndarray) -> None:
        frame = _check_frame(frame)
        confidence = np.asarray(confidence, dtype=np.float64).reshape(-1)
        if len(confidence) != self.n:
            raise ValueError(f"got {len(confidence)} confidences for {self.n} targets")
        self.age += 1
        sel = np.flatnonzero(
            (self.age >= self.update_every) & (confidence >= self.update_threshold)
        )
        if len(sel) == 0:
            return
        self.templates[sel] = self._templates(frame, np.asarray(centers).reshape(-1, 2)[sel])
        self.age[sel] = 0


@njit(cache=True, nogil=True, parallel=True)
def _window_spread(windows, s, k, per_channel, out):
    """Per window ``(n, W, W, C)`` uint8, the sum of squared deviations from the mean of every
    ``s x s x C`` patch into ``out (n, k, k)`` float64: from each channel's own mean
    (``per_channel``) or one mean over pixels and colours. The sums come from integral images
    in whole numbers (exact); ``sum I^2 - (sum I)^2 / m`` is the one rounded step."""
    n, wy, wx, nc = windows.shape
    g = nc if per_channel else 1
    m = s * s * (1 if per_channel else nc)
    for t in prange(n):
        c1 = np.zeros((g, wy + 1, wx + 1), np.int64)
        c2 = np.zeros((wy + 1, wx + 1), np.int64)
        r1 = np.zeros(g, np.int64)
        for y in range(wy):
            r1[:] = 0
            r2 = 0
            for x in range(wx):
                for z in range(nc):
                    v = np.int64(windows[t, y, x, z])
                    r1[z if per_channel else 0] += v
                    r2 += v * v
                for q in range(g):
                    c1[q, y + 1, x + 1] = c1[q, y, x + 1] + r1[q]
                c2[y + 1, x + 1] = c2[y, x + 1] + r2
        for i in range(k):
            for j in range(k):
                s2 = c2[i + s, j + s] - c2[i, j + s] - c2[i + s, j] + c2[i, j]
                sq = 0.0
                for q in range(g):
                    s1 = np.float64(c1[q, i + s, j + s] - c1[q, i, j + s] - c1[q, i + s, j])
                    s1 += np.float64(c1[q, i, j])
                    sq += s1 * s1
                out[t, i, j] = np.float64(s2) - sq / m


def _joint_ncc(windows: np.ndarray, templates: np.ndarray, out: np.ndarray) -> None:
    """NCC with one mean over a patch's pixels and colours (``NCCAppearance(mean="joint")``)
    of templates ``(n, s, s, 3)`` over windows ``(n, W, W, 3)`` into ``out (n, k, k)``, ``k =
    W - s + 1``; 0 where the window or the template is flat (:data:`FLAT_TOLERANCE`; no
    information)."""
    n, s = templates.shape[:2]
    k = out.shape[1]
    tpl = templates.astype(np.float32)
    tpl -= tpl.reshape(n, -1).mean(axis=1)[:, None, None, None]
    t_ss = np.einsum("ijkl,ijkl->i", tpl, tpl, dtype=np.float64)
    win = windows.astype(np.float32)

    def match(lo: int, hi: int) -> None:  # the sum of T - mean T times the window
        for i in range(lo, hi):
            out[i] = cv2.matchTemplate(win[i], tpl[i], cv2.TM_CCORR)

    in_chunks(n, match)
    w_ss = np.empty((n, k, k), np.float64)
    _window_spread(np.ascontiguousarray(windows), s, k, False, w_ss)
    npx = 3 * s * s
    ok = ~(_flat(w_ss, npx) | _flat(template_spread(templates, False), npx)[:, None, None])
    den = np.sqrt(np.maximum(w_ss, 0.0) * t_ss[:, None, None])
    out[...] = np.where(ok, out / np.where(ok, den, 1.0), 0.0)
    # the float32 correlation's rounding takes a near-flat template's match past 1 (1.0006
    # at 12 px): a correlation coefficient, as the per-channel path clips it
    np.clip(out, -1.0, 1.0, out=out)


def make_appearance(
    kind: str,
    template_size: int,
    radius: int,
    *,
    update_threshold: float,
    lam: float = 1e-4,
    learning_rate: float = 0.05,
    label_sigma: float = 0.1,
    kernel: str = "linear",
    kernel_sigma: float = 0.2,
    target_window: float = 0.0,
    update_every: int = 10,
) -> AppearanceModel:
    """Build the appearance model named ``kind`` (``"kcf"`` or ``"ncc"``)."""
    if kind == "kcf":
        return KCFAppearance(
            template_size,
            radius,
            update_threshold,
            lam=lam,
            learning_rate=learning_rate,
            label_sigma=label_sigma,
            kernel=kernel,
            kernel_sigma=kernel_sigma,
            target_window=target_window,
        )
    if kind == "ncc":
        return NCCAppearance(template_size, radius, update_threshold, update_every=update_every)
    raise ValueError(f"unknown appearance model {kind!r}; expected 'kcf' or 'ncc'")
