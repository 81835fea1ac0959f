"""Point-matching evaluation of head detectors: precision, recall, F1 and localisation error.

A predicted head point is a **true positive** when it is assigned to a ground-truth head within
``radius`` px (inclusive: a distance of exactly ``radius`` counts). The assignment is
one-to-one and optimal (:func:`match_points`):

1. it has the **largest possible number of pairs** (a maximum-cardinality matching of the
   bipartite graph whose edges are the prediction/ground-truth pairs within ``radius``), and
2. among those, the **smallest total distance**.

A greedy nearest-first matcher can do worse on both counts: a prediction that grabs its
nearest head may leave a second prediction, which had only that head in range, unmatched.

Cost: the candidate pairs come from a k-d tree (:meth:`scipy.spatial.cKDTree.
sparse_distance_matrix`), so nothing of size ``m x n`` is built; the assignment is
:func:`scipy.sparse.csgraph.min_weight_full_bipartite_matching` (LAPJVsp) on a sparse graph of
``O(pairs + m + n)`` edges, completed with dummy nodes so that a full matching always exists
(see :func:`match_points`).

Scores accumulate over frames with ``+`` (:class:`DetectionScore`), so a sequence's precision
is computed from its summed counts, not as a mean of per-frame ratios.

>>> score = score_frame([[0.0, 0.0], [10.0, 0.0], [50.0, 50.0]], [[1.0, 0.0], [10.0, 3.0]])
>>> score
DetectionScore(tp=2, fp=1, fn=0, error_sum_px=4.0)
>>> round(score.precision, 3), score.recall, score.f1, score.mean_error_px
(0.667, 1.0, 0.8, 2.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_array
from scipy.sparse.csgraph import min_weight_full_bipartite_matching
from scipy.spatial import cKDTree

from crowdsim.checks import require_number

DEFAULT_RADIUS_PX: float = 5.0
"""Matching radius (px) of the detection targets (issue 17: F1 at 5 px)."""


def _points(name: str, value, allow_nan: bool) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (k, 2), got {arr.shape}")
    ok = np.isfinite(arr).all(1)
    if allow_nan:
        ok |= np.isnan(arr).all(1)
    if not ok.all():
        what = "be finite or NaN in both coordinates" if allow_nan else "be finite"
        row = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{name} must {what}, got row {row}: {arr[row].tolist()}")
    return arr


def match_points(
    pred, gt, radius: float = DEFAULT_RADIUS_PX
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimal one-to-one matching of predicted to ground-truth points within ``radius`` px.

    The matching has the maximum number of pairs at distance ``<= radius`` and, among such
    matchings, the minimum total distance.

    Parameters
    ----------
    pred : (m, 2) float
        Predicted points ``(x, y)``, px; must be finite.
    gt : (n, 2) float
        Ground-truth points ``(x, y)``, px; rows that are NaN (people absent from the frame)
        are ignored and never matched.
    radius : float
        Largest matching distance, px, ``> 0`` (inclusive).

    Returns
    -------
    pairs_pred : (k,) int64
        Row of ``pred`` of each pair, increasing.
    pairs_gt : (k,) int64
        Row of ``gt`` (of the array as given, NaN rows included) of each pair.
    dist : (k,) float64
        Distance of each pair, px, ``<= radius``.

    Notes
    -----
    Method: rows are the ``m'`` predictions and ``n'`` ground-truth points that have at least
    one candidate, columns the same sets swapped; the graph has edges

    * ``pred i -> gt j`` of cost ``d_ij`` for each candidate pair (a match);
    * ``pred i -> dummy i`` and ``dummy j -> gt j`` of cost ``C`` (left unmatched);
    * ``dummy j -> dummy i`` of cost 0 for each candidate pair, so that any matching ``M``
      completes to a full one (the dummies of matched points pair up along ``M`` itself).

    A full matching then costs ``sum_M d + C (m' + n' - 2 |M|)``. With
    ``C > radius * min(m', n') / 2`` one more pair always saves more (``2C``) than any change
    of total distance, so the optimum has maximum cardinality first, minimum distance second.

    The costs go to the solver as whole numbers, in units of ``2^-e`` px with ``e`` as large
    as keeps any full matching's cost below ``2^50`` (``e`` is 42 for six points of each 4 px
    apart, 19 for 10,000 of each within 15 px), then offset by 1 (the same for every full
    matching) because sparse zeros are not edges. On some fractional costs SciPy's LAPJVsp
    never returned (five predictions, two of them at one spot, against three heads within
    4 px; one in 30,000-70,000 random scenes of up to six points of each on a half-pixel
    grid); in whole numbers its arithmetic is exact. The rounding moves a total by at most
    ``(m' + n') 2^-(e+1)`` px.

    >>> p, g, d = match_points([[0.0, 0.0], [3.0, 0.0]], [[2.0, 0.0], [np.nan, np.nan],
    ...                                                   [-2.5, 0.0]], radius=3.0)
    >>> p.tolist(), g.tolist(), d.tolist()
    ([0, 1], [2, 0], [2.5, 1.0])
    """
    require_number("match_points", "radius", radius, lo=0, lo_open=True)
    return _match(_points("pred", pred, allow_nan=False), _points("gt", gt, allow_nan=True), radius)


def _match(
    p: np.ndarray, g_all: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    keep = np.flatnonzero(~np.isnan(g_all).any(1))
    g = g_all[keep]
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(p) == 0 or len(g) == 0:
        return empty
    cand = cKDTree(p).sparse_distance_matrix(cKDTree(g), float(radius), output_type="ndarray")
    if len(cand) == 0:
        return empty
    ci = cand["i"].astype(np.int64)
    cj = cand["j"].astype(np.int64)
    cd = cand["v"].astype(np.float64)
    # Only points with a candidate take part; compact their indices.
    rows, ci = np.unique(ci, return_inverse=True)
    cols, cj = np.unique(cj, return_inverse=True)
    mp, ng = len(rows), len(cols)
    big = float(radius) * min(mp, ng) / 2.0 + 1.0
    ip, ig = np.arange(mp), np.arange(ng)
    r = np.concatenate([ci, ip, mp + ig, mp + cj])
    c = np.concatenate([cj, ng + ip, ig, ng + ci])
    w = np.concatenate([cd, np.full(mp, big), np.full(ng, big), np.zeros(len(cd))])
    unit = 2.0 ** math.floor(math.log2(2.0**50 / ((mp + ng) * (big + 1.0))))
    w = 1.0 + np.rint(w * unit)  # whole numbers: see the Notes
    graph = coo_array((w, (r, c)), shape=(mp + ng, ng + mp)).tocsr()
    row_ind, col_ind = min_weight_full_bipartite_matching(graph)
    real = (row_ind < mp) & (col_ind < ng)
    i, j = row_ind[real], col_ind[real]
    order = np.argsort(i)
    i, j = i[order], j[order]
    dist = np.hypot(*(p[rows[i]] - g[cols[j]]).T)
    return rows[i], keep[cols[j]], dist


@dataclass(frozen=True)
class DetectionScore:
    """Counts of a point-matching evaluation, over one frame or summed over many (``+``).

    Attributes
    ----------
    tp : int
        Predictions matched to a ground-truth head within the radius.
    fp : int
        Unmatched predictions (false alarms).
    fn : int
        Unmatched ground-truth heads (misses).
    error_sum_px : float
        Sum of the matched pairs' distances, px.

    Conventions for empty sets: ``precision = 1`` when there are no predictions (nothing
    claimed, nothing wrong), ``recall = 1`` when there is no ground truth (nothing to find),
    ``f1 = 0`` when both precision and recall are 0, ``mean_error_px = nan`` when ``tp = 0``.

    >>> DetectionScore(), DetectionScore().f1
    (DetectionScore(tp=0, fp=0, fn=0, error_sum_px=0.0), 1.0)
    >>> sum([DetectionScore(1, 0, 1, 2.0), DetectionScore(1, 2, 0, 1.0)]).precision
    0.5
    """

    tp: int = 0
    fp: int = 0
    fn: int = 0
    error_sum_px: float = 0.0

    def __post_init__(self) -> None:
        for name in ("tp", "fp", "fn"):
            require_number("DetectionScore", name, getattr(self, name), lo=0, integer=True)
        require_number("DetectionScore", "error_sum_px", self.error_sum_px, lo=0)

    def __add__(self, other: DetectionScore) -> DetectionScore:
        if not isinstance(other, DetectionScore):
            return NotImplemented
        return DetectionScore(
            self.tp + other.tp,
            self.fp + other.fp,
            self.fn + other.fn,
            self.error_sum_px + other.error_sum_px,
        )

    def __radd__(self, other: object) -> DetectionScore:
        # Lets the builtin sum() start from 0.
        if isinstance(other, int) and other == 0:
            return self
        return NotImplemented

    @property
    def precision(self) -> float:
        """``tp / (tp + fp)``; 1 when there are no predictions."""
        n = self.tp + self.fp
        return self.tp / n if n else 1.0

    @property
    def recall(self) -> float:
        """``tp / (tp + fn)``; 1 when there is no ground truth."""
        n = self.tp + self.fn
        return self.tp / n if n else 1.0

    @property
    def f1(self) -> float:
        """Harmonic mean of precision and recall; 0 when both are 0."""
        p, r = self.precision, self.recall
        return 2.0 * p * r / (p + r) if p + r > 0 else 0.0

    @property
    def mean_error_px(self) -> float:
        """Mean distance of the matched pairs, px; NaN when nothing matched."""
        return self.error_sum_px / self.tp if self.tp else math.nan


def score_frame(pred, gt, radius: float = DEFAULT_RADIUS_PX) -> DetectionScore:
    """Score one frame's predicted head points against its ground truth.

    Parameters
    ----------
    pred : (m, 2) float
        Predicted points, px (finite).
    gt : (n, 2) float
        Ground-truth points, px; NaN rows (absent people) count neither as misses nor as
        matches.
    radius : float
        Matching radius, px (inclusive), see :func:`match_points`.

    Returns
    -------
    DetectionScore
    """
    require_number("score_frame", "radius", radius, lo=0, lo_open=True)
    p = _points("pred", pred, allow_nan=False)
    g = _points("gt", gt, allow_nan=True)
    pairs_pred, _, dist = _match(p, g, radius)
    n = int((~np.isnan(g).any(1)).sum())
    k = len(pairs_pred)
    return DetectionScore(k, len(p) - k, n - k, float(dist.sum()))
