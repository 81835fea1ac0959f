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
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

# Pair blocks (pairs x k x k) are evaluated in chunks of about this many entries.
_CHUNK = 2_000_000


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
    d2 = ((grid - prediction[:, None, None, :]) ** 2).sum(-1)
    return -np.exp(-d2 / (2.0 * sigma * sigma))


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
        d2 = ((grid - pred[:, j, None, None, :]) ** 2).sum(-1)
        out -= w[:, None, None] * np.exp(-d2 / (2.0 * sigma * sigma))
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


def _pair_blocks(cand: np.ndarray, pa: np.ndarray, pb: np.ndarray, value_fn,
                 target: np.ndarray | None = None):
    """Evaluate ``value_fn(dist (P, k, k), chunk slice)`` for candidate pairs of target pairs.

    Yields (rows, cols, values) of the entries ``value_fn`` keeps (finite, > 0).
    """
    n, k = cand.shape[:2]
    step = max(1, _CHUNK // max(1, k * k))
    for s in range(0, len(pa), step):
        a, b = pa[s:s + step], pb[s:s + step]
        diff = cand[a][:, :, None, :] - cand[b][:, None, :, :]
        dist = np.sqrt((diff ** 2).sum(-1))
        val = value_fn(dist, slice(s, s + step))
        pi, ci, cj = np.nonzero(val > 0)
        yield a[pi] * k + ci, b[pi] * k + cj, val[pi, ci, cj]


def _normalised(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, size: int,
                sign: float) -> sp.csc_matrix:
    """``diag(D > 0) + sign * D^-1/2 W D^-1/2`` for symmetric ``W`` given by its upper half."""
    r = np.concatenate([rows, cols])
    c = np.concatenate([cols, rows])
    v = np.concatenate([vals, vals])
    deg = np.bincount(r, weights=v, minlength=size)
    inv = np.zeros(size)
    pos = deg > 0
    inv[pos] = 1.0 / np.sqrt(deg[pos])
    off = sp.csc_matrix((sign * v * inv[r] * inv[c], (r, c)), shape=(size, size))
    return (sp.diags(pos.astype(np.float64), format="csc") + off).tocsc()


def proximity_matrix(cand: np.ndarray, sigma: float, cutoff: float) -> sp.csc_matrix:
    """Spatial-proximity matrix ``C_sp`` (Eq. 9) over candidates ``(n, k, 2)``.

    ``S_ij = exp(-|p_i - p_j|^2 / 2 sigma^2)`` between candidates of *different* targets,
    dropped beyond ``cutoff * sigma`` px; ``C_sp = I + D^-1/2 S D^-1/2`` (signless normalised
    Laplacian, see the module docstring). Returns an ``(l, l)`` CSC matrix, ``l = n k``.
    """
    n, k = cand.shape[:2]
    size = n * k
    if n < 2:
        return sp.csc_matrix((size, size))
    reach = cutoff * sigma
    centre = cand.mean(axis=1)
    spread = np.sqrt(((cand - centre[:, None]) ** 2).sum(-1)).max()
    pairs = cKDTree(centre).query_pairs(reach + 2 * spread, output_type="ndarray")
    if len(pairs) == 0:
        return sp.csc_matrix((size, size))

    def value(dist, _):
        return np.where(dist <= reach, np.exp(-dist ** 2 / (2 * sigma * sigma)), 0.0)

    parts = list(_pair_blocks(cand, pairs[:, 0], pairs[:, 1], value))
    rows = np.concatenate([p[0] for p in parts])
    cols = np.concatenate([p[1] for p in parts])
    vals = np.concatenate([p[2] for p in parts])
    return _normalised(rows, cols, vals, size, +1.0)


def grouping_matrix(cand: np.ndarray, edges: np.ndarray, lengths: np.ndarray, sigma: float,
                    cutoff: float) -> sp.csc_matrix:
    """Grouping matrix ``C_g = I - D^-1/2 Gamma D^-1/2`` (Eq. 10) over candidates ``(n, k, 2)``.

    ``Gamma_ij = exp(-(|p_i - p_j| - e_ij)^2 / 2 sigma^2)`` for candidates of the two ends of
    every tree edge (``edges (E, 2)``, ``lengths (E,)`` px), dropped where
    ``| |p_i - p_j| - e_ij | > cutoff * sigma``.
    """
    n, k = cand.shape[:2]
    size = n * k
    if len(edges) == 0:
        return sp.csc_matrix((size, size))

    def value(dist, sl):
        dev = dist - lengths[sl][:, None, None]
        return np.where(np.abs(dev) <= cutoff * sigma,
                        np.exp(-dev ** 2 / (2 * sigma * sigma)), 0.0)

    parts = list(_pair_blocks(cand, edges[:, 0], edges[:, 1], value))
    rows = np.concatenate([p[0] for p in parts])
    cols = np.concatenate([p[1] for p in parts])
    vals = np.concatenate([p[2] for p in parts])
    return _normalised(rows, cols, vals, size, -1.0)
