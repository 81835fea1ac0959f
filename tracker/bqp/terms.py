"""Linear cost terms of the BQP objective and the coherent-motion groups (paper 1, Eq. 1, 6-8, 10).

Linear terms are evaluated on the ``(n, 2r+1, 2r+1)`` search grids of all targets at once:

* :func:`motion_cost` -- Eq. 6, a Gaussian around the constant-velocity prediction.
* :func:`neighbourhood_cost` -- Eq. 7-8, Gaussians around the predictions made with the
  velocities of up to 5 coherently moving neighbours, weighted by distance.
* :func:`linear_cost` -- the appearance, motion and neighbourhood terms of every candidate,
  as the tracker weighs them each frame.

Coherent-motion groups (Sec. 4, Fig. 4) come from :func:`coherent_groups`; the per-group
minimum spanning trees of Eq. 10 from :func:`group_trees`. The quadratic terms built on them
(Eq. 9-10, sparse matrices over the candidates) are :mod:`tracker.bqp.quadratic`'s.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit, prange
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree


def motion_cost(grid: np.ndarray, prediction: np.ndarray, sigma: float) -> np.ndarray:
    """Eq. 6: ``c_m = -exp(-|p - A s_{t-1}|^2 / 2 sigma^2)`` on every grid cell.

    The Gaussian ``N(A s, Sigma)`` with ``Sigma = sigma^2 I`` is used unnormalised (peak 1)
    and negated so that it is a cost on the same scale as the appearance cost.

    Parameters
    ----------
    grid : (n, K, K, 2) float
        Pixel centres of the grid cells.
    prediction : (n, 2) float
        ``A s_{t-1} = p + p_dot`` (constant-velocity prediction), pixels.
    sigma : float
        Standard deviation in pixels.

    Returns
    -------
    (n, K, K) float64
    """
    dx = grid[..., 0] - prediction[:, 0, None, None]
    dy = grid[..., 1] - prediction[:, 1, None, None]
    return -np.exp((dx * dx + dy * dy) * (-0.5 / (sigma * sigma)))


def neighbourhood_cost(
    grid: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    sigma: float,
) -> np.ndarray:
    """Eq. 7: ``c_nm,i = -sum_j w_j N(p_i + p_dot_j, Sigma)`` on every grid cell.

    Parameters
    ----------
    grid : (n, K, K, 2) float
    positions, velocities : (n, 2) float
        Current positions ``p_i`` and velocities ``p_dot_i`` (px, px/frame).
    neighbours : (n, J) int
        Indices of the coherent neighbours ``N_i``, ``-1`` padding.
    weights : (n, J) float
        Eq. 8 weights (0 on padding).
    sigma : float
        Standard deviation in pixels.

    Returns
    -------
    (n, K, K) float64; zero for targets without neighbours.
    """
    n = grid.shape[0]
    out = np.zeros(grid.shape[:3])
    if n == 0 or neighbours.shape[1] == 0:
        return out
    has = neighbours >= 0
    vj = velocities[np.where(has, neighbours, 0)]  # (n, J, 2)
    pred = positions[:, None, :] + vj
    for j in range(neighbours.shape[1]):  # J <= 5: a short loop over neighbour slots
        w = np.where(has[:, j], weights[:, j], 0.0)
        if not w.any():
            continue
        dx = grid[..., 0] - pred[:, j, 0, None, None]
        dy = grid[..., 1] - pred[:, j, 1, None, None]
        out -= w[:, None, None] * np.exp((dx * dx + dy * dy) * (-0.5 / (sigma * sigma)))
    return out


@njit(cache=True, nogil=True, parallel=True)
def _cost_exponents(centers, radius, pred, positions, velocities, nbr, slots, scale, out):
    """The arguments of the ``exp`` of Eq. 6 (``out[:, 0]``) and of Eq. 7's neighbour slots
    ``slots`` (``out[:, 1 + s]``) on every grid cell, one target per loop iteration, with
    the operations of :func:`motion_cost` and :func:`neighbourhood_cost` in their order."""
    side = 2 * radius + 1
    for t in prange(centers.shape[0]):
        for y in range(side):
            gy = float(centers[t, 1]) + float(y - radius)
            for x in range(side):
                gx = float(centers[t, 0]) + float(x - radius)
                dx = gx - pred[t, 0]
                dy = gy - pred[t, 1]
                out[t, 0, y, x] = (dx * dx + dy * dy) * scale
                for s in range(slots.shape[0]):
                    j = nbr[t, slots[s]]
                    if j < 0:
                        j = 0  # padding: any finite value, its weight is 0
                    dx = gx - (positions[t, 0] + velocities[j, 0])
                    dy = gy - (positions[t, 1] + velocities[j, 1])
                    out[t, 1 + s, y, x] = (dx * dx + dy * dy) * scale


@njit(cache=True, nogil=True, parallel=True)
def _cost_combine(app, centers, radius, gauss, zeta, eta, w, border, width, height, out):
    """``-c_a + zeta c_m + eta c_nm + border * outside`` per cell from the Gaussians
    ``gauss`` of :func:`_cost_exponents`, summed in the order of the separate terms."""
    side = 2 * radius + 1
    for t in prange(app.shape[0]):
        for y in range(side):
            gy = float(centers[t, 1]) + float(y - radius)
            for x in range(side):
                gx = float(centers[t, 0]) + float(x - radius)
                c = -np.float64(app[t, y, x])
                if zeta > 0:
                    c += zeta * -gauss[t, 0, y, x]
                if eta > 0:
                    nb = 0.0
                    for s in range(w.shape[1]):
                        nb -= w[t, s] * gauss[t, 1 + s, y, x]
                    c += eta * nb
                outside = gx < 0 or gx > width - 1 or gy < 0 or gy > height - 1
                c += border * (1.0 if outside else 0.0)
                out[t, y, x] = c


def linear_cost(
    app: np.ndarray,
    centers: np.ndarray,
    radius: int,
    prediction: np.ndarray,
    sigma: float,
    zeta: float,
    eta: float,
    positions: np.ndarray,
    velocities: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    border: float,
    frame_size: tuple[int, int],
) -> np.ndarray:
    """The linear cost of Eq. 1 on every cell of the ``(n, 2r+1, 2r+1)`` search grids.

    ``-app + zeta c_m + eta c_nm + border * outside``: the appearance score ``app``, Eq. 6
    around ``prediction`` (:func:`motion_cost`), Eq. 7 with ``neighbours`` and ``weights``
    (:func:`neighbourhood_cost`), and ``border`` on cells outside the ``(width, height)``
    frame. The same values, bit for bit, as those functions on :func:`grid_positions`'s grid
    (the ``exp`` is numpy's, over one array), without the ``(n, K, K, 2)`` grid and the
    per-term temporaries.
    """
    n, side = app.shape[0], 2 * radius + 1
    out = np.empty((n, side, side))
    if n == 0:
        return out
    centers = np.ascontiguousarray(centers, np.int64)
    pred = np.ascontiguousarray(prediction, np.float64)
    has = neighbours >= 0
    w = np.where(has, weights, 0.0) if eta > 0 else np.zeros((n, 0))
    slots = np.flatnonzero(w.any(axis=0)).astype(np.int64)  # slots nobody uses add 0
    w = np.ascontiguousarray(w[:, slots])
    expo = np.empty((n, 1 + len(slots), side, side))
    _cost_exponents(
        centers,
        radius,
        pred,
        np.ascontiguousarray(positions, np.float64),
        np.ascontiguousarray(velocities, np.float64),
        np.ascontiguousarray(neighbours, np.int64),
        slots,
        -0.5 / (sigma * sigma),
        expo,
    )
    gauss = np.exp(expo, out=expo)
    width, height = frame_size
    _cost_combine(
        np.ascontiguousarray(app, np.float32),
        centers,
        radius,
        gauss,
        float(zeta),
        float(eta),
        w,
        float(border),
        width,
        height,
        out,
    )
    return out


def coherent_groups(
    history: np.ndarray, radius: float, threshold: float, min_speed: float = 0.0
) -> np.ndarray:
    """Cluster targets into coherent-motion groups (Sec. 4, Fig. 4).

    Two targets are linked when they are at most ``radius`` px apart in the last row of
    ``history`` and the mean cosine similarity of their frame-to-frame displacements over the
    history (frames where both are present) is at least ``threshold``; both must move at
    ``min_speed`` px/frame or more on average. Groups are the connected components of the
    links ("distance-aware clustering of track correlation").

    Parameters
    ----------
    history : (H, n, 2) float
        Past positions, oldest first, NaN where unknown.

    Returns
    -------
    (n,) int64 group label, ``-1`` for targets in no group.
    """
    h, n = history.shape[:2]
    labels = np.full(n, -1, np.int64)
    if n < 2 or h < 2:
        return labels
    cur = history[-1]
    ok = np.isfinite(cur).all(1)
    disp = np.diff(history, axis=0)  # (H-1, n, 2)
    speed = np.linalg.norm(disp, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = disp / speed[..., None]
        mean_speed = np.nanmean(np.where(np.isfinite(speed), speed, np.nan), axis=0)
    moving = ok & np.isfinite(mean_speed) & (mean_speed >= min_speed)
    idx = np.flatnonzero(moving)
    if len(idx) < 2:
        return labels
    pairs = cKDTree(cur[idx]).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return labels
    a, b = idx[pairs[:, 0]], idx[pairs[:, 1]]
    dots = (unit[:, a] * unit[:, b]).sum(-1)  # (H-1, P), NaN where either is absent/still
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(dots)
        cnt = valid.sum(0)
        corr = np.where(cnt > 0, np.where(valid, dots, 0.0).sum(0) / np.maximum(cnt, 1), -1.0)
    link = corr >= threshold
    if not link.any():
        return labels
    g = sp.coo_matrix((np.ones(link.sum()), (a[link], b[link])), shape=(n, n))
    _, comp = connected_components(g, directed=False)
    sizes = np.bincount(comp, minlength=comp.max() + 1)
    grouped = sizes[comp] > 1
    _, relabel = np.unique(comp[grouped], return_inverse=True)
    labels[grouped] = relabel
    return labels


def neighbours_in_groups(
    positions: np.ndarray,
    labels: np.ndarray,
    k: int,
    radius: float,
    scale: float,
    same_group: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``N_i`` of Eq. 7 and their weights (Eq. 8).

    By default the targets of the same coherent group among the ``k`` nearest group members
    within ``radius`` px (targets of other groups take places: where two groups interleave, a
    target is left with fewer than ``k`` or none). ``same_group=True`` gives Eq. 7's: the ``k``
    nearest targets of the same group within ``radius`` px (each group's members are set
    apart by more than ``radius`` along a third axis, so one tree query finds them). Weights
    are ``exp(-|p_j - p_i|^2 / scale^2)`` normalised over ``N_i`` (Eq. 8 with distances
    measured in units of ``scale`` px).

    >>> pos = np.array([[0.0, 0], [1, 0], [2, 0], [3, 0]])  # two groups, interleaved
    >>> labels = np.array([0, 1, 0, 1])
    >>> neighbours_in_groups(pos, labels, 1, 10.0, 1.0)[0][:, 0].tolist()  # nearest is 1 away
    [-1, -1, -1, -1]
    >>> neighbours_in_groups(pos, labels, 1, 10.0, 1.0, same_group=True)[0][:, 0].tolist()
    [2, 3, 0, 1]

    Returns
    -------
    neighbours : (n, k) int64, ``-1`` padding
    weights : (n, k) float64, rows sum to 1 (or 0 without neighbours)
    """
    n = len(positions)
    nbr = np.full((n, k), -1, np.int64)
    w = np.zeros((n, k))
    member = np.flatnonzero(labels >= 0)
    if len(member) < 2:
        return nbr, w
    kk = min(k + 1, len(member))
    where = positions[member]
    if same_group:  # groups apart by more than the radius: a query finds its own group alone
        apart = 2.0 * float(radius) + 1.0
        where = np.column_stack([where, labels[member] * apart])
    dist, j = cKDTree(where).query(where, k=kk, distance_upper_bound=radius)
    dist, j = dist[:, 1:], j[:, 1:]  # drop self
    found = j < len(member)
    jj = np.where(found, member[np.minimum(j, len(member) - 1)], -1)
    same = found & (labels[np.maximum(jj, 0)] == labels[member][:, None])
    jj = np.where(same, jj, -1)
    # stable softmax of -d^2/scale^2 over the valid neighbours
    logits = np.where(same, -((dist / scale) ** 2), -np.inf)
    mx = logits.max(1, keepdims=True)
    with np.errstate(invalid="ignore"):
        e = np.where(same, np.exp(logits - np.where(np.isfinite(mx), mx, 0.0)), 0.0)
    tot = e.sum(1, keepdims=True)
    ww = np.divide(e, tot, out=np.zeros_like(e), where=tot > 0)
    nbr[member, : kk - 1] = jj
    w[member, : kk - 1] = ww
    return nbr, w


def group_trees(
    positions: np.ndarray, labels: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Minimum spanning tree of each coherent group (the pictorial structure of Eq. 10).

    Members of a group are joined by edges of length ``|p_i - p_j|`` when within ``radius``
    px; the minimum spanning forest of that graph is the union of the per-group trees.

    Returns
    -------
    edges : (E, 2) int64 target indices
    lengths : (E,) float64 ``e_ij`` in pixels
    """
    n = len(positions)
    member = np.flatnonzero(labels >= 0)
    if len(member) < 2:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    pairs = cKDTree(positions[member]).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    a, b = member[pairs[:, 0]], member[pairs[:, 1]]
    same = labels[a] == labels[b]
    a, b = a[same], b[same]
    d = np.linalg.norm(positions[a] - positions[b], axis=1)
    # csgraph treats explicit zeros as missing edges: coincident targets get a tiny length
    g = sp.coo_matrix((np.maximum(d, 1e-9), (a, b)), shape=(n, n)).tocsr()
    t = minimum_spanning_tree(g).tocoo()
    edges = np.stack([t.row, t.col], 1).astype(np.int64)
    return edges, np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
