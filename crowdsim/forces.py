"""Social-force accelerations for all agents at once (numba kernels).

The pedestrian and wall terms of Helbing & Molnár (1995) and the group repulsion of
Moussaïd et al. (2010) are evaluated over a uniform cell grid (cell side >= the interaction
cutoff), so a step costs O(n * neighbours) with no Python loop over agents. Each agent's sum
is accumulated in a fixed neighbour order, so results are bit-identical between runs and do
not depend on the number of threads.

All arrays are over the *present* agents, in the simulator's order:

* ``pos, vel``: ``(n, 2)`` float64, m and m/s;
* ``radius, v0``: ``(n,)`` float64, m and m/s;
* ``e``: ``(n, 2)`` float64 unit desired directions (zero for agents that stand still);
* ``group``: ``(n,)`` int64, -1 = no group;
* ``walls``: ``(m, 5)`` float64 rows ``x0, y0, x1, y1, half_thickness`` in m.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pymunk
import pymunk.batch as pb

from crowdsim.checks import require_memory
from crowdsim.params import SocialForceParams


@nb.njit(cache=True)
def _build_grid(pos, cell, period):
    """Counting-sort agents into cells of side >= ``cell``.

    Returns ``(order, start, nx, ny, x0, y0, cx, cy)``: agents of cell ``k`` are
    ``order[start[k]:start[k+1]]``. With ``period > 0`` the x axis is periodic on [0, period).
    """
    n = pos.shape[0]
    xmin = xmax = pos[0, 0]
    ymin = ymax = pos[0, 1]
    for i in range(n):
        xmin = min(xmin, pos[i, 0])
        xmax = max(xmax, pos[i, 0])
        ymin = min(ymin, pos[i, 1])
        ymax = max(ymax, pos[i, 1])
    if period > 0.0:
        nx = max(1, int(period // cell))
        x0 = 0.0
        cx = period / nx
    else:
        nx = int((xmax - xmin) // cell) + 1
        x0 = xmin
        cx = cell
    ny = int((ymax - ymin) // cell) + 1
    y0 = ymin
    cy = cell
    cell_of = np.empty(n, np.int64)
    counts = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        ix = int((pos[i, 0] - x0) // cx)
        if period > 0.0:
            ix = ix % nx
        else:
            ix = min(ix, nx - 1)
        iy = min(int((pos[i, 1] - y0) // cy), ny - 1)
        k = ix * ny + iy
        cell_of[i] = k
        counts[k + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):  # ascending i inside each cell: a fixed, thread-independent order
        k = cell_of[i]
        order[fill[k]] = i
        fill[k] += 1
    return order, start, nx, ny, x0, y0, cx, cy


def _pedestrian_wall_impl(
    pos,
    vel,
    radius,
    v0,
    e,
    group,
    walls,
    wall_grid,
    wall_start,
    wall_items,
    period,
    cutoff,
    elliptic,
    V0,
    sigma,
    step_time,
    A,
    B,
    U0,
    R,
    cos_half_fov,
    c_out,
    beta3,
    group_gap,
    tau,
    headway_time,
    tan_cone,
    depth,
    v_ref,
    b_min,
    speed_cap,
    dt,
    extra,
    out,
):
    n = pos.shape[0]
    if n == 0:
        return
    order, start, nx, ny, x0, y0, cx, cy = _build_grid(pos, cutoff, period)
    cut2 = cutoff * cutoff
    wgx0, wgy0, wcell, wnx, wny = (
        wall_grid[0],
        wall_grid[1],
        wall_grid[2],
        int(wall_grid[3]),
        int(wall_grid[4]),
    )
    # Agents in cell order, so that a thread's agents and their neighbours lie together in
    # memory (100k agents on 2 threads: 29 against 36 ms; the same on one thread). Each
    # agent's sum is unchanged: the order only decides which thread computes it.
    for ii in nb.prange(n):
        i = order[ii]
        xi = pos[i, 0]
        yi = pos[i, 1]
        # Driving term (v0 e - v) / tau  [HM95 Eq. 2].
        ax = (v0[i] * e[i, 0] - vel[i, 0]) / tau
        ay = (v0[i] * e[i, 1] - vel[i, 1]) / tau
        gap_ahead = np.inf
        ix = int((xi - x0) // cx)
        if period > 0.0:
            ix = ix % nx
        else:
            ix = min(ix, nx - 1)
        iy = min(int((yi - y0) // cy), ny - 1)
        # With fewer than 3 periodic columns the wrapped neighbours repeat; visit each once.
        dx_lo = -1 if nx >= 3 or period <= 0.0 else 0
        dx_hi = 1 if nx >= 3 or period <= 0.0 else nx - 1
        for ddx in range(dx_lo, dx_hi + 1):
            jx = ix + ddx
            if period > 0.0:
                jx = jx % nx
            elif jx < 0 or jx >= nx:
                continue
            for ddy in range(-1, 2):
                jy = iy + ddy
                if jy < 0 or jy >= ny:
                    continue
                k = jx * ny + jy
                for s in range(start[k], start[k + 1]):
                    j = order[s]
                    if j == i:
                        continue
                    rx = xi - pos[j, 0]
                    ry = yi - pos[j, 1]
                    if period > 0.0:
                        rx -= period * math.floor(rx / period + 0.5)
                    d2 = rx * rx + ry * ry
                    if d2 >= cut2 or d2 == 0.0:
                        continue
                    d = math.sqrt(d2)
                    if elliptic:
                        # V(b) = V0 exp(-b/sigma), 2b = sqrt((|r| + |r - s|)^2 - |s|^2),
                        # s = v_j delta_t  [HM95 Eq. 4]; f = -grad_r V.
                        sx = vel[j, 0] * step_time
                        sy = vel[j, 1] * step_time
                        qx = rx - sx
                        qy = ry - sy
                        dq = math.sqrt(qx * qx + qy * qy)
                        tot = d + dq
                        b2 = tot * tot - (sx * sx + sy * sy)
                        b = 0.5 * math.sqrt(max(b2, 1e-12))
                        b = max(b, b_min)
                        mag = V0 / sigma * math.exp(-b / sigma) * tot / (4.0 * b)
                        fx = mag * (rx / d + (qx / dq if dq > 1e-9 else 0.0))
                        fy = mag * (ry / d + (qy / dq if dq > 1e-9 else 0.0))
                    else:
                        # A exp((r_ij - d_ij) / B) n_ij  [HFV00].
                        mag = A * math.exp((radius[i] + radius[j] - d) / B)
                        fx = mag * rx / d
                        fy = mag * ry / d
                    # Field of view [HM95 Eq. 8]: j is seen if e_i . (x_j - x_i) >= d cos(phi).
                    if -(e[i, 0] * rx + e[i, 1] * ry) < d * cos_half_fov:
                        fx *= c_out
                        fy *= c_out
                    ax += fx
                    ay += fy
                    # Free headway along e_i to the nearest body in a cone ahead
                    # that heads the same way (directions within 60 degrees), see
                    # SocialForceParams.headway_time. Such "following" relations cannot form
                    # two-agent cycles, so they cannot dead-lock.
                    if headway_time > 0.0 and e[i, 0] * e[j, 0] + e[i, 1] * e[j, 1] > 0.5:
                        along = -(e[i, 0] * rx + e[i, 1] * ry)
                        if along > 0.0:
                            lateral = abs(e[i, 0] * ry - e[i, 1] * rx)
                            reach = radius[i] + radius[j]
                            if lateral < reach and lateral <= along * tan_cone:
                                gap = along - depth * math.sqrt(reach * reach - lateral * lateral)
                                gap_ahead = min(gap_ahead, gap)
                    # Group members keep a minimal distance [M10, f_rep].
                    if group[i] >= 0 and group[i] == group[j]:
                        if d < radius[i] + radius[j] + group_gap:
                            ax += beta3 * rx / d
                            ay += beta3 * ry / d
        # Walls: U0/R exp(-d/R) away from the nearest point of each segment [HM95 Eq. 5].
        wcx = min(max(int((xi - wgx0) // wcell), 0), wnx - 1)
        wcy = min(max(int((yi - wgy0) // wcell), 0), wny - 1)
        wc = wcx * wny + wcy
        for ws in range(wall_start[wc], wall_start[wc + 1]):
            w = wall_items[ws]
            wx0 = walls[w, 0]
            wy0 = walls[w, 1]
            ux = walls[w, 2] - wx0
            uy = walls[w, 3] - wy0
            len2 = ux * ux + uy * uy
            t = 0.0
            if len2 > 0.0:
                t = ((xi - wx0) * ux + (yi - wy0) * uy) / len2
                t = min(1.0, max(0.0, t))
            rx = xi - (wx0 + t * ux)
            ry = yi - (wy0 + t * uy)
            dc = math.sqrt(rx * rx + ry * ry)
            if dc >= cutoff + walls[w, 4] or dc < 1e-9:
                continue
            dist = max(dc - walls[w, 4], 0.0)
            mag = U0 / R * math.exp(-dist / R)
            ax += mag * rx / dc
            ay += mag * ry / dc
        ax += extra[i, 0]
        ay += extra[i, 1]
        # Speed cap v_max = 1.3 v0 [HM95 Eq. 10] (standing agents: that of a 0.5 m/s walker),
        # lowered to (v0 / v_ref) gap / T; applied as a limit on the acceleration so that
        # |v + a dt| <= v_max.
        cap = speed_cap * max(v0[i], 0.5)
        if headway_time > 0.0:
            cap = min(cap, max(gap_ahead, 0.0) / headway_time * v0[i] / v_ref)
        nvx = vel[i, 0] + ax * dt
        nvy = vel[i, 1] + ay * dt
        sp = math.sqrt(nvx * nvx + nvy * nvy)
        if sp > cap:
            scale = cap / sp
            ax = (nvx * scale - vel[i, 0]) / dt
            ay = (nvy * scale - vel[i, 1]) / dt
        out[i, 0] = ax
        out[i, 1] = ay


class WallGrid:
    """Walls binned into square cells, built once per scene (walls are static).

    Cell ``c`` lists every wall that comes within ``cutoff`` of any point of the cell, so an
    agent only visits the walls of its own cell: O(walls near it), not O(all walls). Agents
    outside the grid use the nearest border cell, whose list covers them as long as they stay
    within ``cutoff`` of the grid (farther out no wall is in range anyway).

    Attributes: ``params (5,)`` = ``x0, y0, cell, nx, ny``; ``start (nx*ny + 1,)`` and
    ``items`` in CSR form.
    """

    def __init__(self, walls: np.ndarray, cutoff: float, cell: float | None = None) -> None:
        walls = np.asarray(walls, dtype=np.float64).reshape(-1, 5)
        cell = float(cell or max(cutoff, 1.0))
        if len(walls) == 0:
            self.params = np.array([0.0, 0.0, cell, 1.0, 1.0])
            self.start = np.zeros(2, np.int64)
            self.items = np.zeros(0, np.int64)
            return
        reach = cutoff + walls[:, 4]
        lo = np.minimum(walls[:, :2], walls[:, 2:4]) - reach[:, None]
        hi = np.maximum(walls[:, :2], walls[:, 2:4]) + reach[:, None]
        x0, y0 = lo.min(axis=0)
        w, h = hi[:, 0].max() - x0, hi[:, 1].max() - y0
        nx = int(w // cell) + 1
        ny = int(h // cell) + 1
        # the cell starts and one entry per (wall, cell) pair: the grid grows with the world's
        # area, so a world of 1e9 m would take all memory before the first step
        pairs = (((hi - lo) // cell + 2).prod(axis=1)).sum()
        require_memory(
            f"the walls' grid ({nx} x {ny} cells of {cell:g} m over a world of {w:.4g} x "
            f"{h:.4g} m)",
            8.0 * (float(nx) * ny + float(pairs)),
        )
        self.params = np.array([x0, y0, cell, nx, ny], dtype=np.float64)
        self.start, self.items = _bin_walls(walls, reach, x0, y0, cell, nx, ny)


@nb.njit(cache=True)
def _bin_walls(walls, reach, x0, y0, cell, nx, ny):
    """CSR lists of the walls within ``reach`` of each cell (exact segment-box test)."""
    counts = np.zeros(nx * ny + 1, np.int64)
    for phase in range(2):
        if phase == 1:
            start = np.cumsum(counts)
            fill = start[:-1].copy()
            items = np.empty(start[-1], np.int64)
        for w in range(walls.shape[0]):
            ax, ay, bx, by = walls[w, 0], walls[w, 1], walls[w, 2], walls[w, 3]
            i0 = max(0, int((min(ax, bx) - reach[w] - x0) // cell))
            i1 = min(nx - 1, int((max(ax, bx) + reach[w] - x0) // cell))
            j0 = max(0, int((min(ay, by) - reach[w] - y0) // cell))
            j1 = min(ny - 1, int((max(ay, by) + reach[w] - y0) // cell))
            for i in range(i0, i1 + 1):
                for j in range(j0, j1 + 1):
                    # Distance from the cell's centre to the segment, minus the cell's
                    # half-diagonal: a conservative "could be within reach" test.
                    cx = x0 + (i + 0.5) * cell
                    cy = y0 + (j + 0.5) * cell
                    ux, uy = bx - ax, by - ay
                    len2 = ux * ux + uy * uy
                    t = 0.0
                    if len2 > 0.0:
                        t = min(1.0, max(0.0, ((cx - ax) * ux + (cy - ay) * uy) / len2))
                    d = math.hypot(cx - ax - t * ux, cy - ay - t * uy)
                    if d - 0.7072 * cell > reach[w]:
                        continue
                    k = i * ny + j
                    if phase == 0:
                        counts[k + 1] += 1
                    else:
                        items[fill[k]] = w
                        fill[k] += 1
    return start, items


@nb.njit(cache=True)
def _nearest_wall_kernel(pos, walls, grid, start, items, reach, clearance, direction):
    gx0, gy0, cell, nx, ny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
    for i in range(pos.shape[0]):
        xi = pos[i, 0]
        yi = pos[i, 1]
        cx = min(max(int((xi - gx0) // cell), 0), nx - 1)
        cy = min(max(int((yi - gy0) // cell), 0), ny - 1)
        c = cx * ny + cy
        best = np.inf
        bx = 0.0
        by = 0.0
        for s in range(start[c], start[c + 1]):
            w = items[s]
            ux = walls[w, 2] - walls[w, 0]
            uy = walls[w, 3] - walls[w, 1]
            len2 = ux * ux + uy * uy
            t = 0.0
            if len2 > 0.0:
                t = ((xi - walls[w, 0]) * ux + (yi - walls[w, 1]) * uy) / len2
                t = min(1.0, max(0.0, t))
            rx = walls[w, 0] + t * ux - xi
            ry = walls[w, 1] + t * uy - yi
            dc = math.hypot(rx, ry)
            if dc - walls[w, 4] < best:
                best = dc - walls[w, 4]
                bx = rx / dc if dc > 1e-12 else 0.0
                by = ry / dc if dc > 1e-12 else 0.0
        if best < reach:
            clearance[i] = best
            direction[i, 0] = bx
            direction[i, 1] = by


def nearest_wall(
    pos: np.ndarray, walls: np.ndarray, wall_grid: WallGrid, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest wall surface of each point, within ``reach`` metres.

    Parameters
    ----------
    pos : (n, 2) float, m
    walls : (m, 5) float segments ``x0, y0, x1, y1, half_thickness``
    wall_grid : WallGrid
        The walls binned for a ``cutoff >= reach`` (a query costs O(walls near each point)).
    reach : float, m

    Returns
    -------
    clearance : (n,) float64
        Distance to the nearest wall surface (segment distance minus its half thickness;
        negative inside a wall), ``inf`` where no wall is within ``reach``.
    direction : (n, 2) float64
        Unit vector from the point towards that wall's centre line; zero where none.
    """
    pos = np.ascontiguousarray(pos, dtype=np.float64).reshape(-1, 2)
    clearance = np.full(len(pos), np.inf)
    direction = np.zeros((len(pos), 2))
    if len(pos) and len(wall_grid.items):
        _nearest_wall_kernel(
            pos,
            np.asarray(walls, np.float64).reshape(-1, 5),
            wall_grid.params,
            wall_grid.start,
            wall_grid.items,
            float(reach),
            clearance,
            direction,
        )
    return clearance, direction


@nb.njit(cache=True, inline="always")
def _k_nearest_cells(pos, i, q, jx, jy, k, r2, period, order, start, ny, found, idx, dist, rel):
    """Offer every point of cell ``(jx, jy)`` to row ``q``'s sorted top ``k``; return the
    new count. Ties go to the smaller index, so the result does not depend on scan order."""
    xi = pos[i, 0]
    yi = pos[i, 1]
    c = jx * ny + jy
    for s in range(start[c], start[c + 1]):
        j = order[s]
        if j == i:
            continue
        rx = pos[j, 0] - xi
        ry = pos[j, 1] - yi
        if period > 0.0:
            rx -= period * math.floor(rx / period + 0.5)
        d2 = rx * rx + ry * ry
        if d2 > r2 or (
            found == k and (d2 > dist[q, k - 1] or (d2 == dist[q, k - 1] and j > idx[q, k - 1]))
        ):
            continue
        p = found if found < k else k - 1
        while p > 0 and (dist[q, p - 1] > d2 or (dist[q, p - 1] == d2 and idx[q, p - 1] > j)):
            dist[q, p] = dist[q, p - 1]
            idx[q, p] = idx[q, p - 1]
            rel[q, p, 0] = rel[q, p - 1, 0]
            rel[q, p, 1] = rel[q, p - 1, 1]
            p -= 1
        dist[q, p] = d2
        idx[q, p] = j
        rel[q, p, 0] = rx
        rel[q, p, 1] = ry
        if found < k:
            found += 1
    return found


@nb.njit(cache=True)
def _k_nearest_kernel(
    pos, rows, k, radius, period, order, start, nx, ny, x0, y0, cx, cy, rings, idx, dist, rel
):
    """Per query: scan the 3 x 3 cells around it; with ``rings == 2`` (cells of half the
    radius) scan the outer ring of the 5 x 5 block only when the k-th neighbour found so
    far lies beyond the half radius that the inner block is sure to cover."""
    r2 = radius * radius
    for q in range(rows.shape[0]):
        i = rows[q]
        ix = int((pos[i, 0] - x0) // cx)
        if period > 0.0:
            ix = ix % nx
        else:
            ix = min(ix, nx - 1)
        iy = min(int((pos[i, 1] - y0) // cy), ny - 1)
        found = 0
        for ring in range(1, rings + 1):
            if ring == 2 and found == k and dist[q, k - 1] <= (0.5 * radius) ** 2:
                break
            # With fewer than 3 periodic columns the wrapped neighbours repeat (rings == 1
            # there, see k_nearest); visit each once.
            lo = -ring if nx >= 3 or period <= 0.0 else 0
            hi = ring if nx >= 3 or period <= 0.0 else nx - 1
            for ddx in range(lo, hi + 1):
                jx = ix + ddx
                if period > 0.0:
                    jx = jx % nx
                elif jx < 0 or jx >= nx:
                    continue
                for ddy in range(-ring, ring + 1):
                    if ring == 2 and abs(ddx) < 2 and abs(ddy) < 2:
                        continue  # the inner block, done in ring 1
                    jy = iy + ddy
                    if jy < 0 or jy >= ny:
                        continue
                    found = _k_nearest_cells(
                        pos, i, q, jx, jy, k, r2, period, order, start, ny, found, idx, dist, rel
                    )
        for p in range(found):
            dist[q, p] = math.sqrt(dist[q, p])


def k_nearest(
    pos: np.ndarray, rows: np.ndarray, k: int, radius: float, period: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``k`` nearest other points within ``radius`` of the points ``pos[rows]``.

    A uniform grid of cells of half the radius: the 3 x 3 block around a query covers half
    the radius, and the outer ring of the 5 x 5 block is scanned only when the k-th
    neighbour is not found within it (0.28 ms for 1,000 agents at 1 /m², k = 6, 3 m, best
    of 30 on the 2-core test machine). Deterministic (ties go to the smaller index); a
    periodic x axis is seen across its seam.

    Parameters
    ----------
    pos : (n, 2) float, m
    rows : (m,) int, the query points
    k : int
    radius : float, m (> 0)
    period : float, length of a periodic x axis (0 = none)

    Returns
    -------
    idx : (m, k) int64, rows of ``pos``, nearest first; -1 pads past the last neighbour
    dist : (m, k) float64, distances (inf in padding)
    rel : (m, k, 2) float64, ``pos[idx] - pos[rows]`` (periodic images), zero in padding
    """
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    m = len(rows)
    idx = np.full((m, k), -1, np.int64)
    dist = np.full((m, k), np.inf)
    rel = np.zeros((m, k, 2))
    if m == 0 or k == 0 or len(pos) < 2:
        return idx, dist, rel
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    # Half-radius cells need 5 distinct periodic columns; narrower worlds use whole-radius
    # cells and one ring.
    rings = 2 if period <= 0 or period // (0.5 * radius) >= 5 else 1
    cell = 0.5 * radius if rings == 2 else float(radius)
    order, start, nx, ny, x0, y0, cx, cy = _build_grid(pos, cell, float(period))
    _k_nearest_kernel(
        pos,
        rows,
        int(k),
        float(radius),
        float(period),
        order,
        start,
        nx,
        ny,
        x0,
        y0,
        cx,
        cy,
        rings,
        idx,
        dist,
        rel,
    )
    return idx, dist, rel


def _jit_variant(func, suffix: str, **options):
    """``nb.njit(cache=True, **options)`` of a copy of ``func`` named ``{name}_{suffix}``.

    numba's on-disk cache files a compiled function under its module, qualified name and first
    line, and keys the entries by signature, not by the jit options (numba issue #6845). Two
    wrappings of one function, one with ``parallel=True``, would share one cache entry, and
    whichever compiled first would be loaded for both: after a small crowd had compiled the
    serial kernel, every later process ran the "parallel" kernel on one thread (100k agents on
    the 2-core machine: 58 ms a call with 2 threads, its wall time equal to its CPU time,
    against 35-37 ms with its own entry). A copy under its own name gets its own cache file.
    """
    import types

    clone = types.FunctionType(
        func.__code__, func.__globals__, f"{func.__name__}_{suffix}", func.__defaults__
    )
    clone.__qualname__ = f"{func.__qualname__}_{suffix}"
    clone.__doc__ = func.__doc__
    return nb.njit(cache=True, **options)(clone)


_kernel_serial = _jit_variant(_pedestrian_wall_impl, "serial")
_kernel_parallel = _jit_variant(_pedestrian_wall_impl, "parallel", parallel=True)

PARALLEL_MIN_AGENTS = 5000
"""From this many agents the force kernel runs on all of numba's threads
(``NUMBA_NUM_THREADS``); each agent's sum stays in one thread, so results do not change."""


def group_vision_attraction(
    pos: np.ndarray, vel: np.ndarray, e: np.ndarray, group: np.ndarray, params: SocialForceParams
) -> np.ndarray:
    """Group vision and attraction accelerations of Moussaïd et al. (2010), ``(n, 2)``.

    * vision ``f_vis = -beta1 alpha_i v_i``: ``alpha_i`` is the head rotation (rad) needed to
      see the group's centre of mass within ``group_gaze_deg`` of the walking direction;
    * attraction ``f_att = q_A beta2 U_i``: towards the centre of mass, ``q_A = 1`` when the
      distance to it exceeds ``(N_g - 1) / 2`` m.

    Vectorised over groups with ``bincount``; agents without a group get zero.
    """
    out = np.zeros_like(pos)
    member = group >= 0
    if not member.any():
        return out
    g = group[member]
    _, gi = np.unique(g, return_inverse=True)
    size = np.bincount(gi).astype(np.float64)
    p = pos[member]
    centre = np.column_stack([np.bincount(gi, p[:, 0]), np.bincount(gi, p[:, 1])]) / size[:, None]
    to_c = centre[gi] - p
    dist = np.hypot(to_c[:, 0], to_c[:, 1])
    u = np.divide(to_c, dist[:, None], out=np.zeros_like(to_c), where=dist[:, None] > 1e-9)
    v = vel[member]
    speed = np.hypot(v[:, 0], v[:, 1])
    heading = np.where(speed[:, None] > 0.1, v / np.maximum(speed, 1e-9)[:, None], e[member])
    cosang = np.clip(np.sum(heading * u, axis=1), -1.0, 1.0)
    alpha = np.maximum(np.arccos(cosang) - np.deg2rad(params.group_gaze_deg), 0.0)
    f = -params.beta1 * alpha[:, None] * v
    attract = (dist > (size[gi] - 1.0) / 2.0) & (size[gi] > 1)
    f += params.beta2 * attract[:, None] * u
    out[member] = f
    return out


def social_force(
    pos: np.ndarray,
    vel: np.ndarray,
    radius: np.ndarray,
    v0: np.ndarray,
    e: np.ndarray,
    group: np.ndarray,
    walls: np.ndarray,
    params: SocialForceParams,
    period: float = 0.0,
    wall_grid: WallGrid | None = None,
) -> np.ndarray:
    """Total social-force acceleration ``(n, 2)`` in m/s², speed cap included.

    Parameters
    ----------
    pos, vel : (n, 2) float64
    radius, v0 : (n,) float64
    e : (n, 2) float64 unit desired directions
    group : (n,) int64, -1 = none
    walls : (m, 5) float64 segments ``x0, y0, x1, y1, half_thickness``
    params : SocialForceParams
    period : float
        Length of a periodic x axis in m (0 = not periodic); needs ``period >= 3 * cutoff``.
    wall_grid : WallGrid, optional
        The walls binned for this ``cutoff`` (built here when omitted; pass it to reuse it).
    """
    n = pos.shape[0]
    acc = np.zeros((n, 2))
    if n == 0:
        return acc
    if period > 0 and period < 3 * params.cutoff:
        raise ValueError(
            f"periodic length must be >= 3 * cutoff = {3 * params.cutoff} m, got {period}"
        )
    extra = (
        group_vision_attraction(pos, vel, e, group, params)
        if (group >= 0).any()
        else np.zeros((n, 2))
    )
    kernel = _kernel_parallel if n >= PARALLEL_MIN_AGENTS else _kernel_serial
    if wall_grid is None:
        wall_grid = WallGrid(walls, params.cutoff)
    kernel(
        pos,
        vel,
        radius,
        v0,
        e,
        group,
        walls,
        wall_grid.params,
        wall_grid.start,
        wall_grid.items,
        float(period),
        params.cutoff,
        params.potential == "elliptic",
        params.V0,
        params.sigma,
        params.step_time,
        params.A,
        params.B,
        params.U0,
        params.R,
        math.cos(math.radians(params.fov_deg / 2)),
        params.c,
        params.beta3,
        params.group_repulsion_gap,
        params.tau,
        params.headway_time,
        math.tan(math.radians(params.headway_cone_deg)),
        params.headway_depth,
        params.headway_ref_speed,
        params.b_min,
        params.speed_cap,
        params.dt,
        extra,
        acc,
    )
    return acc


def contact_space(params: SocialForceParams, walls: np.ndarray) -> pymunk.Space:
    """A pymunk space with the contact solver's settings of ``params`` and the wall segments
    ``walls (W, 5)`` (x0, y0, x1, y1, half-thickness m) as static shapes: the one home of
    these settings for the one-process simulator and every worker of a split one."""
    space = pymunk.Space()
    space.iterations = int(params.solver_iterations)
    space.collision_slop = params.contact_slop
    space.collision_bias = params.contact_bias
    space.damping = 1.0
    for x0, y0, x1, y1, th in walls:
        seg = pymunk.Segment(space.static_body, (x0, y0), (x1, y1), th)
        seg.friction = params.friction
        seg.elasticity = 0.0
        space.add(seg)
    return space


class BodyRows:
    """The bodies of one pymunk space as rows of floats, read and written through buffers
    reused for the space's whole life.

    :class:`pymunk.batch.Buffer` grows C arrays that nothing frees (pymunk 7.3 gives it no
    destructor), so a fresh buffer per read leaked the rows every step: +112 MB over 300
    steps of 10k agents in the one-process simulator (60 bytes an agent a step), gigabytes
    in a long run of 100k. Here one reading buffer is cleared and refilled for the space's
    whole life; the writing buffer only ever points at the caller's numpy array. (The reading
    buffer's arrays, one space's rows at their largest, are left to pymunk when this object
    goes: freeing them here would free them twice once a pymunk release frees its own.)

    >>> space = pymunk.Space()
    >>> body = pymunk.Body(1.0, float("inf")); body.position = (1.0, 2.0)
    >>> space.add(body, pymunk.Circle(body, 0.2))
    >>> rows = BodyRows(space)
    >>> rows.write(pb.BodyFields.VELOCITY, np.array([[0.5, -0.5]]))
    >>> rows.read(pb.BodyFields.POSITION | pb.BodyFields.VELOCITY).tolist()
    [[1.0, 2.0, 0.5, -0.5]]
    """

    def __init__(self, space: pymunk.Space) -> None:
        self.space = space
        self._read = pb.Buffer()
        self._write = pb.Buffer()
        self._seen: int | None = None  # bodies the last read found

    def read(self, fields: pb.BodyFields) -> np.ndarray:
        """``(bodies, k)`` float rows of ``fields`` (float fields only) in pymunk's body order:
        a view of the reading buffer, valid until the next :meth:`read` or :meth:`read_ids`."""
        self._read.clear()
        pb.get_space_bodies(self.space, fields, self._read)
        rows = np.frombuffer(self._read.float_buf(), dtype=np.float64).reshape(
            -1, _row_width(fields)
        )
        self._seen = len(rows)
        return rows

    def read_ids(self) -> np.ndarray:
        """``(bodies,)`` int64 ``Body.id`` of each body, in pymunk's body order (a copy)."""
        self._read.clear()
        pb.get_space_bodies(self.space, pb.BodyFields.BODY_ID, self._read)
        ids = np.frombuffer(self._read.int_buf(), dtype=np.uintp).astype(np.int64)
        self._seen = len(ids)
        return ids

    def rows_of(self, *body_ids: np.ndarray) -> tuple[int, list[np.ndarray]]:
        """The number of rows pymunk iterates (the walls' static body included) and, for each
        array of ``Body.id`` values in ``body_ids``, the row of each of those bodies, from one
        read of the ids (pymunk's order changes when bodies are removed).

        >>> space = pymunk.Space()
        >>> bodies = [pymunk.Body(1.0, float("inf")) for _ in range(3)]
        >>> for b in bodies:
        ...     space.add(b, pymunk.Circle(b, 0.2))
        >>> space.remove(bodies[0], *bodies[0].shapes)
        >>> n, (rows,) = BodyRows(space).rows_of(np.array([bodies[1].id, bodies[2].id]))
        >>> n, sorted(rows.tolist())
        (2, [0, 1])
        """
        space_ids = self.read_ids()
        sorter = np.argsort(space_ids)
        rows = [sorter[np.searchsorted(space_ids, ids, sorter=sorter)] for ids in body_ids]
        return len(space_ids), rows

    def write(self, fields: pb.BodyFields, rows: np.ndarray) -> None:
        """Set ``fields`` of every body from ``rows (bodies, k)`` float64, in pymunk's order.

        pymunk reads one row per body it iterates, with no bound: fewer rows, and it reads
        past the array's end. Its bodies include the space's static body once a static
        shape (a wall) hangs on it, so a space of ``n`` agents between walls has ``n + 1``
        rows; ``rows`` must have as many as the last :meth:`read` or :meth:`read_ids` saw.
        """
        if self._seen is not None and len(rows) != self._seen:
            raise ValueError(
                f"BodyRows.write: {len(rows)} rows for the {self._seen} bodies pymunk iterates"
            )
        flat = np.ascontiguousarray(rows, dtype=np.float64).reshape(-1)
        self._write.set_float_buf(flat)
        pb.set_space_bodies(self.space, fields, self._write)


def _row_width(fields: pb.BodyFields) -> int:
    """Floats per body that ``fields`` read (pymunk.batch's order and widths)."""
    f = pb.BodyFields
    widths = (f.POSITION, 2), (f.ANGLE, 1), (f.VELOCITY, 2), (f.ANGULAR_VELOCITY, 1)
    widths += (f.FORCE, 2), (f.TORQUE, 1)
    return sum(w for field, w in widths if fields & field) or 1
