"""Cost terms (Eq. 6-10), candidates and the parameter dataclass."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import connected_components

from tracker.bqp.params import BQPParams
from tracker.bqp.quadratic import _target_components as target_components
from tracker.bqp.quadratic import grouping_matrix, proximity_matrix, quadratic_matrix
from tracker.bqp.terms import (
    coherent_groups,
    group_trees,
    motion_cost,
    neighbourhood_cost,
    neighbours_in_groups,
)
from tracker.candidates import dense_candidates, grid_positions, search_radius, speedup_candidates


def test_motion_cost_peaks_at_prediction():
    grid = grid_positions(np.array([[10, 10], [50, 40]]), 3)
    pred = np.array([[12.0, 9.0], [50.0, 40.0]])
    c = motion_cost(grid, pred, 2.0)
    assert c.shape == (2, 7, 7)
    assert np.unravel_index(c[0].argmin(), (7, 7)) == (3 - 1, 3 + 2)
    assert c[1, 3, 3] == pytest.approx(-1.0)
    assert (c <= 0).all() and (c >= -1).all()
    # Eq. 6 with Sigma = sigma^2 I: -exp(-|p - A s|^2 / (2 sigma^2)) on every cell, e.g. the
    # centre (10, 10) is (2, 1) px from the prediction: -exp(-5 / 8)
    assert c[0, 3, 3] == pytest.approx(-np.exp(-5 / 8), rel=1e-12)
    d2 = ((grid - pred[:, None, None]) ** 2).sum(-1)
    np.testing.assert_allclose(c, -np.exp(-d2 / (2 * 2.0**2)), rtol=1e-12)


def test_neighbourhood_cost_uses_neighbour_velocities_eq7():
    grid = grid_positions(np.array([[20, 20]]), 4)
    pos = np.array([[20.0, 20.0], [30.0, 20.0], [40.0, 20.0]])
    vel = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, -2.0]])
    nbr = np.array([[1, 2, -1]])
    w = np.array([[0.75, 0.25, 0.0]])
    c = neighbourhood_cost(grid, pos[:1], vel, nbr, w, 1.0)
    # strongest pull at p_i + v_1 = (23, 20), weaker at p_i + v_2 = (20, 18)
    assert np.unravel_index(c[0].argmin(), (9, 9)) == (4, 7)
    assert c[0, 4 - 2, 4] == pytest.approx(-0.25, abs=5e-3)
    # at the centre (20, 20): 3 px from (23, 20) and 2 px from (20, 18), sigma = 1
    want = -(0.75 * np.exp(-9 / 2) + 0.25 * np.exp(-4 / 2))
    assert c[0, 4, 4] == pytest.approx(want, rel=1e-12)
    none = neighbourhood_cost(grid, pos[:1], vel, np.full((1, 3), -1), np.zeros((1, 3)), 1.0)
    assert (none == 0).all()


def _history(n_frames=10):
    # group A moves right, group B moves left, C stands still, D is far away moving right
    t = np.arange(n_frames)[:, None]
    xs = np.concatenate(
        [
            10 + 2 * t + np.array([0, 8, 16]),
            60 - 2 * t + np.array([0, 8, 16]),
            np.full((n_frames, 1), 40.0),
            300 + 2 * t,
        ],
        axis=1,
    )
    ys = np.concatenate(
        [
            np.full((n_frames, 3), 10.0),
            np.full((n_frames, 3), 30.0),
            np.full((n_frames, 1), 20.0),
            np.full((n_frames, 1), 10.0),
        ],
        axis=1,
    )
    return np.stack([xs, ys], axis=-1)


def test_coherent_groups_split_opposite_flows():
    h = _history()
    labels = coherent_groups(h, radius=20.0, threshold=0.8, min_speed=0.5)
    assert labels[0] == labels[1] == labels[2] >= 0
    assert labels[3] == labels[4] == labels[5] >= 0
    assert labels[0] != labels[3]
    assert labels[6] == -1 and labels[7] == -1  # still / isolated
    assert (coherent_groups(h[:, :1], 20.0, 0.8) == -1).all()
    h[:5, 1] = np.nan  # a target born mid-history still joins via the frames it shares
    assert coherent_groups(h, 20.0, 0.8, 0.5)[1] == labels[0]


def test_neighbours_and_weights_eq8():
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [50.0, 0.0]])
    labels = np.array([0, 0, 0, -1])
    nbr, w = neighbours_in_groups(pos, labels, k=5, radius=10.0, scale=1.0)
    assert set(nbr[0][nbr[0] >= 0]) == {1, 2}
    np.testing.assert_allclose(w.sum(1), [1, 1, 1, 0])
    e1, e2 = np.exp(-1.0), np.exp(-4.0)
    np.testing.assert_allclose(w[0][nbr[0] == 1], e1 / (e1 + e2))
    assert (nbr[3] == -1).all()


def test_group_trees_are_spanning_trees():
    h = _history()
    labels = coherent_groups(h, 20.0, 0.8, 0.5)
    edges, lengths = group_trees(h[-1], labels, 20.0)
    assert len(edges) == 4  # two groups of three -> 2 + 2 edges
    assert (labels[edges[:, 0]] == labels[edges[:, 1]]).all()
    np.testing.assert_allclose(lengths, 8.0)


def _dense_reference(cand, sigma, cutoff, edges=None, lengths=None):
    n, k = cand.shape[:2]
    p = cand.reshape(-1, 2)
    tgt = np.repeat(np.arange(n), k)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    if edges is None:
        w = np.exp(-(d**2) / (2 * sigma**2)) * (d <= cutoff * sigma)
        w[tgt[:, None] == tgt[None]] = 0
    else:
        w = np.zeros_like(d)
        for (a, b), e in zip(edges, lengths, strict=True):
            ia, ib = np.flatnonzero(tgt == a), np.flatnonzero(tgt == b)
            dev = d[np.ix_(ia, ib)] - e
            blk = np.exp(-(dev**2) / (2 * sigma**2)) * (np.abs(dev) <= cutoff * sigma)
            w[np.ix_(ia, ib)] = blk
            w[np.ix_(ib, ia)] = blk.T
    deg = w.sum(1)
    inv = np.where(deg > 0, 1 / np.sqrt(np.where(deg > 0, deg, 1)), 0)
    return np.diag((deg > 0).astype(float)), inv[:, None] * w * inv[None]


def test_proximity_matrix_matches_dense_reference_and_is_psd():
    rng = np.random.default_rng(1)
    cand = rng.uniform(0, 20, (5, 6, 2))
    q = proximity_matrix(cand, sigma=3.0, cutoff=2.0)
    assert sp.issparse(q) and q.shape == (30, 30)
    eye, a = _dense_reference(cand, 3.0, 2.0)
    np.testing.assert_allclose(q.toarray(), eye + a, atol=1e-12)
    assert np.linalg.eigvalsh(q.toarray()).min() > -1e-9
    # binary points: choosing two close candidates costs more than two far ones
    p = cand.reshape(-1, 2)
    x_close = np.zeros(30)
    x_far = np.zeros(30)
    d = np.linalg.norm(p[:6, None] - p[None, 6:12], axis=-1)
    i, j = np.unravel_index(d.argmin(), d.shape)
    x_close[[i, 6 + j]] = 1
    i, j = np.unravel_index(d.argmax(), d.shape)
    x_far[[i, 6 + j]] = 1
    assert x_close @ q @ x_close > x_far @ q @ x_far


def test_grouping_matrix_matches_dense_reference_and_is_psd():
    rng = np.random.default_rng(2)
    cand = rng.uniform(0, 20, (4, 5, 2))
    edges = np.array([[0, 1], [1, 3]])
    lengths = np.array([6.0, 9.0])
    q = grouping_matrix(cand, edges, lengths, sigma=3.0, cutoff=2.5)
    eye, a = _dense_reference(cand, 3.0, 2.5, edges, lengths)
    np.testing.assert_allclose(q.toarray(), eye - a, atol=1e-12)
    assert np.linalg.eigvalsh(q.toarray()).min() > -1e-9
    both = quadratic_matrix(cand, 0.5, 3.0, 2.0, 2.0, edges, lengths, 3.0, 2.5)
    ref = 0.5 * proximity_matrix(cand, 3.0, 2.0) + 2.0 * q
    np.testing.assert_allclose(both.toarray(), ref.toarray(), atol=1e-12)


def test_quadratic_terms_edge_cases():
    assert proximity_matrix(np.zeros((0, 4, 2)), 3.0, 2.0).shape == (0, 0)
    assert proximity_matrix(np.zeros((1, 4, 2)), 3.0, 2.0).nnz == 0
    far = np.array([[[0.0, 0.0]], [[100.0, 0.0]]])
    assert proximity_matrix(far, 3.0, 2.0).nnz == 0
    assert quadratic_matrix(far, 1, 3, 2, 1, np.zeros((0, 2), int), np.zeros(0), 3, 2).nnz == 0


def test_speedup_samples_are_the_smallest_draws_in_order():
    """Around each extremum the samples are the offsets of the ``n_samples`` smallest draws,
    ascending (a random permutation's first ``n_samples``), ties to the lower offset."""
    from tracker.candidates import _speedup_cells

    rng = np.random.default_rng(5)
    side, m, ns = 9, 2, 7
    cost = rng.normal(size=(4, side, side))
    offs = np.stack(np.meshgrid(np.arange(-2, 3), np.arange(-2, 3)), -1).reshape(-1, 2)
    offs = offs[(offs != 0).any(1)].astype(np.int64)  # 24 offsets, the centre left out
    draws = rng.random((4, m, len(offs)))
    draws[0, 0, 3] = draws[0, 0, 9] = -1.0  # a tie: offset 3 comes before offset 9
    cell = np.empty((4, m * (1 + ns)), np.int64)
    _speedup_cells(cost, 1e9, m, ns, offs, draws, cell, False)
    from scipy.ndimage import minimum_filter

    for t in range(4):
        # extrema: the m lowest local minima (3x3, border as "nearest"), ascending
        local = cost[t] == minimum_filter(cost[t], size=3, mode="nearest")
        key = np.where(local, cost[t], cost[t] + 1e9).ravel()
        np.testing.assert_array_equal(cell[t, :m], np.argsort(key, kind="stable")[:m])
        for e in range(m):
            ey, ex = divmod(cell[t, e], side)
            best = np.argsort(draws[t, e], kind="stable")[:ns]
            sx = np.clip(ex + offs[best, 0], 0, side - 1)
            sy = np.clip(ey + offs[best, 1], 0, side - 1)
            np.testing.assert_array_equal(cell[t, m + e * ns : m + (e + 1) * ns], sy * side + sx)


def test_dense_and_speedup_candidates():
    r = 3
    centers = np.array([[10, 10], [30, 12]])
    cost = np.zeros((2, 7, 7))
    cost[0, 1, 5] = -3  # extremum at offset (+2, -2)
    cost[0, 5, 1] = -2
    cost[1, 3, 3] = -1
    app = -cost.astype(np.float32)
    d = dense_candidates(centers, r, cost, app, stride=1)
    assert d.k == 49 and d.n == 2
    np.testing.assert_array_equal(d.block_ptr, [0, 49, 98])
    assert dense_candidates(centers, r, cost, app, stride=2).k == 9  # offsets -2, 0, 2
    rng = np.random.default_rng(0)
    s = speedup_candidates(centers, r, cost, app, rng, n_extrema=3, n_samples=10, window=6)
    assert s.k == 33
    np.testing.assert_array_equal(s.positions[0, 0], [12, 8])
    np.testing.assert_array_equal(s.positions[0, 1], [8, 12])
    assert s.cost[0, 0] == -3
    # samples lie within the 6x6 neighbourhood of their extremum (clipped to the grid)
    ext = s.positions[:, :3]
    samp = s.positions[:, 3:].reshape(2, 3, 10, 2)
    off = samp - ext[:, :, None]
    assert (off >= -3).all() and (off <= 2).all()
    assert (np.abs(s.positions - centers[:, None]) <= r).all()
    empty = speedup_candidates(np.zeros((0, 2)), r, np.zeros((0, 7, 7)), np.zeros((0, 7, 7)), rng)
    assert empty.n == 0 and empty.k == 33


def test_params_validation():
    assert BQPParams().zeta == 0.3 and BQPParams().eta == 0.2
    assert BQPParams().update_threshold == 0.6
    with pytest.raises(ValueError, match="zeta"):
        BQPParams(zeta=-1)
    with pytest.raises(ValueError, match="update_threshold"):
        BQPParams(update_threshold=1.5)
    with pytest.raises(ValueError, match="appearance"):
        BQPParams(appearance="hog")
    with pytest.raises(ValueError, match="fw_variant"):
        BQPParams(fw_variant="newton")
    with pytest.raises(ValueError, match="n_extrema"):
        BQPParams(n_extrema=0)
    with pytest.raises(ValueError, match="w_sp"):
        BQPParams(w_sp=float("nan"))
    assert search_radius(14, 2.0) == 7


def test_grouping_with_relative_offsets():
    rng = np.random.default_rng(4)
    cand = rng.uniform(0, 20, (3, 5, 2))
    edges = np.array([[0, 1], [2, 1]])
    off = np.array([[-4.0, 1.0], [3.0, 3.0]])
    q = grouping_matrix(cand, edges, off, sigma=3.0, cutoff=2.0).toarray()
    p = cand.reshape(-1, 2)
    w = np.zeros((15, 15))
    for (a, b), e in zip(edges, off, strict=True):
        for i in range(5):
            for j in range(5):
                dev = np.linalg.norm(p[a * 5 + i] - p[b * 5 + j] - e)
                if dev <= 6.0:
                    w[a * 5 + i, b * 5 + j] = w[b * 5 + j, a * 5 + i] = np.exp(-(dev**2) / 18)
    deg = w.sum(1)
    inv = np.where(deg > 0, 1 / np.sqrt(np.where(deg > 0, deg, 1)), 0)
    np.testing.assert_allclose(
        q, np.diag((deg > 0) * 1.0) - inv[:, None] * w * inv[None], atol=1e-12
    )


def test_regularised_laplacian_keeps_weak_couplings_weak():
    far = np.array([[[0.0, 0.0]], [[5.9, 0.0]]])  # one barely-similar pair (S ~ 0.14)
    plain = proximity_matrix(far, 3.0, 2.0).toarray()
    reg = proximity_matrix(far, 3.0, 2.0, tau=1.0).toarray()
    s = np.exp(-(5.9**2) / 18)
    assert plain[0, 1] == pytest.approx(1.0)  # plain normalisation: full strength
    assert reg[0, 1] == pytest.approx(s / (s + 1.0))
    assert reg[0, 0] == pytest.approx(s / (s + 1.0))
    # the grouping Laplacian the same way: I - D^-1/2 Gamma D^-1/2 becomes
    # D / (D + tau) - (D + tau)^-1/2 Gamma (D + tau)^-1/2, one edge of length 4 px here, so
    # the pair 5.9 px apart deviates by 1.9 px: Gamma = D = exp(-1.9^2 / 18)
    edge, length = np.array([[0, 1]]), np.array([4.0])
    g = np.exp(-(1.9**2) / 18)
    plain_g = grouping_matrix(far, edge, length, 3.0, 2.0).toarray()
    reg_g = grouping_matrix(far, edge, length, 3.0, 2.0, tau=1.0).toarray()
    np.testing.assert_allclose(plain_g, [[1.0, -1.0], [-1.0, 1.0]], rtol=1e-12)
    w = g / (g + 1.0)
    np.testing.assert_allclose(reg_g, [[w, -w], [-w, w]], rtol=1e-12)
    rng = np.random.default_rng(5)
    cand = rng.uniform(0, 20, (4, 5, 2))
    for q in (
        proximity_matrix(cand, 3.0, 2.0, tau=1.0),
        grouping_matrix(cand, np.array([[0, 1], [1, 2]]), np.array([5.0, 7.0]), 3.0, 2.0, tau=1.0),
    ):
        assert np.linalg.eigvalsh(q.toarray()).min() > -1e-9


def test_quadratic_matrix_is_canonical_csc():
    rng = np.random.default_rng(6)
    cand = rng.uniform(0, 30, (6, 7, 2))
    q = quadratic_matrix(
        cand,
        0.3,
        3.0,
        2.0,
        1.0,
        np.array([[0, 2], [2, 5], [1, 4]]),
        np.array([4.0, 6.0, 9.0]),
        2.0,
        2.0,
        1.0,
    )
    for col in range(q.shape[1]):
        rows = q.indices[q.indptr[col] : q.indptr[col + 1]]
        assert (np.diff(rows) > 0).all()  # sorted, no duplicates
    ref = q.copy()
    ref.has_sorted_indices = False
    ref.sort_indices()
    ref.sum_duplicates()
    np.testing.assert_array_equal(ref.indices, q.indices)
    np.testing.assert_allclose(q.toarray(), q.toarray().T, atol=1e-14)


INTEGER_CROWDS = {
    "n": st.integers(2, 6),
    "k": st.integers(1, 8),
    "seed": st.integers(0, 2**32 - 1),
    "span": st.sampled_from([6, 12, 30]),
}
"""``n`` targets of ``k`` candidates on integer points in ``[0, span)``: pairs fall exactly on
a cutoff of 5 px, where a lost boundary entry shows."""


@settings(max_examples=60, deadline=None)
@given(**INTEGER_CROWDS)
def test_proximity_links_exactly_the_pairs_within_reach(n, k, seed, span):
    """Every candidate pair of two targets within the cutoff (``d^2 <= reach^2`` as computed,
    boundary included: integer points at distance 5 of a reach of 5) gets an entry, and no
    other: the pair pre-selection (target pairs by candidate means and spread, then by
    candidate boxes) must not lose one."""
    cand = np.random.default_rng(seed).integers(0, span, (n, k, 2)).astype(np.float64)
    q = proximity_matrix(cand, sigma=2.5, cutoff=2.0)  # reach 5 px
    p = cand.reshape(-1, 2)
    dx = p[:, None, 0] - p[None, :, 0]
    dy = p[:, None, 1] - p[None, :, 1]
    tgt = np.repeat(np.arange(n), k)
    linked = (dx * dx + dy * dy <= 25.0) & (tgt[:, None] != tgt[None])
    off = q.toarray() * (1 - np.eye(n * k))
    np.testing.assert_array_equal(off != 0, linked)


@settings(max_examples=60, deadline=None)
@given(**INTEGER_CROWDS, offsets=st.booleans())
def test_grouping_links_exactly_the_pairs_within_reach(n, k, seed, span, offsets):
    """Along the tree edges, every candidate pair whose deviation from the edge's length
    (``| |p_i - p_j| - e |``, Eq. 10) or offset (``|p_i - p_j - e|``) is within the cutoff,
    boundary included (integer points and lengths), gets an entry, and no other: skipping
    the candidates whose partner's box is out of reach must not lose one."""
    rng = np.random.default_rng(seed)
    cand = rng.integers(0, span, (n, k, 2)).astype(np.float64)
    edges = np.array([[i, i + 1] for i in range(n - 1)] + ([[n - 1, 0]] if n > 2 else []))
    if offsets:
        ref = rng.integers(-span, span + 1, (len(edges), 2)).astype(np.float64)
    else:
        ref = rng.integers(0, span + 1, len(edges)).astype(np.float64)
    q = grouping_matrix(cand, edges, ref, sigma=2.5, cutoff=2.0)  # reach 5 px
    p = cand.reshape(-1, 2)
    linked = np.zeros((n * k, n * k), bool)
    for (a, b), e in zip(edges, ref, strict=True):
        lo, hi = (a, b) if a < b else (b, a)
        e = (e if a < b else -e) if offsets else e
        for i in range(k):
            for j in range(k):
                dx = p[lo * k + i, 0] - p[hi * k + j, 0]
                dy = p[lo * k + i, 1] - p[hi * k + j, 1]
                if offsets:
                    dev2 = (dx - e[0]) ** 2 + (dy - e[1]) ** 2
                else:
                    dev2 = (np.sqrt(dx * dx + dy * dy) - e) ** 2
                if dev2 <= 25.0:
                    linked[lo * k + i, hi * k + j] = linked[hi * k + j, lo * k + i] = True
    off = q.toarray() * (1 - np.eye(n * k))
    np.testing.assert_array_equal(off != 0, linked)


@pytest.mark.parametrize(
    ("b_points", "ref"),
    [
        ([[3.0, 4.0]], [0.0]),  # lengths: a deviation of 5, on the cutoff (the box a point)
        ([[6.0, 8.0]], [15.0]),  # |10 - 15| = 5, from below
        ([[3.0, 4.0], [9.0, 0.0]], [0.0]),  # deviations 5 and 9
        ([[6.0, 8.0], [0.0, 1.0]], [5.0]),  # |10 - 5| = 5 (on it) and |1 - 5| = 4
        ([[0.0, 0.5], [0.0, 12.0]], [5.5]),  # |0.5 - 5.5| = 5 from below, and 6.5
        ([[0.0, 0.0], [6.0, 8.0], [9.0, 9.0]], [-3.0, -4.0]),  # offsets: 5, 5 and 13
    ],
)
@pytest.mark.parametrize("tables", [False, True])
def test_grouping_pairs_on_the_cutoff_are_linked(b_points, ref, tables, monkeypatch):
    """Candidate pairs exactly on the cutoff (a reach of 5 px) are linked and those beyond
    it are not, whatever the partner's candidate box: the box test that skips candidates
    must not round a pair on the boundary away, nor the tables' bounds (``tables``: used
    wherever the candidates lie on whole pixels, however few the entries)."""
    if tables:
        _tables_always(monkeypatch)
    b = np.array(b_points)
    k = len(b)
    cand = np.stack([np.zeros((k, 2)), b])  # target 0: k copies of the origin
    e = np.array(ref)
    q = grouping_matrix(cand, np.array([[0, 1]]), e[None] if len(e) == 2 else e, 2.5, 2.0)
    dense = q.toarray()
    on_cutoff = 0
    for j in range(k):
        d = -b[j]  # p_a - p_b
        dev2 = ((d - e) ** 2).sum() if len(e) == 2 else (np.sqrt((d * d).sum()) - e[0]) ** 2
        on_cutoff += dev2 == 25.0
        for i in range(k):  # every copy of the origin alike
            assert (dense[i, k + j] != 0) == (dev2 <= 25.0), (i, j, dev2)
    assert on_cutoff >= 1


def _tables_always(monkeypatch) -> None:
    """Have quadratic_matrix take the Gaussians from tables whenever the candidates allow it
    (on whole pixels), however few entries they serve."""
    from tracker.bqp import quadratic

    real = quadratic._gauss_tables_for
    monkeypatch.setattr(
        quadratic, "_gauss_tables_for", lambda *args: real(*args[:-1], np.iinfo(np.int64).max)
    )


def _no_tables(monkeypatch) -> None:
    """Have quadratic_matrix exp every entry's exponent (the path of fractional candidates)."""
    from tracker.bqp import quadratic

    monkeypatch.setattr(quadratic, "_gauss_tables_for", lambda *args: None)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    offsets=st.booleans(),
    sp_sigma=st.floats(0.5, 8.0),
    sp_cutoff=st.floats(0.5, 3.0),
    g_sigma=st.floats(0.5, 6.0),
    g_cutoff=st.floats(0.5, 3.0),
)
def test_tabled_gaussians_are_the_exp_of_every_entry_bit_for_bit(
    seed, offsets, sp_sigma, sp_cutoff, g_sigma, g_cutoff
):
    """On whole pixels the entries' Gaussians come from tables of the distances the pairs
    can have (``_gauss_tables``): the matrix is exactly the one of each entry's own exp, for
    tree edges given by lengths and by offsets, including lengths shorter than the reach."""
    rng = np.random.default_rng(seed)
    n, k = 40, 12
    pos = np.rint(rng.uniform(0, 60, (n, 2)))
    cand = pos[:, None, :] + rng.integers(-4, 5, (n, k, 2))
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    rel = pos[edges[:, 0]] - pos[edges[:, 1]] + rng.uniform(-2, 2, (n - 1, 2))
    ref = rel if offsets else np.linalg.norm(rel, axis=1)
    args = (cand, 0.5, sp_sigma, sp_cutoff, 1.0, edges, ref, g_sigma, g_cutoff, 1.0)
    with pytest.MonkeyPatch.context() as mp:
        _tables_always(mp)
        tabled = quadratic_matrix(*args)
    with pytest.MonkeyPatch.context() as mp:
        _no_tables(mp)
        each = quadratic_matrix(*args)
    np.testing.assert_array_equal(tabled.indptr, each.indptr)
    np.testing.assert_array_equal(tabled.indices, each.indices)
    np.testing.assert_array_equal(tabled.data, each.data)


def test_gaussian_tables_serve_whole_pixels_only():
    """The tables are built for candidates on whole pixels (the tracker's search grids),
    when they hold fewer values than the entries; fractional candidates exp each entry."""
    from tracker.bqp import quadratic

    flags = np.array([3, 2, 1])
    ref = np.array([[4.0, 0.0], [12.5, 0.0], [0.0, 0.0]])
    gauss = (0.5, 9.0, 0.5, 4.0)
    whole = np.zeros((3, 2, 2))
    s_tab, box, off, g_tab = quadratic._gauss_tables_for(whole, flags, ref, 1, gauss, 10_000)
    np.testing.assert_array_equal(s_tab, np.exp(-np.arange(10) * 0.5))
    assert box[2, 2] == 0 and off[-1] == len(g_tab)  # no tree edge: no table
    d = np.arange(box[0, 0], box[0, 0] + box[0, 2])
    dev2 = (np.sqrt(d) - 4.0) ** 2
    np.testing.assert_array_equal(g_tab[: off[1]], np.where(dev2 <= 4.0, np.exp(-dev2 * 0.5), 0))
    assert box[0, 0] <= 4 and box[0, 0] + box[0, 2] - 1 >= 36  # (4 - 2)^2 .. (4 + 2)^2
    assert quadratic._gauss_tables_for(whole + 0.5, flags, ref, 1, gauss, 10_000) is None
    assert quadratic._gauss_tables_for(whole, flags, ref, 1, gauss, 5) is None  # more than m
    # a reference no table can hold: each entry's own exp (which links none of its pairs)
    for bad in (np.nan, np.inf, 1e30):
        odd = ref.copy()
        odd[1, 0] = bad
        for mode in (1, 2):
            assert quadratic._gauss_tables_for(whole, flags, odd, mode, gauss, 10**12) is None


@pytest.mark.parametrize("length", [np.nan, 1e30])
def test_tree_edges_of_any_length_give_the_same_matrix_with_or_without_tables(length, monkeypatch):
    """An edge length no table can hold (not finite, or beyond every candidate) falls back to
    each entry's exp: that edge links nothing, the others as ever."""
    rng = np.random.default_rng(5)
    cand = np.rint(rng.uniform(0, 30, (6, 5, 2)))
    edges = np.array([[0, 1], [1, 2], [3, 4]])
    lengths = np.array([5.0, length, 7.0])
    tabled = quadratic_matrix(cand, 0.5, 3.0, 2.0, 1.0, edges, lengths, 2.0, 2.0, 1.0)
    _no_tables(monkeypatch)
    each = quadratic_matrix(cand, 0.5, 3.0, 2.0, 1.0, edges, lengths, 2.0, 2.0, 1.0)
    assert (tabled != each).nnz == 0 and np.isfinite(tabled.data).all()


def _crowd_terms(components: bool = True):
    """A crowd of 300 targets in three separate clusters, with tree edges inside them."""
    rng = np.random.default_rng(11)
    centres = np.array([[50.0, 50.0], [400.0, 60.0], [220.0, 400.0]])
    pos = np.concatenate([c + rng.uniform(-40, 40, (100, 2)) for c in centres])
    cand = pos[:, None, :] + rng.uniform(-5, 5, (300, 9, 2))
    edges = np.array([[i, i + 1] for i in range(0, 299) if i % 100 != 99])
    lengths = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    return quadratic_matrix(
        cand, 0.5, 4.0, 3.0, 1.0, edges, lengths, 2.0, 2.0, 1.0, components=components
    )


def test_quadratic_matrix_is_the_same_for_any_number_of_threads():
    from tracker.threads import max_threads, using_threads

    if max_threads() < 2:
        pytest.skip("needs 2 cores")
    with using_threads(1):
        q1, lab1, _ = _crowd_terms()
    with using_threads(2):
        q2, lab2, _ = _crowd_terms()
    np.testing.assert_array_equal(q1.indptr, q2.indptr)
    np.testing.assert_array_equal(q1.indices, q2.indices)
    np.testing.assert_array_equal(q1.data, q2.data)  # bit for bit
    np.testing.assert_array_equal(lab1, lab2)


@settings(max_examples=200, deadline=None)
@given(
    st.integers(1, 40).flatmap(
        lambda n: st.tuples(
            st.just(n), st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)))
        )
    )
)
def test_target_components_match_scipy_labels(graph):
    # the union-find numbers components as scipy does (by lowest target), so the solver's
    # split is the same partition in the same order
    n, edges = graph
    pa = np.array([a for a, _ in edges], np.int64)
    pb = np.array([b for _, b in edges], np.int64)
    g = sp.coo_matrix((np.ones(len(pa), np.int8), (pa, pb)), shape=(n, n))
    expected = connected_components(g, directed=False)[1]
    np.testing.assert_array_equal(target_components(n, pa, pb), expected)


def test_quadratic_matrix_grouped_by_component_is_q_permuted_exactly():
    """With split_share the targets are grouped by component: the matrix is the targets'-order
    matrix permuted, bit for bit, and the labels are non-decreasing slices."""
    q, labels, _ = _crowd_terms()
    rng = np.random.default_rng(11)
    centres = np.array([[50.0, 50.0], [400.0, 60.0], [220.0, 400.0]])
    pos = np.concatenate([c + rng.uniform(-40, 40, (100, 2)) for c in centres])
    cand = pos[:, None, :] + rng.uniform(-5, 5, (300, 9, 2))
    perm = rng.permutation(300)  # mix the clusters, so that grouping must reorder
    edges = np.array([[i, i + 1] for i in range(0, 299) if i % 100 != 99])
    lengths = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    rank = np.argsort(perm)
    args = (cand[perm], 0.5, 4.0, 3.0, 1.0, rank[edges], lengths, 2.0, 2.0, 1.0)
    plain, lab_plain, none = quadratic_matrix(*args, components=True)
    grouped, lab, order = quadratic_matrix(*args, components=True, split_share=0.9)
    assert none is None and order is not None
    assert (np.diff(lab) >= 0).all()
    np.testing.assert_array_equal(lab, lab_plain[order])
    for comp in np.unique(lab):  # each component keeps its targets' order
        assert (np.diff(order[lab == comp]) > 0).all()
    var = (order[:, None] * 9 + np.arange(9)).ravel()
    expect = plain[var][:, var].tocsc()
    expect.sort_indices()
    np.testing.assert_array_equal(grouped.indptr, expect.indptr)
    np.testing.assert_array_equal(grouped.indices, expect.indices)
    np.testing.assert_array_equal(grouped.data, expect.data)
    # a dominant component is not reordered
    assert quadratic_matrix(*args, components=True, split_share=0.01)[2] is None


@pytest.mark.parametrize(("zeta", "eta"), [(0.3, 0.2), (0.0, 0.7), (1.2, 0.0), (0.0, 0.0)])
def test_linear_cost_equals_the_separate_terms_bit_for_bit(zeta, eta):
    """The fused grid cost is -app + zeta c_m + eta c_nm + border * outside from the reference
    functions of Eq. 6 and 7, exactly, including padded neighbour slots and a slot no target
    uses, and cells outside the frame."""
    from tracker.bqp.terms import linear_cost

    rng = np.random.default_rng(2)
    n, r = 6, 3
    centers = np.array([[1, 1], [30, 12], [45, 20], [10, 18], [20, 5], [2, 22]])
    pred = centers + rng.normal(0, 1.5, (n, 2))
    pos, vel = pred - rng.normal(0, 1, (n, 2)), rng.normal(0, 2, (n, 2))
    nbr = np.array([[1, 2, -1], [0, -1, -1], [0, 1, -1], [-1, -1, -1], [5, -1, -1], [4, 3, -1]])
    wts = np.where(nbr >= 0, rng.random(nbr.shape), 0.0)
    app = rng.normal(size=(n, 2 * r + 1, 2 * r + 1)).astype(np.float32)
    grid = grid_positions(centers, r)
    expect = -app.astype(np.float64)
    if zeta > 0:
        expect += zeta * motion_cost(grid, pred, 1.7)
    if eta > 0:
        expect += eta * neighbourhood_cost(grid, pos, vel, nbr, wts, 1.7)
    outside = (grid[..., 0] < 0) | (grid[..., 0] > 47) | (grid[..., 1] < 0) | (grid[..., 1] > 23)
    expect += 10.0 * outside
    got = linear_cost(app, centers, r, pred, 1.7, zeta, eta, pos, vel, nbr, wts, 10.0, (48, 24))
    np.testing.assert_array_equal(got, expect)


def test_quadratic_matrix_components_are_independent():
    q, labels, order = _crowd_terms()
    assert order is None  # no split_share: block i is target i
    assert labels.shape == (300,)
    # the three clusters are 150+ px apart: at least three components, none spanning two
    assert len(np.unique(labels)) >= 3
    for cluster in range(3):
        assert (
            len(
                np.intersect1d(labels[: 100 * cluster], labels[100 * cluster : 100 * cluster + 100])
            )
            == 0
        )
    coo = q.tocoo()
    k = 9
    assert (labels[coo.row // k] == labels[coo.col // k]).all()
    # exactly symmetric: every value is computed once per side from the same operands
    np.testing.assert_array_equal(q.toarray(), q.toarray().T)


def test_quadratic_matrix_diagonal_is_all_q_holds_inside_a_block():
    """``diagonal=True`` returns Q's diagonal, and inside a target's block Q holds nothing
    else (what BlockQP.from_terms relies on), in the targets' order and grouped."""
    for share in (None, 0.9):
        q, labels, order, diag = _crowd_terms_with(split_share=share, diagonal=True)
        np.testing.assert_array_equal(diag, q.diagonal())
        coo = q.tocoo()
        same_block = coo.row // 9 == coo.col // 9
        np.testing.assert_array_equal(coo.row[same_block], coo.col[same_block])
        assert (order is None) == (share is None)
    plain = quadratic_matrix(
        np.zeros((3, 4, 2)) + [[[0.0, 0.0]], [[50.0, 0.0]], [[0.0, 90.0]]],
        1.0,
        2.0,
        2.0,
        0.0,
        np.zeros((0, 2), int),
        np.zeros(0),
        1.0,
        1.0,
        diagonal=True,
    )
    assert plain[0].nnz == 0 and plain[1].shape == (12,) and not plain[1].any()


def test_linked_pair_bits_fill_the_entries_a_full_scan_fills(monkeypatch):
    """The filling pass over the counting pass's link bits writes the matrix the full scan of
    every candidate pair writes, bit for bit (grouping by lengths and by offsets)."""
    import tracker.bqp.quadratic as quadratic

    rng = np.random.default_rng(5)
    pos = rng.uniform(0, 120, (60, 2))
    cand = pos[:, None, :] + rng.uniform(-6, 6, (60, 33, 2))  # k = 33: the speed-up's
    edges = np.array([[i, i + 1] for i in range(59)])
    lengths = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    offsets = pos[edges[:, 0]] - pos[edges[:, 1]]
    for ref in (lengths, offsets):
        args = (cand, 0.4, 4.0, 2.5, 1.0, edges, ref, 3.0, 2.0, 1.0)
        with_bits = quadratic_matrix(*args)
        monkeypatch.setattr(quadratic, "LINK_MASK_MAX_K", 0)
        scanned = quadratic_matrix(*args)
        monkeypatch.undo()
        assert with_bits.nnz > 60 * 33
        for field in ("indptr", "indices", "data"):
            np.testing.assert_array_equal(getattr(with_bits, field), getattr(scanned, field))


def _crowd_terms_with(**kwargs):
    """:func:`_crowd_terms`' crowd with ``quadratic_matrix`` options."""
    rng = np.random.default_rng(11)
    centres = np.array([[50.0, 50.0], [400.0, 60.0], [220.0, 400.0]])
    pos = np.concatenate([c + rng.uniform(-40, 40, (100, 2)) for c in centres])
    cand = pos[:, None, :] + rng.uniform(-5, 5, (300, 9, 2))
    perm = rng.permutation(300)
    edges = np.array([[i, i + 1] for i in range(0, 299) if i % 100 != 99])
    lengths = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    rank = np.argsort(perm)
    return quadratic_matrix(
        cand[perm],
        0.5,
        4.0,
        3.0,
        1.0,
        rank[edges],
        lengths,
        2.0,
        2.0,
        1.0,
        components=True,
        **kwargs,
    )


@pytest.mark.parametrize("before", ["fresh", "half-word", "doubles"])
@pytest.mark.parametrize("shape", [(600, 3, 99), (7, 3, 99), (0, 3, 99)])
def test_uniform_draws_are_rng_random_in_chunks(shape, before, monkeypatch):
    """The speed-up sampling's draws filled in chunks on two threads (the bit generator
    skipped ahead per chunk) are ``rng.random``'s numbers, and leave ``rng`` where it would
    be, a buffered 32-bit half included."""
    import tracker.candidates as cands
    from tracker.threads import max_threads, using_threads

    if max_threads() < 2:
        pytest.skip("needs 2 cores")
    monkeypatch.setattr(cands, "DRAWS_PER_THREAD", 1000)
    a, b = np.random.default_rng(7), np.random.default_rng(7)
    for r in (a, b):
        if before == "half-word":
            r.integers(0, 10, 5, dtype=np.int32)  # leaves half a 64-bit output buffered
        elif before == "doubles":
            r.random(3)
    with using_threads(2):
        got = cands.uniform_draws(b, shape)
    np.testing.assert_array_equal(got, a.random(shape))
    assert a.bit_generator.state == b.bit_generator.state
    np.testing.assert_array_equal(
        a.integers(0, 2**30, 9, dtype=np.int32), b.integers(0, 2**30, 9, dtype=np.int32)
    )
    np.testing.assert_array_equal(a.random(4), b.random(4))


def test_abs_max_is_numpys():
    from tracker.candidates import _abs_max

    v = np.random.default_rng(0).normal(size=(300, 81))
    assert _abs_max(v) == np.abs(v).max()
    assert _abs_max(-np.full((2, 3), 2.5)) == 2.5
    v[123, 4] = np.nan
    assert np.isnan(_abs_max(v)) and np.isnan(np.abs(v).max())


def test_a_correlation_exactly_at_the_threshold_links_the_pair():
    """``coherent_groups`` links at ``corr >= threshold``: steps (5, 0) and (3, 4) have a
    cosine of exactly 0.6."""
    t = np.arange(4.0)[:, None]
    history = np.stack([np.hstack([5 * t, 0 * t]), np.hstack([10 + 3 * t, 4 * t])], axis=1)
    assert coherent_groups(history, radius=100.0, threshold=0.6).tolist() == [0, 0]


def test_speedup_extrema_need_every_neighbour_higher_including_the_right_one():
    """A cell with a lower right neighbour is no local minimum; true minima rank first."""
    cost = (10.0 + np.arange(25, dtype=np.float64)).reshape(1, 5, 5)
    cost[0, 1, 1] = 3.0  # cell 6: its right neighbour (cell 7) is lower
    cost[0, 1, 2] = 2.0  # cell 7: a local minimum
    cost[0, 3, 3] = 4.0  # cell 18: a local minimum
    app = -cost.astype(np.float32)
    rng = np.random.default_rng(0)
    s = speedup_candidates(np.array([[20, 20]]), 2, cost, app, rng, n_extrema=3, n_samples=0)
    assert s.k == 3
    assert s.cell[0].tolist() == [7, 18, 6]
    np.testing.assert_array_equal(s.positions[0], [[20, 19], [21, 21], [19, 19]])


def test_eq7_neighbours_are_the_nearest_of_the_own_group():
    """Two interleaved lanes: by default the nearest targets of any group take the places,
    so with k = 2 each target finds at most one of its own; Eq. 7's set finds two."""
    x = np.arange(8, dtype=float) * 3.0
    pos = np.column_stack([x, np.zeros(8)])
    labels = np.array([0, 1] * 4)
    nbr, _ = neighbours_in_groups(pos, labels, k=2, radius=20.0, scale=1.0)
    assert ((nbr >= 0).sum(1) <= 1).all()
    nbr, w = neighbours_in_groups(pos, labels, k=2, radius=20.0, scale=1.0, same_group=True)
    assert nbr[0].tolist() == [2, 4] and nbr[3].tolist() in ([1, 5], [5, 1])
    assert (labels[nbr] == labels[:, None]).all()
    np.testing.assert_allclose(w.sum(1), 1.0)
    nbr, _ = neighbours_in_groups(pos, labels, k=2, radius=5.0, scale=1.0, same_group=True)
    assert (nbr == -1).all()  # the own group's nearest is 6 px away: beyond the radius


def test_a_repeated_candidate_counts_in_the_degrees_as_often_as_it_repeats():
    """Speed-up sampling can repeat a cell (:func:`speedup_candidates`); the repeat is a
    candidate of its own in Eq. 9's degrees. Target A's candidate a0 sits on B's b0 (S = 1),
    everything else is far apart. A on a0 with B on the far b1 pays a0's diagonal alone,
    ``D / (D + tau)`` (tau 1): 1/2 with b0 once, 2/3 with b0 repeated (D = 2), although
    neither choice selects b0; B on b0 (or its repeat) pays ``D_a0 / (D_a0 + 1) + 1/2 +
    2 / sqrt((D_a0 + 1) 2)``."""
    far = [[100.0, 0.0], [200.0, 0.0]]
    for b2, d_a0 in (([300.0, 0.0], 1.0), ([0.0, 0.0], 2.0)):  # b2 far, then b2 = b0
        cand = np.array([[[0.0, 0.0], *far], [[0.0, 0.0], [0.0, 500.0], b2]])
        q = proximity_matrix(cand, 3.0, 1.5, tau=1.0).toarray()

        def pay(i, j, q=q):
            x = np.zeros(6)
            x[[i, 3 + j]] = 1.0
            return x @ q @ x

        assert pay(0, 1) == pytest.approx(d_a0 / (d_a0 + 1.0), abs=1e-12)
        both = d_a0 / (d_a0 + 1.0) + 0.5 + 2.0 / np.sqrt((d_a0 + 1.0) * 2.0)
        assert pay(0, 0) == pytest.approx(both, abs=1e-12)
        assert pay(1, 1) == 0.0
    rng = np.random.default_rng(0)
    cost = np.zeros((1, 9, 9))
    cost[0, 0, 0] = -1.0  # an extremum in the grid's corner: its samples clip onto the edge
    s = speedup_candidates(np.array([[20, 20]]), 4, cost, -cost, rng, 1, 10, 10)
    assert s.k == 11 and len(np.unique(s.cell[0])) < s.k


def test_distinct_samples_take_no_cell_twice_and_leave_the_draws_as_they_were():
    """``distinct=True`` (BQP's ``distinct_samples``): the same extrema, no repeated cell, the
    corner extremum's samples on the grid around it, the generator in the same state; a grid
    smaller than ``k`` keeps the clipped samples."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(3)
    cost = gaussian_filter(rng.random((60, 13, 13)), (0, 1.5, 1.5))
    cost[0] = 1.0
    cost[0, 0, 0] = 0.0  # one extremum in a corner, the others the lowest other cells
    centers = np.full((60, 2), 40)
    keep_rng, own_rng = np.random.default_rng(1), np.random.default_rng(1)
    keep = speedup_candidates(centers, 6, cost, -cost, keep_rng, 3, 10, 10)
    own = speedup_candidates(centers, 6, cost, -cost, own_rng, 3, 10, 10, distinct=True)
    assert keep_rng.random() == own_rng.random()
    np.testing.assert_array_equal(own.cell[:, :3], keep.cell[:, :3])
    repeats = [own.k - len(np.unique(c)) for c in keep.cell]
    assert sum(repeats) > 60 and all(len(np.unique(c)) == own.k for c in own.cell)
    # the corner extremum's ten samples lie in its window (offsets -5..4) on the grid
    corner = own.cell[0, 3:13]
    assert ((corner // 13 <= 4) & (corner % 13 <= 4)).all()
    # candidates' positions, costs and appearance follow their cells
    np.testing.assert_array_equal(own.positions[:, :, 0], 40 + own.cell % 13 - 6)
    np.testing.assert_array_equal(own.cost, np.take_along_axis(cost.reshape(60, -1), own.cell, 1))
    small = np.random.default_rng(0).random((4, 5, 5))  # 25 cells for k = 33: repeats stay
    a = speedup_candidates(centers[:4], 2, small, -small, np.random.default_rng(2), 3, 10, 10)
    b = speedup_candidates(
        centers[:4], 2, small, -small, np.random.default_rng(2), 3, 10, 10, distinct=True
    )
    np.testing.assert_array_equal(a.cell, b.cell)
    with pytest.raises(ValueError, match="distinct_samples must be one of"):
        BQPParams(distinct_samples="yes")
