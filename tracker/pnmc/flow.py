"""Appearance-based instantaneous flow (paper 2, Sec. 3.3).

Patches of ``patch x patch`` px are laid on a regular grid (spacing ``spacing`` px) over the
oldest of the last ``frames`` frames and tracked frame to frame with normalised
cross-correlation (the form of Eq. 7) up to the newest frame; the velocity of a patch is its
displacement averaged over the ``frames - 1`` steps. The paper found NCC patch tracks over
five frames less noisy than optical-flow particle advection, so this follows it rather than
``cv2.calcOpticalFlowPyrLK``. The paper does not say whether the flow patches are in colour;
they are grey levels here (a third of the cost; Eq. 7's colour sum is kept for the targets'
likelihood).

The flow is only needed for targets whose update confidence is low, so it is computed lazily
and cached at two levels:

* per frame pair and grid cell, the best NCC displacement of the cell's patch (one numba
  kernel over all requested cells at once, reading the patches in place from the buffered
  frames: :func:`ncc_argmax`'s loop on ungathered patches); a pair stays in the cache
  while it is among the last ``frames`` frames, so each pair is matched once, not once per
  frame that uses it;
* per start cell, the patch track: from the cell in the oldest frame, each step applies the
  displacement of the grid patch nearest to the track's current position (the patch is
  re-anchored on the 4 px grid at every step, so a step's motion is measured at most
  ``spacing / 2`` px from where the track is; the displacements themselves are summed
  exactly). This makes the five-frame tracks about as cheap as one frame pair.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True)
def _disc_cells(
    cx: float, cy: float, radius: float, s: int, half: float, gh: int, gw: int
) -> tuple[np.ndarray, np.ndarray]:
    """Grid ``(rows, cols)`` (row-major) of the ``gh x gw`` patch grid (spacing ``s``, patch
    centre ``half`` px into its cell) whose centres lie within ``radius`` px of ``(cx, cy)``.
    Called once per target that needs the flow: numpy's meshgrid and masks took 40 us."""
    c0 = max(0, int(np.ceil((cx - radius - half) / s)))
    c1 = min(gw - 1, int(np.floor((cx + radius - half) / s)))
    r0 = max(0, int(np.ceil((cy - radius - half) / s)))
    r1 = min(gh - 1, int(np.floor((cy + radius - half) / s)))
    m = max(0, r1 - r0 + 1) * max(0, c1 - c0 + 1)
    rows = np.empty(m, np.int64)
    cols = np.empty(m, np.int64)
    q = 0
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            dx = c * s + half - cx
            dy = r * s + half - cy
            if dx * dx + dy * dy <= radius * radius:
                rows[q] = r
                cols[q] = c
                q += 1
    return rows[:q], cols[:q]


@njit(cache=True, nogil=True)
def _discs_cells(
    centers: np.ndarray, radius: float, s: int, half: float, gh: int, gw: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_disc_cells` of every centre ``(q, 2)``, concatenated: ``ptr (q+1,)`` and the
    cells ``rows, cols`` of centre ``t`` at ``ptr[t]:ptr[t+1]``, each disc in its order."""
    q = centers.shape[0]
    ptr = np.zeros(q + 1, np.int64)
    parts = []
    for t in range(q):
        rows, cols = _disc_cells(centers[t, 0], centers[t, 1], radius, s, half, gh, gw)
        parts.append((rows, cols))
        ptr[t + 1] = ptr[t] + rows.shape[0]
    rows = np.empty(ptr[q], np.int64)
    cols = np.empty(ptr[q], np.int64)
    for t in range(q):
        rows[ptr[t] : ptr[t + 1]] = parts[t][0]
        cols[ptr[t] : ptr[t + 1]] = parts[t][1]
    return ptr, rows, cols


def batched_ncc(templates: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """NCC of ``m`` templates over their windows (Eq. 7, one mean over x, y and colour).

    Parameters
    ----------
    templates : (m, C, p, p) float32
    windows : (m, C, p + 2r, p + 2r) float32

    Returns
    -------
    (m, 2r+1, 2r+1) float32 in [-1, 1]; 0 where the template or the window is flat.
    """
    m, c, p, _ = templates.shape
    k = windows.shape[-1] - p + 1
    npx = c * p * p
    t0 = templates - templates.reshape(m, -1).mean(1)[:, None, None, None]
    tn = (t0 * t0).reshape(m, -1).sum(1)
    wsum = windows.sum(1)  # (m, W, W): the template mean is removed over colour too
    wsq = (windows * windows).sum(1)
    num = np.zeros((m, c, k, k), np.float32)
    s1 = np.zeros((m, k, k), np.float32)
    s2 = np.zeros((m, k, k), np.float32)
    # p^2 shifted products, each one vectorised op over all patches, channels and offsets
    for dy in range(p):
        for dx in range(p):
            num += windows[:, :, dy : dy + k, dx : dx + k] * t0[:, :, dy, dx, None, None]
            s1 += wsum[:, dy : dy + k, dx : dx + k]
            s2 += wsq[:, dy : dy + k, dx : dx + k]
    num = num.sum(1)
    var = np.maximum(s2 - s1 * s1 / npx, 0.0)
    den = np.sqrt(var * tn[:, None, None])
    ok = den > 1e-3 * npx
    out = np.where(ok, num / np.where(ok, den, 1.0), 0.0)
    return np.clip(out, -1.0, 1.0).astype(np.float32)


@njit(cache=True, nogil=True, inline="always")
def _best_offset(template, window, k):
    """The best offset of one ``(C, p, p)`` template in its ``(C, p + k - 1, p + k - 1)``
    window (:func:`ncc_argmax`'s loop body): flat index ``dy k + dx`` and its NCC."""
    c, p = template.shape[0], template.shape[1]
    npx = c * p * p
    t0 = np.empty((c, p, p), np.float64)
    mean = 0.0
    for a in range(c):
        for y in range(p):
            for x in range(p):
                mean += template[a, y, x]
    mean /= npx
    tn = 0.0
    for a in range(c):
        for y in range(p):
            for x in range(p):
                v = template[a, y, x] - mean
                t0[a, y, x] = v
                tn += v * v
    top = -2.0
    arg = 0
    for oy in range(k):
        for ox in range(k):
            num = 0.0
            s1 = 0.0
            s2 = 0.0
            for a in range(c):
                for y in range(p):
                    for x in range(p):
                        w = window[a, oy + y, ox + x]
                        num += w * t0[a, y, x]
                        s1 += w
                        s2 += w * w
            var = s2 - s1 * s1 / npx
            den = np.sqrt(max(var, 0.0) * tn)
            val = num / den if den > 1e-3 * npx else 0.0
            val = min(1.0, max(-1.0, val))
            if val > top:
                top = val
                arg = oy * k + ox
    return arg, top


@njit(cache=True, nogil=True, parallel=True)
def ncc_argmax(templates: np.ndarray, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best offset of each template in its window: :func:`batched_ncc` then argmax, fused.
    One template per loop iteration on the tracker's threads (the same result for any
    number of threads).

    Parameters
    ----------
    templates : (m, C, p, p) float32
    windows : (m, C, p + 2r, p + 2r) float32

    Returns
    -------
    best : (m,) int64
        Flat index ``dy * (2r+1) + dx`` of the best offset (the first on ties).
    score : (m,) float32
        Its NCC (0 where the template or every window is flat).
    """
    m, p = templates.shape[0], templates.shape[2]
    k = windows.shape[3] - p + 1
    best = np.zeros(m, np.int64)
    score = np.zeros(m, np.float32)
    for i in prange(m):
        best[i], score[i] = _best_offset(templates[i], windows[i], k)
    return best, score


@njit(cache=True, nogil=True, parallel=True)
def _ncc_argmax_in(prev, nxt, top_left, p, r):
    """:func:`ncc_argmax` of the ``p x p`` patches of the padded frame ``prev (C, H, W)`` at
    ``top_left (m, 2)`` (x, y) in their windows, ``r`` px wider on every side, of ``nxt``,
    read in place: no gathered copies (numpy's fancy-indexed gather of them took a fifth of
    PNMC's update on a packed 1,000-target frame). A patch or window reaching past the
    padded frame is moved back inside it (clipped), the same for both frames."""
    m = top_left.shape[0]
    hp, wp = prev.shape[1], prev.shape[2]
    size = p + 2 * r
    best = np.zeros(m, np.int64)
    score = np.zeros(m, np.float32)
    for i in prange(m):
        x = min(max(top_left[i, 0], 0), wp - p)
        y = min(max(top_left[i, 1], 0), hp - p)
        xw = min(max(top_left[i, 0] - r, 0), wp - size)
        yw = min(max(top_left[i, 1] - r, 0), hp - size)
        best[i], score[i] = _best_offset(
            prev[:, y : y + p, x : x + p], nxt[:, yw : yw + size, xw : xw + size], 2 * r + 1
        )
    return best, score


SELECT_BY: tuple[str, ...] = ("start", "last")
"""Which position of a patch track :meth:`InstantaneousFlow.near` compares with the centre:
its ``"start"`` (the grid cell in the oldest buffered frame) or its ``"last"`` position (the
frame before the newest, where ``x_i^{t-1}`` lives and where the positions it returns are)."""


class InstantaneousFlow:
    """Lazily computed patch flow over the last ``frames`` frames (module docstring).

    Parameters
    ----------
    patch, spacing : int
        Patch side and grid spacing, px.
    frames : int
        Length of each patch track, frames (paper: 5).
    search : int
        Search radius per frame step, px.
    min_ncc : float
        Tracks whose NCC falls below this in any step (or that cross a flat patch) are dropped.
    """

    def __init__(
        self,
        patch: int = 4,
        spacing: int = 4,
        frames: int = 5,
        search: int = 3,
        min_ncc: float = 0.5,
    ):
        if patch < 2 or spacing < 1 or frames < 2 or search < 1:
            raise ValueError(
                f"bad flow geometry: patch {patch}, spacing {spacing}, "
                f"frames {frames}, search {search}"
            )
        self.patch, self.spacing, self.search = int(patch), int(spacing), int(search)
        self.min_ncc = float(min_ncc)
        self.buffer: deque[np.ndarray] = deque(maxlen=int(frames))
        # per frame pair (buffer[j], buffer[j+1]): computed?, displacement (dx, dy), NCC
        self.pairs: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=int(frames) - 1)
        self._shape: tuple[int, int] = (0, 0)
        self._reset_tracks()

    @property
    def pad(self) -> int:
        """Border (px) replicated around each buffered frame: one whole track's reach."""
        return self.patch + self.spacing + (self.buffer.maxlen or 1) * self.search

    def _grid_shape(self, h: int, w: int) -> tuple[int, int]:
        return (
            max(0, (h - self.patch) // self.spacing + 1),
            max(0, (w - self.patch) // self.spacing + 1),
        )

    def _new_pair(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        gh, gw = self._shape
        return (
            np.zeros((gh, gw), bool),
            np.zeros((gh, gw, 2), np.int64),
            np.zeros((gh, gw), np.float32),
        )

    def _reset_tracks(self) -> None:
        gh, gw = self._shape
        self._done = np.zeros((gh, gw), bool)
        self._valid = np.zeros((gh, gw), bool)
        self._vel = np.zeros((gh, gw, 2))
        self._last = np.zeros((gh, gw, 2))  # track position in the frame before the newest

    def reconfigure(
        self, patch: int, spacing: int, frames: int, search: int, min_ncc: float
    ) -> None:
        """New geometry; the newest ``frames`` buffered frames are kept, the caches cleared."""
        old_pad = self.pad
        old = list(self.buffer)
        self.__init__(patch, spacing, frames, search, min_ncc)
        for f in old[-int(frames) :]:
            inner = f[:, old_pad : f.shape[1] - old_pad, old_pad : f.shape[2] - old_pad]
            self._append(inner[0])

    def push(self, frame: np.ndarray) -> None:
        """Add the newest frame ``(H, W, 3)`` uint8 BGR (kept as grey levels)."""
        self._append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float32))

    def _append(self, grey: np.ndarray) -> None:
        pad = self.pad
        shape = self._grid_shape(*grey.shape)
        if shape != self._shape:
            self.buffer.clear()
            self.pairs.clear()
            self._shape = shape
        padded = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        self.buffer.append(padded[None])
        if len(self.buffer) >= 2:
            self.pairs.append(self._new_pair())
        self._reset_tracks()

    def clear(self) -> None:
        self.buffer.clear()
        self.pairs.clear()
        self._reset_tracks()

    def _match(self, j: int, rows: np.ndarray, cols: np.ndarray) -> None:
        """Match the grid patches ``(rows, cols)`` of pair ``j`` not matched yet."""
        done, disp, score = self.pairs[j]
        todo = ~done[rows, cols]
        if not todo.any():
            return
        cells = np.unique(rows[todo] * self._shape[1] + cols[todo])
        rr, cc = np.divmod(cells, self._shape[1])
        p, r = self.patch, self.search
        tl = np.stack([cc, rr], 1) * self.spacing
        frames = list(self.buffer)[-len(self.pairs) - 1 :]
        best, top = _ncc_argmax_in(frames[j], frames[j + 1], tl + self.pad, p, r)
        dy, dx = np.divmod(best, 2 * r + 1)
        disp[rr, cc] = np.stack([dx - r, dy - r], 1)
        score[rr, cc] = top
        done[rr, cc] = True

    def _track(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Tracks of the start cells ``(rows, cols)`` through every buffered pair."""
        gh, gw = self._shape
        s, half = self.spacing, self.patch / 2.0
        pos = np.stack([cols * s + half, rows * s + half], 1).astype(np.float64)
        start = pos.copy()
        last = pos.copy()
        worst = np.full(len(rows), np.inf)
        for j in range(len(self.pairs)):
            r = np.clip(np.rint((pos[:, 1] - half) / s).astype(np.int64), 0, gh - 1)
            c = np.clip(np.rint((pos[:, 0] - half) / s).astype(np.int64), 0, gw - 1)
            self._match(j, r, c)
            _, disp, score = self.pairs[j]
            worst = np.minimum(worst, score[r, c])
            last = pos
            pos = pos + disp[r, c]
        steps = max(1, len(self.pairs))
        self._vel[rows, cols] = (pos - start) / steps
        self._last[rows, cols] = last
        self._valid[rows, cols] = worst >= self.min_ncc
        self._done[rows, cols] = True

    def near(
        self, center: np.ndarray, radius: float, by: str = "start"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Valid patches whose start (``by="start"``) or whose position in the frame before
        the newest (``by="last"``) lies within ``radius`` px of ``center`` ``(2,)``
        (:data:`SELECT_BY`).

        Returns
        -------
        positions : (q, 2) float64
            Patch centres in the frame before the newest (where ``x_i^{t-1}`` lives), px.
        velocities : (q, 2) float64
            Mean velocity of each patch over the buffered frames, px/frame.
        """
        _, positions, velocities = self.near_many(np.asarray(center).reshape(1, 2), radius, by)
        return positions, velocities

    def near_many(
        self, centers: np.ndarray, radius: float, by: str = "start"
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`near` of every centre ``(m, 2)`` at once, the patches tracked in one batch.

        ``by="last"`` tracks every patch that could end up within ``radius``: those starting
        within ``radius`` plus a track's reach by the frame before the newest (each step
        moves a track at most ``search`` px in x and in y), then keeps those whose position
        in that frame is within ``radius``; the same row-major order of start cells.

        Returns
        -------
        ptr : (m + 1,) int64
            Centre ``t``'s patches are rows ``ptr[t]:ptr[t+1]`` of the two arrays, in the
            order :meth:`near` gives them.
        positions, velocities : (Q, 2) float64
            As :meth:`near`'s.
        """
        if by not in SELECT_BY:
            raise ValueError(f"near_many: by must be one of {SELECT_BY}, got {by!r}")
        centers = np.asarray(centers, np.float64).reshape(-1, 2)
        gh, gw = self._shape
        if len(centers) == 0 or len(self.buffer) < 2 or gh == 0 or gw == 0:
            return np.zeros(len(centers) + 1, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
        reach = 0.0
        if by == "last":  # |last - start| <= (pairs - 1) search in x and in y
            reach = np.sqrt(2.0) * (len(self.pairs) - 1) * self.search + 1e-6
        ptr, rr, cc = _discs_cells(
            centers, float(radius) + reach, self.spacing, self.patch / 2.0, gh, gw
        )
        todo = ~self._done[rr, cc]
        if todo.any():
            flat = np.unique(rr[todo] * gw + cc[todo])
            self._track(*np.divmod(flat, gw))
        ok = self._valid[rr, cc]
        if by == "last":
            seg = np.repeat(np.arange(len(centers)), np.diff(ptr))
            d2 = ((self._last[rr, cc] - centers[seg]) ** 2).sum(1)
            ok &= d2 <= float(radius) ** 2
        kept = np.zeros(len(ok) + 1, np.int64)  # valid cells before each cell
        np.cumsum(ok, out=kept[1:])
        return kept[ptr], self._last[rr[ok], cc[ok]], self._vel[rr[ok], cc[ok]]
