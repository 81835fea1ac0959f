"""Cost terms of the BQP objective (paper 1, Eq. 1, 6-10).

Linear terms are evaluated on the ``(n, 2r+1, 2r+1)`` search grids of all targets at once:

* :func:`motion_cost` -- Eq. 6, a Gaussian around the constant-velocity prediction.
* :func:`neighbourhood_cost` -- Eq. 7-8, Gaussians around the predictions made with the
  velocities of up to 5 coherently moving neighbours, weighted by distance.

Coherent-motion groups (Sec. 4, Fig. 4) come from :func:`coherent_groups`; the per-group
minimum spanning trees of Eq. 10 from :func:`group_trees`.

Quadratic terms are sparse ``(l, l)`` CSC matrices over the ``l = n k`` candidates:

* :func:`proximity_matrix` -- spatial proximity, Eq. 9;
* :func:`grouping_matrix` -- grouping, Eq. 10.

Both follow the paper's normalised-Laplacian construction on a sparse similarity ``W``
(``D = diag(W 1)``, ``W_hat = D^-1/2 W D^-1/2``). For grouping, ``C_g = I - W_hat`` (Eq. 10's
Laplacian, PSD) rewards co-selecting candidates that keep the group's formation. For
proximity the paper's ``C_sp = I - D^-1/2 S D^-1/2`` would *reward* co-selecting close
candidates of two targets, the opposite of its stated purpose; we use the signless normalised
Laplacian ``C_sp = I + D^-1/2 S D^-1/2 = D^-1/2 (D + S) D^-1/2``, which is PSD as well and
penalises close co-selection. On binary points the identity part is a constant. The identity
is only put on candidates with at least one neighbour (``D_ii > 0``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit
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


def neighbourhood_cost(grid: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
                       neighbours: np.ndarray, weights: np.ndarray,
                       sigma: float) -> np.ndarray:
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


def coherent_groups(history: np.ndarray, radius: float, threshold: float,
                    min_speed: float = 0.0) -> np.ndarray:
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


def neighbours_in_groups(positions: np.ndarray, labels: np.ndarray, k: int, radius: float,
                         scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``N_i`` of Eq. 7 and their weights (Eq. 8).

    Up to ``k`` nearest targets of the same coherent group within ``radius`` px. Weights are
    ``exp(-|p_j - p_i|^2 / scale^2)`` normalised over ``N_i`` (Eq. 8 with distances measured in
    units of ``scale`` px).

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
    dist, j = cKDTree(positions[member]).query(positions[member], k=kk,
                                               distance_upper_bound=radius)
    dist, j = dist[:, 1:], j[:, 1:]  # drop self
    found = j < len(member)
    jj = np.where(found, member[np.minimum(j, len(member) - 1)], -1)
    same = found & (labels[np.maximum(jj, 0)] == labels[member][:, None])
    jj = np.where(same, jj, -1)
    # stable softmax of -d^2/scale^2 over the valid neighbours
    logits = np.where(same, -(dist / scale) ** 2, -np.inf)
    mx = logits.max(1, keepdims=True)
    with np.errstate(invalid="ignore"):
        e = np.where(same, np.exp(logits - np.where(np.isfinite(mx), mx, 0.0)), 0.0)
    tot = e.sum(1, keepdims=True)
    ww = np.divide(e, tot, out=np.zeros_like(e), where=tot > 0)
    nbr[member, :kk - 1] = jj
    w[member, :kk - 1] = ww
    return nbr, w


def group_trees(positions: np.ndarray, labels: np.ndarray,
                radius: float) -> tuple[np.ndarray, np.ndarray]:
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


@njit(cache=True)
def _pair_kernel(cand, pa, pb, ref, sigma, reach, mode, rows, cols, vals, fill):
    """Count (``fill`` False) or write the kept candidate-pair entries of target pairs.

    ``mode`` 0, proximity (Eq. 9): ``exp(-d^2 / 2 sigma^2)`` where ``d <= reach``.
    ``mode`` 1, grouping (Eq. 10): ``exp(-(d - e)^2 / 2 sigma^2)`` where ``|d - e| <= reach``,
    ``e = ref[p, 0]``. ``mode`` 2, grouping with offsets: ``exp(-|(p_i - p_j) - e|^2 / 2
    sigma^2)`` where that distance is ``<= reach``, ``e = ref[p]`` (2-vector).
    """
    k = cand.shape[1]
    inv = 1.0 / (2.0 * sigma * sigma)
    reach2 = reach * reach
    m = 0
    for p in range(pa.shape[0]):
        a = pa[p]
        b = pb[p]
        for i in range(k):
            xi = cand[a, i, 0]
            yi = cand[a, i, 1]
            for j in range(k):
                dx = xi - cand[b, j, 0]
                dy = yi - cand[b, j, 1]
                if mode == 0:
                    dev2 = dx * dx + dy * dy
                elif mode == 1:
                    dev = np.sqrt(dx * dx + dy * dy) - ref[p, 0]
                    dev2 = dev * dev
                else:
                    ex = dx - ref[p, 0]
                    ey = dy - ref[p, 1]
                    dev2 = ex * ex + ey * ey
                if dev2 > reach2:
                    continue
                if fill:
                    rows[m] = a * k + i
                    cols[m] = b * k + j
                    vals[m] = np.exp(-dev2 * inv)
                m += 1
    return m


def _pair_entries(cand: np.ndarray, pa: np.ndarray, pb: np.ndarray, ref: np.ndarray,
                  sigma: float, reach: float, mode: int):
    """Entries ``(rows, cols, vals)`` (upper half: target ``pa`` rows) of ``S`` or ``Gamma``."""
    cand = np.ascontiguousarray(cand, dtype=np.float64)
    pa = np.ascontiguousarray(pa, dtype=np.int64)
    pb = np.ascontiguousarray(pb, dtype=np.int64)
    ref = np.ascontiguousarray(np.asarray(ref, dtype=np.float64).reshape(len(pa), -1))
    if ref.shape[1] == 1:
        ref = np.concatenate([ref, np.zeros_like(ref)], axis=1)
    e_i = np.zeros(0, np.int64)
    e_f = np.zeros(0, np.float64)
    m = _pair_kernel(cand, pa, pb, ref, sigma, reach, mode, e_i, e_i, e_f, False)
    rows = np.empty(m, np.int64)
    cols = np.empty(m, np.int64)
    vals = np.empty(m, np.float64)
    _pair_kernel(cand, pa, pb, ref, sigma, reach, mode, rows, cols, vals, True)
    return rows, cols, vals


@njit(cache=True)
def _csc_kernel(rows, cols, vals, diag, size, indptr, indices, data):
    """Symmetric CSC from upper-half entries plus a diagonal, by a counting sort on columns."""
    count = np.zeros(size + 1, np.int64)
    for e in range(rows.shape[0]):
        count[cols[e] + 1] += 1
        count[rows[e] + 1] += 1
    for c in range(size):
        if diag[c] != 0.0:
            count[c + 1] += 1
    for c in range(size):
        count[c + 1] += count[c]
    for c in range(size + 1):
        indptr[c] = count[c]
    pos = count[:size].copy()
    for c in range(size):
        if diag[c] != 0.0:
            indices[pos[c]] = c
            data[pos[c]] = diag[c]
            pos[c] += 1
    for e in range(rows.shape[0]):
        r = rows[e]
        c = cols[e]
        indices[pos[c]] = r
        data[pos[c]] = vals[e]
        pos[c] += 1
        indices[pos[r]] = c
        data[pos[r]] = vals[e]
        pos[r] += 1


def symmetric_csc(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, diag: np.ndarray,
                  size: int) -> sp.csc_matrix:
    """``(size, size)`` CSC of ``diag + W + W^T`` for ``W`` given by entries (no dense step)."""
    nnz = 2 * len(rows) + int(np.count_nonzero(diag))
    indptr = np.empty(size + 1, np.int64)
    indices = np.empty(nnz, np.int64)
    data = np.empty(nnz, np.float64)
    _csc_kernel(np.ascontiguousarray(rows, np.int64), np.ascontiguousarray(cols, np.int64),
                np.ascontiguousarray(vals, np.float64), np.ascontiguousarray(diag, np.float64),
                size, indptr, indices, data)
    return sp.csc_matrix((data, indices, indptr), shape=(size, size))


def normalised_entries(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, size: int,
                       sign: float, tau: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Off-diagonal entries and diagonal of ``(D + tau I)^-1/2 (D + sign W) (D + tau I)^-1/2``.

    ``W`` is symmetric and given by its upper-half entries; ``D = diag(W 1)``. With ``tau = 0``
    this is the normalised Laplacian ``I + sign D^-1/2 W D^-1/2`` of the paper (identity only
    where ``D > 0``). ``tau > 0`` regularises the degrees (as in regularised spectral
    clustering): a candidate whose only neighbour is barely similar then keeps a weak coupling
    instead of the full-strength one plain normalisation gives it. PSD either way.
    """
    deg = np.bincount(rows, weights=vals, minlength=size) + \
        np.bincount(cols, weights=vals, minlength=size)
    inv = np.zeros(size)
    pos = deg > 0
    inv[pos] = 1.0 / np.sqrt(deg[pos] + tau)
    diag = np.zeros(size)
    diag[pos] = deg[pos] / (deg[pos] + tau)
    return sign * vals * inv[rows] * inv[cols], diag


def proximity_entries(cand: np.ndarray, sigma: float, cutoff: float):
    """Upper-half entries ``(rows, cols, S_ij)`` of Eq. 9 between candidates of different targets.

    ``S_ij = exp(-|p_i - p_j|^2 / 2 sigma^2)``, dropped beyond ``cutoff * sigma`` px.
    """
    n, k = cand.shape[:2]
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if n < 2:
        return empty
    reach = cutoff * sigma
    centre = cand.mean(axis=1)
    off = cand - centre[:, None]
    spread = float(np.sqrt((off[..., 0] ** 2 + off[..., 1] ** 2).max()))
    pairs = cKDTree(centre).query_pairs(reach + 2 * spread, output_type="ndarray")
    if len(pairs) == 0:
        return empty
    return _pair_entries(cand, pairs[:, 0], pairs[:, 1], np.zeros((len(pairs), 2)), sigma,
                         reach, 0)


def grouping_entries(cand: np.ndarray, edges: np.ndarray, lengths: np.ndarray, sigma: float,
                     cutoff: float):
    """Upper-half entries ``(rows, cols, Gamma_ij)`` of Eq. 10 along the tree ``edges (E, 2)``.

    ``lengths (E,)``: ``Gamma_ij = exp(-(|p_i - p_j| - e_ij)^2 / 2 sigma^2)`` (Eq. 10), dropped
    where ``| |p_i - p_j| - e_ij | > cutoff * sigma``. ``lengths (E, 2)``: relative positions
    ``e_ij = p_a - p_b`` and ``Gamma_ij = exp(-|(p_i - p_j) - e_ij|^2 / 2 sigma^2)``, which
    keeps the formation's orientation too and is far sparser (a disc, not an annulus).
    """
    if len(edges) == 0 or cand.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    lengths = np.asarray(lengths, dtype=np.float64)
    mode = 2 if lengths.ndim == 2 else 1
    return _pair_entries(cand, edges[:, 0], edges[:, 1], lengths, sigma, cutoff * sigma, mode)


def proximity_matrix(cand: np.ndarray, sigma: float, cutoff: float,
                     tau: float = 0.0) -> sp.csc_matrix:
    """Spatial-proximity matrix ``C_sp = I + D^-1/2 S D^-1/2`` (Eq. 9, signless; see module).

    ``cand`` is ``(n, k, 2)``; returns an ``(l, l)`` CSC matrix, ``l = n k``.
    """
    size = cand.shape[0] * cand.shape[1]
    r, c, v = proximity_entries(cand, sigma, cutoff)
    off, diag = normalised_entries(r, c, v, size, +1.0, tau)
    return symmetric_csc(r, c, off, diag, size)


def grouping_matrix(cand: np.ndarray, edges: np.ndarray, lengths: np.ndarray, sigma: float,
                    cutoff: float, tau: float = 0.0) -> sp.csc_matrix:
    """Grouping matrix ``C_g = I - D^-1/2 Gamma D^-1/2`` (Eq. 10) over candidates ``(n, k, 2)``."""
    size = cand.shape[0] * cand.shape[1]
    r, c, v = grouping_entries(cand, edges, lengths, sigma, cutoff)
    off, diag = normalised_entries(r, c, v, size, -1.0, tau)
    return symmetric_csc(r, c, off, diag, size)


def quadratic_matrix(cand: np.ndarray, w_sp: float, sp_sigma: float, sp_cutoff: float,
                     w_g: float, edges: np.ndarray, lengths: np.ndarray, g_sigma: float,
                     g_cutoff: float, tau: float = 0.0) -> sp.csc_matrix:
    """``w_sp C_sp + w_g C_g`` built in one pass (one CSC, duplicates summed by the QP)."""
    size = cand.shape[0] * cand.shape[1]
    parts_r, parts_c, parts_v = [], [], []
    diag = np.zeros(size)
    if w_sp > 0:
        r, c, v = proximity_entries(cand, sp_sigma, sp_cutoff)
        off, d = normalised_entries(r, c, v, size, +1.0, tau)
        parts_r.append(r)
        parts_c.append(c)
        parts_v.append(w_sp * off)
        diag += w_sp * d
    if w_g > 0 and len(edges):
        r, c, v = grouping_entries(cand, edges, lengths, g_sigma, g_cutoff)
        off, d = normalised_entries(r, c, v, size, -1.0, tau)
        parts_r.append(r)
        parts_c.append(c)
        parts_v.append(w_g * off)
        diag += w_g * d
    if not parts_r:
        return sp.csc_matrix((size, size))
    return symmetric_csc(np.concatenate(parts_r), np.concatenate(parts_c),
                         np.concatenate(parts_v), diag, size)
