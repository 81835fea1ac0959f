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


def _pedestrian_wall_impl(pos, vel, radius, v0, e, group, walls, wall_grid, wall_start,
                          wall_items, period, cutoff, elliptic, V0, sigma, step_time, A, B, U0,
                          R, cos_half_fov, c_out, beta3, group_gap, tau, headway_time, tan_cone,
                          depth, v_ref, b_min, speed_cap, dt, extra, out):
    n = pos.shape[0]
    if n == 0:
        return
    order, start, nx, ny, x0, y0, cx, cy = _build_grid(pos, cutoff, period)
    cut2 = cutoff * cutoff
    wgx0, wgy0, wcell, wnx, wny = wall_grid[0], wall_grid[1], wall_grid[2], int(wall_grid[3]), \
        int(wall_grid[4])
    for i in nb.prange(n):
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
        nx = int((hi[:, 0].max() - x0) // cell) + 1
        ny = int((hi[:, 1].max() - y0) // cell) + 1
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


_kernel_serial = nb.njit(cache=True)(_pedestrian_wall_impl)
_kernel_parallel = nb.njit(cache=True, parallel=True)(_pedestrian_wall_impl)

PARALLEL_MIN_AGENTS = 5000
"""From this many agents the force kernel runs on all of numba's threads
(``NUMBA_NUM_THREADS``); each agent's sum stays in one thread, so results do not change."""


def group_vision_attraction(pos: np.ndarray, vel: np.ndarray, e: np.ndarray, group: np.ndarray,
                            params: SocialForceParams) -> np.ndarray:
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


def social_force(pos: np.ndarray, vel: np.ndarray, radius: np.ndarray, v0: np.ndarray,
                 e: np.ndarray, group: np.ndarray, walls: np.ndarray, params: SocialForceParams,
                 period: float = 0.0, wall_grid: WallGrid | None = None) -> np.ndarray:
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
        raise ValueError(f"periodic length must be >= 3 * cutoff = {3 * params.cutoff} m, "
                         f"got {period}")
    extra = (group_vision_attraction(pos, vel, e, group, params) if (group >= 0).any()
             else np.zeros((n, 2)))
    kernel = _kernel_parallel if n >= PARALLEL_MIN_AGENTS else _kernel_serial
    if wall_grid is None:
        wall_grid = WallGrid(walls, params.cutoff)
    kernel(
        pos, vel, radius, v0, e, group, walls, wall_grid.params, wall_grid.start,
        wall_grid.items, float(period), params.cutoff,
        params.potential == "elliptic", params.V0, params.sigma, params.step_time, params.A,
        params.B, params.U0, params.R, math.cos(math.radians(params.fov_deg / 2)), params.c,
        params.beta3, params.group_repulsion_gap, params.tau, params.headway_time,
        math.tan(math.radians(params.headway_cone_deg)), params.headway_depth,
        params.headway_ref_speed, params.b_min, params.speed_cap, params.dt, extra, acc)
    return acc
