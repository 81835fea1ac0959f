"""Candidate locations of every target for one frame (paper 1, Sec. 3 and Sec. 6).

Candidates are kept as a struct of arrays with the same number ``k`` of candidates per target,
so that a frame's candidates are an ``(n, k, 2)`` block and every term can be evaluated with
array operations. Targets' search regions are square grids of side ``2r + 1`` around the
integer search centres; every per-candidate quantity starts as a map ``(n, 2r+1, 2r+1)`` over
that grid (``map[i, r + dy, r + dx]`` belongs to the centre ``c_i + (dx, dy)``) and candidates
are gathered from the maps.

* :func:`dense_candidates` -- every ``stride``-th grid cell (Sec. 3, "sampled densely").
* :func:`speedup_candidates` -- the ``m`` best local extrema of the linear-term map, plus
  ``n_samples`` random cells in a ``window x window`` neighbourhood of each (Sec. 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from tracker.threads import current_threads, in_chunks


@dataclass
class Candidates:
    """Candidates of ``n`` targets, ``k`` each (``l = n k`` variables of the BQP).

    Attributes
    ----------
    positions : (n, k, 2) float64
        Candidate centres ``(x, y)``, pixels.
    cost : (n, k) float64
        Linear cost ``c_a + zeta c_m + eta c_nm`` (+ border penalty) of each candidate.
    appearance : (n, k) float32
        Appearance score (``-c_a``) of each candidate, the update confidence.
    cell : (n, k) int64
        Flat index of the candidate in its target's ``(2r+1)^2`` map.
    """

    positions: np.ndarray
    cost: np.ndarray
    appearance: np.ndarray
    cell: np.ndarray

    @property
    def n(self) -> int:
        """Number of targets."""
        return self.positions.shape[0]

    @property
    def k(self) -> int:
        """Candidates per target."""
        return self.positions.shape[1]

    @property
    def block_ptr(self) -> np.ndarray:
        """``(n+1,)`` int64 start of each target's block in the flat variable vector."""
        return np.arange(self.n + 1, dtype=np.int64) * self.k

    @property
    def flat_positions(self) -> np.ndarray:
        """``(n k, 2)`` candidate centres in variable order."""
        return self.positions.reshape(-1, 2)

    @classmethod
    def empty(cls, k: int = 1) -> Candidates:
        return cls(
            np.zeros((0, k, 2)),
            np.zeros((0, k)),
            np.zeros((0, k), np.float32),
            np.zeros((0, k), np.int64),
        )


def grid_offsets(radius: int) -> np.ndarray:
    """``((2r+1)^2, 2)`` int64 ``(dx, dy)`` offsets of the map cells, row-major.

    >>> grid_offsets(1)[:4].tolist()
    [[-1, -1], [0, -1], [1, -1], [-1, 0]]
    """
    d = np.arange(-radius, radius + 1)
    dy, dx = np.meshgrid(d, d, indexing="ij")
    return np.stack([dx.ravel(), dy.ravel()], axis=1).astype(np.int64)


def grid_positions(centers: np.ndarray, radius: int) -> np.ndarray:
    """``(n, 2r+1, 2r+1, 2)`` float64 pixel centres of every map cell."""
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    k = 2 * radius + 1
    off = grid_offsets(radius).reshape(k, k, 2).astype(np.float64)
    return centers[:, None, None, :] + off[None]


def _gather(
    centers: np.ndarray, radius: int, cost_map: np.ndarray, app_map: np.ndarray, cell: np.ndarray
) -> Candidates:
    n = cost_map.shape[0]
    side = 2 * radius + 1
    flat_cost = cost_map.reshape(n, -1)
    flat_app = app_map.reshape(n, -1)
    off = grid_offsets(radius)
    pos = np.asarray(centers, np.float64).reshape(-1, 2)[:, None, :] + off[cell]
    rows = np.arange(n)[:, None]
    assert cell.max(initial=0) < side * side
    return Candidates(
        pos,
        flat_cost[rows, cell].astype(np.float64),
        flat_app[rows, cell].astype(np.float32),
        cell.astype(np.int64),
    )


def dense_candidates(
    centers: np.ndarray, radius: int, cost_map: np.ndarray, app_map: np.ndarray, stride: int = 1
) -> Candidates:
    """Every ``stride``-th cell of the search grid (always including the centre).

    Parameters
    ----------
    centers : (n, 2) int
        Search centres.
    radius : int
        Grid radius ``r``; maps are ``(n, 2r+1, 2r+1)``.
    cost_map, app_map : (n, 2r+1, 2r+1)
        Linear cost and appearance score of every cell.
    stride : int
        Pixel stride of the grid.
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride!r}")
    n = cost_map.shape[0]
    side = 2 * radius + 1
    d = np.concatenate([-np.arange(0, radius + 1, stride)[:0:-1], np.arange(0, radius + 1, stride)])
    iy, ix = np.meshgrid(d + radius, d + radius, indexing="ij")
    cell = np.broadcast_to((iy * side + ix).ravel(), (n, iy.size))
    if n == 0:
        return Candidates.empty(iy.size)
    return _gather(centers, radius, cost_map, app_map, np.ascontiguousarray(cell))


def speedup_candidates(
    centers: np.ndarray,
    radius: int,
    cost_map: np.ndarray,
    app_map: np.ndarray,
    rng: np.random.Generator,
    n_extrema: int = 3,
    n_samples: int = 10,
    window: int = 6,
    distinct: bool = False,
) -> Candidates:
    """Speed-up sampling of Sec. 6: ``m`` extrema plus ``n_samples`` neighbours of each.

    The extrema are the ``m`` lowest local minima of the linear cost map (3x3 neighbourhood);
    if a map has fewer local minima the lowest remaining cells fill in. Around each extremum
    ``n_samples`` distinct cells are drawn uniformly from the ``window x window`` block whose
    offsets run from ``-(window // 2)`` to ``window - window // 2 - 1`` (the extremum
    excluded), clipped to the grid. Every target gets ``k = m (1 + n_samples)`` candidates.
    A cell may repeat (a sample clipped onto the grid's edge, or one on another extremum or
    another's sample: 4-7 of the 33 per target on 9 x 9 to 13 x 13 grids). A repeat is a
    candidate of its own, so it is not harmless to the QP: it counts in the degrees ``D`` of
    Eq. 9-10's normalised Laplacians (:func:`tracker.bqp.quadratic.quadratic_matrix`) as often
    as it repeats, which raises the proximity cost of other targets' candidates near it.
    ``distinct=True`` draws no cell twice (where the grid has ``k`` cells or more): each
    window's random order goes on past the offsets off the grid or on a cell taken already,
    and where a window runs out the unused cells of lowest cost (the extrema's order) fill
    in. The draws are the same either way, so the generator is left in the same state.
    """
    n = cost_map.shape[0]
    side = 2 * radius + 1
    m = min(n_extrema, side * side)
    n_off = window * window - 1
    ns = min(n_samples, n_off)
    k = m * (1 + ns)
    if n == 0:
        return Candidates.empty(k)
    flat = np.ascontiguousarray(cost_map, dtype=np.float64).reshape(n, side, side)
    big = (_abs_max(flat.reshape(n, -1)) + 1.0) * 4.0
    lo = window // 2
    d = np.arange(-lo, window - lo)
    oy, ox = np.meshgrid(d, d, indexing="ij")
    keep = ~((oy == 0) & (ox == 0)).ravel()
    offs = np.stack([ox.ravel()[keep], oy.ravel()[keep]], 1).astype(np.int64)  # (n_off, 2)
    draws = uniform_draws(rng, (n, m, n_off))  # one draw per target, extremum and offset
    cell = np.empty((n, k), np.int64)
    _speedup_cells(flat, big, m, ns, offs, draws, cell, bool(distinct))
    pos = np.empty((n, k, 2))
    cost = np.empty((n, k))
    app = np.empty((n, k), np.float32)
    _gather_cells(
        np.asarray(centers, np.float64).reshape(-1, 2),
        radius,
        flat,
        np.ascontiguousarray(app_map, dtype=np.float32).reshape(n, side, side),
        cell,
        pos,
        cost,
        app,
    )
    return Candidates(pos, cost, app, cell)


DRAWS_PER_THREAD: int = 100_000
""":func:`uniform_draws` fills chunks of at least this many numbers on the tracker's threads."""


def uniform_draws(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """``rng.random(shape)``: the same numbers, and ``rng`` left in the same state, but drawn
    in row chunks on the tracker's threads (:func:`tracker.threads.in_chunks`) when its bit
    generator can skip ahead (PCG64, the trackers' ``default_rng``: one 64-bit output per
    double, so chunk ``c`` starts that many outputs on). At 7,850 targets the draws of the
    speed-up sampling took 5.7 ms on one thread."""
    bg = rng.bit_generator
    out = np.empty(shape)
    flat = out.reshape(-1)
    if type(bg) is not np.random.PCG64 or current_threads() == 1:
        rng.random(out=out)
        return out
    start = bg.state

    def fill(lo: int, hi: int) -> None:
        own = np.random.PCG64()
        own.state = start
        own.advance(lo)
        np.random.Generator(own).random(out=flat[lo:hi])

    in_chunks(len(flat), fill, DRAWS_PER_THREAD)
    end = np.random.PCG64()
    end.state = start
    end.advance(len(flat))
    state = end.state  # advance drops a buffered 32-bit half: the stream keeps it
    state["has_uint32"], state["uinteger"] = start["has_uint32"], start["uinteger"]
    bg.state = state
    return out


@njit(cache=True, nogil=True, parallel=True)
def _abs_max(v):
    """``np.abs(v).max()`` over a ``(n, m)`` array without the temporary (NaN if any is)."""
    n = v.shape[0]
    part = np.full(n, -np.inf)
    for t in prange(n):
        top = -np.inf
        for j in range(v.shape[1]):
            a = abs(v[t, j])
            if a > top or a != a:
                top = a
                if a != a:
                    break
        part[t] = top
    top = -np.inf
    for t in range(n):
        if part[t] > top or part[t] != part[t]:
            top = part[t]
            if top != top:
                break
    return top


@njit(cache=True, nogil=True, inline="always")
def _keep_smallest(v, q, low, pick, filled):
    """Offer value ``v`` (item ``q``) to the ``filled`` smallest so far, kept ascending in
    ``low`` with their items in ``pick`` (at most ``len(low)``; ties: the earlier item
    first); returns the new count. One pass of offers selects the smallest in order."""
    cap = low.shape[0]
    if cap == 0 or (filled == cap and not v < low[cap - 1]):
        return filled
    i = filled if filled < cap else cap - 1
    while i > 0 and v < low[i - 1]:
        low[i] = low[i - 1]
        pick[i] = pick[i - 1]
        i -= 1
    low[i] = v
    pick[i] = q
    return filled + 1 if filled < cap else filled


@njit(cache=True, nogil=True, inline="always")
def _draw_order(row, low, pick):
    """The ``len(pick)`` offsets of smallest draw in ``row`` (one extremum's), ascending
    (ties: lower offset), into ``pick``; their draws into ``low``."""
    filled = 0
    for q in range(row.shape[0]):
        filled = _keep_smallest(row[q], q, low, pick, filled)


@njit(cache=True, nogil=True, parallel=True)
def _speedup_cells(cost, big, m, ns, offs, draws, cell, distinct):
    """The cells of :func:`speedup_candidates`, one target per loop iteration (the same for
    any number of threads).

    A cell is a local minimum when no cell of its 3x3 neighbourhood (clipped to the grid, as
    ``mode="nearest"``) is lower. Extrema: the ``m`` lowest local minima, then the lowest other
    cells (``big`` added to their cost), ties to the lower index. Around extremum ``e`` the
    ``ns`` offsets with the smallest ``draws[t, e]`` (a random permutation's first ``ns``),
    clipped to the grid; with ``distinct`` (:func:`_distinct_samples`) the permutation goes on
    past the offsets off the grid or on a cell the target has already.
    """
    n, side = cost.shape[0], cost.shape[1]
    cells = side * side
    for t in prange(n):
        key = np.empty(cells)
        # the 3x3 minimum as a row pass then a column pass (min is exact: same cells as a
        # 9-cell scan, a third of the comparisons)
        row = np.empty((side, side))
        for y in range(side):
            for x in range(side):
                low = cost[t, y, x]
                if x > 0 and cost[t, y, x - 1] < low:
                    low = cost[t, y, x - 1]
                if x < side - 1 and cost[t, y, x + 1] < low:
                    low = cost[t, y, x + 1]
                row[y, x] = low
        for y in range(side):
            for x in range(side):
                low = row[y, x]
                if y > 0 and row[y - 1, x] < low:
                    low = row[y - 1, x]
                if y < side - 1 and row[y + 1, x] < low:
                    low = row[y + 1, x]
                v = cost[t, y, x]
                key[y * side + x] = v if v == low else v + big
        # the m lowest keys, ascending (ties: lower index)
        top = np.empty(m)
        filled = 0
        for q in range(cells):
            filled = _keep_smallest(key[q], q, top, cell[t, :m], filled)
        if distinct and m * (1 + ns) <= cells:
            _distinct_samples(t, side, m, ns, offs, draws, key, cell)
            continue
        # the ns smallest draws in ascending order (ties: lower offset)
        low = np.empty(ns)
        pick = np.empty(ns, np.int64)
        for e in range(m):
            ey = cell[t, e] // side
            ex = cell[t, e] % side
            _draw_order(draws[t, e], low, pick)
            for s in range(ns):
                sx = min(max(ex + offs[pick[s], 0], 0), side - 1)
                sy = min(max(ey + offs[pick[s], 1], 0), side - 1)
                cell[t, m + e * ns + s] = sy * side + sx


@njit(cache=True, nogil=True)
def _distinct_samples(t, side, m, ns, offs, draws, key, cell):
    """Target ``t``'s samples with no cell twice (``speedup_candidates(distinct=True)``):
    around each extremum in turn, the offsets in ascending ``draws[t, e]`` order that land on
    the grid and on a cell not taken yet; where a window runs out (a corner, other extrema's
    samples), the unused cells of lowest ``key`` (the extrema's order) fill in."""
    n_off = offs.shape[0]
    used = np.zeros(side * side, np.bool_)
    for e in range(m):
        used[cell[t, e]] = True
    low = np.empty(n_off)
    order = np.empty(n_off, np.int64)
    for e in range(m):
        ey = cell[t, e] // side
        ex = cell[t, e] % side
        _draw_order(draws[t, e], low, order)
        got = 0
        for q in range(n_off):
            if got == ns:
                break
            sx = ex + offs[order[q], 0]
            sy = ey + offs[order[q], 1]
            if sx < 0 or sx >= side or sy < 0 or sy >= side or used[sy * side + sx]:
                continue
            used[sy * side + sx] = True
            cell[t, m + e * ns + got] = sy * side + sx
            got += 1
        while got < ns:
            best = -1
            for c in range(side * side):
                if not used[c] and (best < 0 or key[c] < key[best]):
                    best = c
            used[best] = True
            cell[t, m + e * ns + got] = best
            got += 1


@njit(cache=True, nogil=True, parallel=True)
def _gather_cells(centers, radius, cost_map, app_map, cell, pos, cost, app):
    """Positions, linear costs and appearance scores of the chosen ``cell`` (per target)."""
    side = cost_map.shape[1]
    for t in prange(cell.shape[0]):
        for q in range(cell.shape[1]):
            cy = cell[t, q] // side
            cx = cell[t, q] % side
            pos[t, q, 0] = centers[t, 0] + (cx - radius)
            pos[t, q, 1] = centers[t, 1] + (cy - radius)
            cost[t, q] = cost_map[t, cy, cx]
            app[t, q] = app_map[t, cy, cx]


def search_radius(template_size: int, search_factor: float) -> int:
    """Candidate radius ``r`` (px) for a search region of ``search_factor`` template sizes.

    >>> search_radius(14, 2.0)
    7
    >>> search_radius(8, 2.0)
    4
    """
    if template_size < 2:
        raise ValueError(f"template_size must be >= 2 px, got {template_size!r}")
    return max(1, int(round((search_factor - 1.0) * template_size / 2.0)))
