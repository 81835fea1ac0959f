"""Frank-Wolfe solver of the relaxed BQP: properties, exact tiny cases, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tracker.bqp.frank_wolfe import VARIANTS, FWParams, FWResult, default_start, solve
from tracker.bqp.qp import BlockQP, load_many, save_many
from tracker.bqp.qp_baselines import solve_clarabel, solve_osqp

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_qp(
    seed: int, n: int, kmax: int, density: float = 0.3, rank: int = 4, diag: float = 0.05
) -> BlockQP:
    """Random PSD instance: Q = M M^T (sparse, low rank) + diag I, blocks of 1..kmax."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, kmax + 1, size=n)
    bp = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    l = int(bp[-1])
    M = sp.random(l, rank, density=density, random_state=rng) if l else sp.csc_matrix((0, rank))
    Q = (M @ M.T + diag * sp.identity(l)).tocsc()
    c = rng.normal(size=l)
    return BlockQP(c, Q, bp)


def check_result(qp: BlockQP, res: FWResult, eps: float) -> None:
    n = qp.n_blocks
    assert res.choice.shape == (n,) and res.choice.dtype == np.int64
    assert np.all(res.choice >= 0) and np.all(res.choice < qp.block_sizes)
    v = qp.vertex(res.choice)
    np.testing.assert_allclose(qp.block_sums(v), 1.0)
    assert np.all(res.x >= 0)
    np.testing.assert_allclose(qp.block_sums(res.x), 1.0, atol=1e-9)
    assert np.isclose(res.objective, qp.objective(res.x), rtol=1e-9, atol=1e-9)
    assert np.isclose(res.rounded_objective, qp.objective(v), rtol=1e-9, atol=1e-9)
    if res.converged:
        assert res.gap <= eps
    # The reported gap is the exact FW duality gap at x.
    g = qp.gradient(res.x)
    exact = sum(
        float(g[lo:hi] @ res.x[lo:hi] - g[lo:hi].min())
        for lo, hi in zip(qp.block_ptr[:-1], qp.block_ptr[1:], strict=True)
    )
    assert res.gap == pytest.approx(exact, abs=1e-9)
    for b in range(n):  # rounding = argmax per block
        lo, hi = qp.block_ptr[b], qp.block_ptr[b + 1]
        assert res.x[lo + res.choice[b]] == res.x[lo:hi].max()


# ---------------------------------------------------------------------------- properties
@FAST
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(0, 12),
    kmax=st.integers(1, 7),
    variant=st.sampled_from(VARIANTS),
    eps=st.sampled_from([1e-2, 1e-4, 1e-7]),
)
def test_feasible_monotone_and_gap(seed, n, kmax, variant, eps):
    qp = random_qp(seed, n, kmax)
    x0 = default_start(qp)
    res = solve(qp, params=FWParams(variant=variant, eps=eps, max_iter=20_000, record_history=True))
    check_result(qp, res, eps)
    # Plain FW converges sublinearly when the optimum lies on a face: no guarantee there.
    assert res.converged or (variant == "plain" and res.iterations == 20_000)
    assert res.objective <= qp.objective(x0) + 1e-12
    # Every step decreases f (exact line search on a convex quadratic).
    assert np.all(np.diff(res.history) <= 1e-12)
    assert res.history[0] == pytest.approx(qp.objective(x0))
    assert res.history[-1] == pytest.approx(res.objective, abs=1e-9)


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 10), kmax=st.integers(1, 6))
def test_matches_clarabel(seed, n, kmax):
    qp = random_qp(seed, n, kmax)
    ref = solve_clarabel(qp)
    res = solve(qp, params=FWParams(eps=1e-7, max_iter=50_000))
    assert res.converged
    # f(x) - f* <= gap, and Clarabel is accurate to ~1e-8.
    assert res.objective == pytest.approx(ref.objective, abs=1e-6, rel=1e-6)
    assert res.objective >= ref.objective - 1e-6


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 8), kmax=st.integers(1, 5))
def test_warm_start_from_random_interior_point(seed, n, kmax):
    qp = random_qp(seed, n, kmax)
    rng = np.random.default_rng(seed)
    x0 = rng.random(qp.n_vars) + 0.01
    x0 /= np.repeat(qp.block_sums(x0), qp.block_sizes)
    for variant in VARIANTS:
        res = solve(qp, x0, FWParams(variant=variant, eps=1e-6, max_iter=50_000))
        check_result(qp, res, 1e-6)
        assert res.converged or variant == "plain"
        assert res.objective <= qp.objective(x0) + 1e-12


def test_matches_osqp_medium():
    qp = random_qp(7, 60, 8, density=0.1, rank=20)
    ref = solve_osqp(qp, tol=1e-8)
    res = solve(qp, params=FWParams(eps=1e-7, max_iter=200_000))
    assert res.converged
    assert res.objective == pytest.approx(ref.objective, rel=1e-5)


# ---------------------------------------------------------------------- exact tiny cases
def test_linear_problem_picks_cheapest_candidates():
    c = np.array([3.0, 1.0, 2.0, 5.0, -1.0])
    qp = BlockQP(c, sp.csc_matrix((5, 5)), np.array([0, 3, 5]))
    res = solve(qp, x0=np.array([1 / 3, 1 / 3, 1 / 3, 0.5, 0.5]))
    np.testing.assert_array_equal(res.choice, [1, 1])
    assert res.objective == pytest.approx(0.0)
    assert res.gap == 0.0 and res.converged


def test_hand_built_two_targets_known_optimum():
    # Two targets, two candidates each. Linear costs prefer candidate 0 for both, but the
    # two candidate-0 locations coincide: a proximity penalty 2*w*x0*y0 (w = 2) makes the
    # joint choice (0, 0) cost -1 - 1 + 2*2 = 2, worse than (0, 1): -1 - 0.5 = -1.5.
    c = np.array([-1.0, 0.0, -1.0, -0.5])
    w = 2.0
    Q = sp.csc_matrix(np.array([[0, 0, w, 0], [0, 0, 0, 0], [w, 0, 0, 0], [0, 0, 0, 0.0]]))
    # Not PSD on its own; add a PSD-making diagonal identical on every candidate: on the
    # simplex sum x^2 differs between vertices only by constants (1 per block at vertices).
    Q = Q + sp.identity(4) * w
    qp = BlockQP(c, sp.csc_matrix(Q), np.array([0, 2, 4]))
    assert np.all(np.linalg.eigvalsh(qp.Q.toarray()) >= -1e-12)
    res = solve(qp, params=FWParams(eps=1e-10, max_iter=10_000))
    # Relaxed optimum by hand: x = (a, 1-a), y = (b, 1-b); f is a 2-variable quadratic.
    grid = np.linspace(0, 1, 2001)
    A, B = np.meshgrid(grid, grid, indexing="ij")
    f = -A - B - 0.5 * (1 - B) + 2 * w * A * B + w * (A**2 + (1 - A) ** 2 + B**2 + (1 - B) ** 2)
    assert res.objective == pytest.approx(f.min(), abs=1e-6)
    ref = solve_clarabel(qp)
    assert res.objective == pytest.approx(ref.objective, abs=1e-7)
    # The vertices (0,0) and (0,1): rounded objective is f at the choice.
    assert res.rounded_objective == pytest.approx(qp.objective(qp.vertex(res.choice)))


def test_swap_step_exact_solution():
    # One block of three, Q = I: min c.x + |x|^2 on the simplex is a projection,
    # x* = max(-c/2 - tau, 0) with tau set by sum = 1.
    c = np.array([0.0, -0.2, 1.0])
    qp = BlockQP(c, sp.identity(3, format="csc"), np.array([0, 3]))
    res = solve(qp, params=FWParams(eps=1e-12, max_iter=1000))
    np.testing.assert_allclose(res.x, [0.45, 0.55, 0.0], atol=1e-9)
    assert res.objective == pytest.approx(-0.2 * 0.55 + 0.45**2 + 0.55**2)
    np.testing.assert_array_equal(res.choice, [1])


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_block_with_coupled_candidates_by_hand(variant):
    """One block of three whose candidates are coupled inside the block (``Q_sy != 0``): the
    SWAP step's curvature ``Q_ss + Q_yy - 2 Q_sy`` needs the coupling. By hand, the KKT
    conditions ``c + 2 Q x = lambda 1`` hold at ``x = (0.15, 0.25, 0.6)`` (``lambda = 1.65``),
    ``f = c.x + x'Qx = 0.065 + 0.7925``. An exact line search lands there in a few steps
    (measured: 4 for swap), and the history's running sum of the step decreases is ``f``."""
    q = np.array([[2.0, 1.5, 0.0], [1.5, 2.0, 0.5], [0.0, 0.5, 1.0]])
    c = np.array([0.3, -0.4, 0.2])
    qp = BlockQP(c, sp.csc_matrix(q), np.array([0, 3]))
    x = np.array([0.15, 0.25, 0.6])
    np.testing.assert_allclose(c + 2 * q @ x, 1.65, atol=1e-12)
    res = solve(
        qp, params=FWParams(variant=variant, eps=1e-12, max_iter=10_000, record_history=True)
    )
    assert res.converged
    np.testing.assert_allclose(res.x, x, atol=1e-6)
    assert res.objective == pytest.approx(0.8575, abs=1e-12)
    assert res.history[-1] == pytest.approx(res.objective, abs=1e-12)
    if variant in ("swap", "block"):  # "block" takes SWAP steps: Q is not diagonal in-block
        assert res.steps["swap"] >= 1 and res.iterations <= 10, res.steps


def test_zero_blocks():
    qp = BlockQP(np.zeros(0), sp.csc_matrix((0, 0)), np.array([0]))
    for variant in VARIANTS:
        res = solve(qp, params=FWParams(variant=variant, record_history=True))
        assert res.converged and res.iterations == 0 and res.gap == 0.0
        assert res.choice.shape == (0,) and res.x.shape == (0,)
        assert res.objective == 0.0 and res.rounded_objective == 0.0


def test_blocks_of_size_one():
    qp = random_qp(3, 5, 1)
    for variant in VARIANTS:
        res = solve(qp, params=FWParams(variant=variant))
        np.testing.assert_array_equal(res.choice, np.zeros(5, dtype=np.int64))
        np.testing.assert_array_equal(res.x, np.ones(5))
        assert res.iterations == 0 and res.converged


def test_max_iter_stops_unconverged():
    qp = random_qp(11, 30, 6)
    res = solve(qp, params=FWParams(variant="plain", eps=0.0, max_iter=3))
    assert res.iterations == 3 and not res.converged
    check_result(qp, res, 0.0)
    res0 = solve(qp, params=FWParams(max_iter=0))
    np.testing.assert_array_equal(res0.x, default_start(qp))


def test_default_start_is_cheapest_linear_vertex():
    qp = BlockQP(np.array([2.0, 1.0, 1.0, 0.0]), sp.csc_matrix((4, 4)), np.array([0, 3, 4]))
    np.testing.assert_array_equal(default_start(qp), [0, 1, 0, 1])


def test_save_load_roundtrip(tmp_path):
    qps = [random_qp(s, 4, 5) for s in range(3)]
    save_many(tmp_path / "many.npz", qps)
    qps[0].save(tmp_path / "one.npz")
    back = load_many(tmp_path / "many.npz")
    assert len(back) == 3
    for a, b in zip(qps, back, strict=True):
        np.testing.assert_array_equal(a.c, b.c)
        np.testing.assert_array_equal(a.block_ptr, b.block_ptr)
        assert (a.Q != b.Q).nnz == 0
    one = BlockQP.load(tmp_path / "one.npz")
    np.testing.assert_array_equal(one.c, qps[0].c)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="bad.npz"):
        load_many(tmp_path / "bad.npz")
    np.savez(tmp_path / "partial.npz", c=np.zeros(2))
    with pytest.raises(ValueError, match="Q_data"):
        load_many(tmp_path / "partial.npz")


# ----------------------------------------------------------------------------- iterations
def test_iteration_order_on_tracking_like_instances():
    """Fig. 13: SWAP needs fewer iterations than away steps, which need fewer than plain FW."""
    from tracker.testing import FrameSpec, synthetic_frame_qp

    its = {v: [] for v in VARIANTS}
    for seed in range(3):
        qp = synthetic_frame_qp(FrameSpec(n_targets=40), np.random.default_rng(seed))
        for v in VARIANTS:
            res = solve(qp, params=FWParams(variant=v, eps=1e-4, max_iter=200_000))
            assert res.converged
            its[v].append(res.iterations)
    mean = {v: float(np.mean(its[v])) for v in VARIANTS}
    assert mean["swap"] <= mean["away"] <= mean["plain"], mean


# ---------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("variant", ["Swap", "pairwise", ""])
def test_unknown_variant(variant):
    with pytest.raises(ValueError, match="variant"):
        FWParams(variant=variant)


@pytest.mark.parametrize(
    "kw", [{"eps": -1.0}, {"eps": float("nan")}, {"max_iter": -1}, {"max_iter": 2.5}]
)
def test_bad_params(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        FWParams(**kw)


def test_non_symmetric_q():
    Q = sp.csc_matrix(np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="Q must be symmetric"):
        BlockQP(np.zeros(2), Q, np.array([0, 2]))


@pytest.mark.parametrize(
    "bp, msg",
    [
        ([0, 1], r"block_ptr\[-1\]"),
        ([1, 3], r"block_ptr\[0\]"),
        ([0, 2, 2, 3], "non-empty"),
        ([0, 3, 1, 3], "non-empty"),
        ([[0, 3]], "block_ptr must be 1-D"),
        ([0.5, 3], "block_ptr must be integers"),
    ],
)
def test_bad_block_ptr(bp, msg):
    with pytest.raises(ValueError, match=msg):
        BlockQP(np.zeros(3), sp.identity(3, format="csc"), np.array(bp))


def test_bad_q_and_c():
    with pytest.raises(ValueError, match="Q must have shape"):
        BlockQP(np.zeros(3), sp.identity(2, format="csc"), np.array([0, 3]))
    with pytest.raises(ValueError, match="Q must be a scipy.sparse"):
        BlockQP(np.zeros(2), np.eye(2), np.array([0, 2]))
    with pytest.raises(ValueError, match=r"c must be finite; c\[1\]"):
        BlockQP(np.array([0.0, np.nan]), sp.identity(2, format="csc"), np.array([0, 2]))
    with pytest.raises(ValueError, match="c must be 1-D"):
        BlockQP(np.zeros((2, 1)), sp.identity(2, format="csc"), np.array([0, 2]))


@pytest.mark.parametrize(
    "x0, msg",
    [
        ([0.5, 0.4, 0.5, 0.5], "x0 must sum to 1"),
        ([1.5, -0.5, 1.0, 0.0], "x0 must be >= 0"),
        ([1.0, 0.0, 1.0], r"x0 must have shape"),
        ([np.nan, 1.0, 1.0, 0.0], "x0 must be finite"),
    ],
)
def test_infeasible_x0(x0, msg):
    qp = BlockQP(np.zeros(4), sp.identity(4, format="csc"), np.array([0, 2, 4]))
    with pytest.raises(ValueError, match=msg):
        solve(qp, np.array(x0))


def test_q_is_canonicalised_and_never_densified():
    # Duplicate entries are summed and rows sorted (the kernels binary-search columns).
    Q = sp.csc_matrix(
        (np.array([1.0, 1.0, 2.0]), np.array([0, 0, 1]), np.array([0, 2, 3])), shape=(2, 2)
    )
    qp = BlockQP(np.zeros(2), Q, np.array([0, 2]))
    assert sp.issparse(qp.Q) and qp.Q.nnz == 2 and qp.Q[0, 0] == 2.0
    assert qp.Q.has_canonical_format
    # Unsorted rows and CSR / COO input are accepted too.
    Q = sp.csc_matrix(
        (np.array([1.0, 0.5, 0.5, 1.0]), np.array([1, 0, 1, 0]), np.array([0, 2, 4])), shape=(2, 2)
    )
    Q.has_sorted_indices = False
    for M in (Q, Q.tocsr(), Q.tocoo()):
        qp = BlockQP(np.array([0.0, 1.0]), M, np.array([0, 2]))
        res = solve(qp, params=FWParams(eps=1e-9))
        assert res.objective == pytest.approx(solve_clarabel(qp).objective, abs=1e-7)


# ----------------------------------------------------------------------------- benchmark
def test_bench_solver_smoke(tmp_path, capsys):
    import json

    from crowdsim.bench import main as bench_main

    def main(argv):
        return bench_main("solver", argv)

    npz = tmp_path / "frames.npz"
    args = [
        "--sizes",
        "8,12",
        "--frames",
        "1",
        "--repeats",
        "1",
        "--out",
        str(tmp_path),
        "--save-npz",
        str(npz),
    ]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(report["summary"]) == {"8", "12"}
    for s in report["summary"].values():
        assert s["all_converged"] and s["max_abs_rel_objective_diff"] < 1e-3
    assert (tmp_path / "solver_convergence.png").stat().st_size > 0
    # Dumped frames come back through --from-npz with the same results.
    assert main(["--from-npz", str(npz), "--repeats", "1", "--no-plot", "--reference", "none"]) == 0
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["source"] == "npz"
    for n in ("8", "12"):
        assert again["summary"][n]["iterations_swap"] == report["summary"][n]["iterations_swap"]
    assert main(["--from-npz", str(tmp_path / "missing.npz")]) == 2
    assert main(["--sizes", "ten"]) == 2


def test_eps_zero_stops_at_round_off():
    for seed in range(4):
        qp = random_qp(seed, 10, 5)
        for variant in VARIANTS:
            res = solve(qp, params=FWParams(variant=variant, eps=0.0, max_iter=100_000))
            assert res.iterations < 100_000
            assert res.gap < 1e-9
            check_result(qp, res, 0.0)


def test_bench_solver_on_tracker_frames(capsys):
    import json

    pytest.importorskip("cv2")
    from crowdsim.bench import main as bench_main

    def main(argv):
        return bench_main("solver", argv)

    assert (
        main(
            [
                "--tracker-frames",
                "3",
                "--frames",
                "2",
                "--sizes",
                "6",
                "--repeats",
                "1",
                "--no-plot",
            ]
        )
        == 0
    )
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["source"] == "tracker" and len(report["problems"]) == 2
    assert report["summary"]["6"]["all_converged"]


# ------------------------------------------------------------ independent components
def interleaved_components(seed: int, parts: int, n: int, kmax: int) -> tuple[BlockQP, np.ndarray]:
    """``parts`` independent random problems whose blocks are shuffled together: the joint
    ``Q`` is block-diagonal up to a permutation of the blocks. Returns it and the labels."""
    rng = np.random.default_rng(seed)
    qps = [random_qp(int(rng.integers(2**31)), n, kmax) for _ in range(parts)]
    labels = rng.permutation(np.repeat(np.arange(parts), n))
    where = [np.flatnonzero(labels == p) for p in range(parts)]
    sizes = np.zeros(parts * n, np.int64)
    for p, qp in enumerate(qps):
        sizes[where[p]] = qp.block_sizes
    bp = np.concatenate([[0], np.cumsum(sizes)])
    c = np.zeros(bp[-1])
    rows, cols, vals = [], [], []
    for p, qp in enumerate(qps):
        # variable v of problem p sits at the same place of its block in the joint problem
        new = np.concatenate([np.arange(bp[b], bp[b + 1]) for b in where[p]])
        c[new] = qp.c
        q = qp.Q.tocoo()
        rows.append(new[q.row])
        cols.append(new[q.col])
        vals.append(q.data)
    l = int(bp[-1])
    Q = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(l, l)
    )
    return BlockQP(c, Q, bp), labels


@FAST
@given(
    seed=st.integers(0, 2**31 - 1),
    parts=st.integers(2, 6),
    n=st.integers(1, 8),
    variant=st.sampled_from(VARIANTS),
)
def test_components_solved_apart_meet_the_whole_problems_gap(seed, parts, n, variant):
    qp, labels = interleaved_components(seed, parts, n, 5)
    eps = 1e-4
    params = FWParams(variant=variant, eps=eps, max_iter=20_000)
    split = solve(qp, params=params, components=labels)
    whole = solve(qp, params=params)
    check_result(qp, split, eps)
    if variant != "plain":  # plain FW zig-zags: 1e-4 may take more than max_iter
        assert split.converged
    if split.converged and whole.converged:  # both eps-optimal for the same problem
        assert abs(split.objective - whole.objective) <= 2 * eps
    # a component solved on its own with its share of eps gives the same blocks
    p0 = np.flatnonzero(labels == labels[0])
    sub_vars = np.concatenate([np.arange(qp.block_ptr[b], qp.block_ptr[b + 1]) for b in p0])
    sub = BlockQP(
        qp.c[sub_vars], qp.Q[sub_vars][:, sub_vars], np.r_[0, np.cumsum(qp.block_sizes[p0])]
    )
    alone = solve(
        sub,
        params=FWParams(
            variant=variant,
            eps=eps * len(p0) / qp.n_blocks,
            max_iter=-(-20_000 * len(p0) // qp.n_blocks),  # the solver's share: ceil
        ),
    )
    np.testing.assert_array_equal(split.x[sub_vars], alone.x)


def test_components_split_is_the_same_for_any_number_of_threads():
    numba = pytest.importorskip("numba")
    from tracker.threads import max_threads, using_threads

    if max_threads() < 2:
        pytest.skip("needs 2 cores")
    qp, labels = interleaved_components(7, 40, 6, 6)
    with using_threads(1):
        one = solve(qp, components=labels)
    with using_threads(2):
        assert numba.get_num_threads() == 2
        two = solve(qp, components=labels)
    np.testing.assert_array_equal(one.x, two.x)
    assert one.objective == two.objective and one.iterations == two.iterations


def test_one_dominant_component_is_solved_whole():
    qp, labels = interleaved_components(3, 2, 10, 4)
    labels[:] = 0
    labels[0] = 1  # 19 of 20 blocks in one component: above SPLIT_MAX_SHARE
    whole = solve(qp)
    same = solve(qp, components=labels)
    np.testing.assert_array_equal(whole.x, same.x)
    assert whole.iterations == same.iterations


def test_components_labels_are_checked():
    qp, labels = interleaved_components(3, 2, 4, 3)
    with pytest.raises(ValueError, match="components must be"):
        solve(qp, components=labels[:-1])
    with pytest.raises(ValueError, match="components must be"):
        solve(qp, components=labels.astype(float))


def test_grouped_components_are_solved_in_place_as_when_permuted():
    """Blocks already grouped by component (non-decreasing labels, as the tracker builds its
    QP) give the same solution as the interleaved problem solved through the permuted copy."""
    qp, labels = interleaved_components(4, 3, 8, 5)
    mixed = solve(qp, components=labels)
    order = np.argsort(labels, kind="stable")
    var = np.concatenate([np.arange(qp.block_ptr[b], qp.block_ptr[b + 1]) for b in order])
    bp = np.concatenate([[0], np.cumsum(qp.block_sizes[order])])
    Q = qp.Q[var][:, var].tocsc()
    Q.sort_indices()
    grouped = solve(BlockQP(qp.c[var], Q, bp), components=labels[order])
    np.testing.assert_array_equal(grouped.x, mixed.x[var])
    np.testing.assert_array_equal(grouped.choice, mixed.choice[order])
    assert grouped.iterations == mixed.iterations and grouped.steps == mixed.steps


def test_from_terms_keeps_the_cheap_checks():
    """BlockQP.from_terms (a Q from quadratic_matrix) is the same problem as the checked
    constructor, and still refuses a non-finite c or a broken block layout."""
    qp = random_qp(3, 6, 4)
    fast = BlockQP.from_terms(qp.c, qp.Q, qp.block_ptr)
    np.testing.assert_array_equal(fast.block_of, qp.block_of)
    assert solve(fast).objective == solve(qp).objective
    bad_c = qp.c.copy()
    bad_c[2] = np.nan
    with pytest.raises(ValueError, match="BlockQP.c"):
        BlockQP.from_terms(bad_c, qp.Q, qp.block_ptr)
    with pytest.raises(ValueError, match="BlockQP.block_ptr"):
        BlockQP.from_terms(qp.c, qp.Q, qp.block_ptr[:-1])
    with pytest.raises(ValueError, match="BlockQP.Q"):
        BlockQP.from_terms(qp.c, qp.Q.tocsr(), qp.block_ptr)


def test_lone_blocks_without_entries_give_the_loops_figures():
    """Components with no entry of Q (lone targets) skip the loop's set-up: x, gap, objective
    and iterations are those of the loop on the whole problem, and a lone block whose start
    is not optimal still takes its steps."""
    rng = np.random.default_rng(6)
    n, k = 6, 4
    c = rng.normal(size=n * k)
    qp = BlockQP(c, sp.csc_matrix((n * k, n * k)), np.arange(0, n * k + 1, k))
    x0 = default_start(qp)
    x0[k : 2 * k] = 1.0 / k  # block 1 starts inside its simplex
    split = solve(qp, x0=x0, components=np.arange(n))
    whole = solve(qp, x0=x0)
    np.testing.assert_array_equal(split.x, whole.x)
    np.testing.assert_array_equal(split.choice, c.reshape(n, k).argmin(1))
    assert split.iterations == whole.iterations == 1 and split.converged
    assert split.gap == whole.gap == 0.0
    assert split.objective == pytest.approx(whole.objective, abs=1e-12)


@FAST
@given(
    leaves=st.lists(st.floats(0.0, 10.0), min_size=1, max_size=40),
    updates=st.lists(st.tuples(st.integers(0, 39), st.floats(0.0, 10.0)), max_size=60),
)
def test_gap_tree_stays_a_max_tree_under_updates(leaves, updates):
    # The solver's max-gap tree repairs ancestors only until one's maximum is unchanged;
    # after any sequence of updates every node must still be the max of its children and
    # the argmax the first largest leaf (np.argmax), as with a full repair.
    from tracker.bqp.frank_wolfe import _tree_argmax, _tree_update

    n = len(leaves)
    size = 1
    while size < n:
        size *= 2
    tree = np.full(2 * size, -1.0)
    values = np.full(size, -1.0)
    for i, v in enumerate(leaves):
        _tree_update(tree, size, i, v)
        values[i] = v
    for i, v in updates:
        i %= n
        _tree_update(tree, size, i, v)
        values[i] = v
        assert _tree_argmax(tree, size) == int(np.argmax(values))
    for node in range(1, size):
        assert tree[node] == max(tree[2 * node], tree[2 * node + 1])


def test_a_known_diagonal_solves_as_the_gathered_block_parts():
    """BlockQP.from_terms with quadratic_matrix's diagonal: the blocks' parts of Q come from
    it instead of a search of every column; the same arrays, and the same solve bit for bit,
    whole, split in place and split through the permuted copy."""
    from tracker.bqp.frank_wolfe import _intra_block, _intra_diagonal
    from tracker.bqp.quadratic import quadratic_matrix

    rng = np.random.default_rng(3)
    centres = np.array([[40.0, 40.0], [300.0, 50.0], [150.0, 300.0]])
    pos = np.concatenate([c + rng.uniform(-30, 30, (40, 2)) for c in centres])
    pos = pos[rng.permutation(120)]  # the components interleaved
    cand = pos[:, None, :] + rng.uniform(-5, 5, (120, 7, 2))
    edges = np.array([[i, i + 1] for i in range(119)])
    lengths = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    args = (cand, 0.5, 4.0, 3.0, 0.5, edges, lengths, 2.0, 2.0, 1.0)
    for share in (None, 0.9):
        q, labels, order, diag = quadratic_matrix(
            *args, components=True, split_share=share, diagonal=True
        )
        c = rng.normal(size=q.shape[0])
        bp = np.arange(0, q.shape[0] + 1, 7)
        known = BlockQP.from_terms(c, q, bp, diag)
        gathered = BlockQP.from_terms(c, q, bp)
        assert gathered.diagonal is None
        for a, b in zip(
            _intra_diagonal(diag, bp, known.block_of),
            _intra_block(q.indptr, q.indices, q.data, bp, known.block_of),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)
        for comps in (None, labels):
            one, two = solve(known, components=comps), solve(gathered, components=comps)
            np.testing.assert_array_equal(one.x, two.x)
            assert one.iterations == two.iterations and one.objective == two.objective
    with pytest.raises(ValueError, match="BlockQP.diagonal"):
        BlockQP.from_terms(c, q, bp, diag[:-1])
    with pytest.raises(ValueError, match="BlockQP.diagonal"):
        BlockQP.from_terms(c, q, bp, diag.astype(np.float32))


# ------------------------------------------------------------------- the exact block step
def laplacian_qp(seed: int, n: int, kmax: int, isolated: float = 0.2) -> BlockQP:
    """Random PSD instance shaped as the tracker's: ``Q = a (D + W) + b (D - W)`` with ``W``
    a sparse non-negative similarity between candidates of different blocks and ``D =
    diag(W 1)``, so that inside a block ``Q`` holds its diagonal alone; a share of the
    candidates link to nothing (a zero diagonal)."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, kmax + 1, size=n)
    bp = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    l = int(bp[-1])
    block_of = np.repeat(np.arange(n), sizes)
    W = sp.random(l, l, density=min(1.0, 4.0 / max(l, 1)), random_state=rng).tocoo()
    keep = block_of[W.row] != block_of[W.col]
    keep &= rng.random(l)[W.row] >= isolated
    keep &= rng.random(l)[W.col] >= isolated
    W = sp.csc_matrix((W.data[keep], (W.row[keep], W.col[keep])), shape=(l, l))
    W = W + W.T
    D = sp.diags(np.asarray(W.sum(axis=1)).ravel())
    a, b = rng.uniform(0.0, 1.0, 2)
    Q = (a * (D + W) + b * (D - W)).tocsc()
    return BlockQP(rng.normal(size=l), Q, bp)


def block_kkt_residual(h: np.ndarray, d: np.ndarray, z: np.ndarray) -> float:
    """How far ``z`` is from the minimiser of ``sum h z + d z^2`` on the simplex: with ``lam``
    the smallest partial derivative ``h + 2 d z``, every candidate holding mass must have its
    derivative at ``lam`` (complementary slackness)."""
    grad = h + 2.0 * d * z
    lam = grad.min()
    return float(np.max(z * (grad - lam)))


@FAST
@given(
    seed=st.integers(0, 2**31 - 1),
    k=st.integers(1, 12),
    zeros=st.integers(0, 3),
)
def test_the_block_minimum_meets_its_kkt_conditions(seed, k, zeros):
    from tracker.bqp.frank_wolfe import _block_minimum

    rng = np.random.default_rng(seed)
    d = rng.uniform(0.0, 2.0, k)
    d[rng.permutation(k)[: min(zeros, k)]] = 0.0  # candidates that link to nothing
    x = rng.dirichlet(np.ones(k))
    g = rng.normal(size=k) + 2.0 * d * x  # the gradient of h = N(0, 1) at x
    z = np.empty(k)
    df = _block_minimum(g, x, d, 0, k, np.empty(k), np.empty(k, np.int64), z)
    h = g - 2.0 * d * x
    assert np.all(z >= 0) and z.sum() == pytest.approx(1.0, abs=1e-12)
    assert block_kkt_residual(h, d, z) <= 1e-9
    f = lambda v: float(h @ v + d @ (v * v))  # noqa: E731
    assert df == pytest.approx(f(z) - f(x), abs=1e-12)
    for v in rng.dirichlet(np.ones(k), 50):  # no point of the simplex does better
        assert f(v) >= f(z) - 1e-12


def test_the_block_minimum_by_hand():
    from tracker.bqp.frank_wolfe import _block_minimum

    def minimum(h, d):
        k = len(h)
        z = np.empty(k)
        x = np.full(k, 1.0 / k)
        g = np.asarray(h) + 2.0 * np.asarray(d) * x
        _block_minimum(g, x, np.asarray(d, float), 0, k, np.empty(k), np.empty(k, np.int64), z)
        return z

    # Q = I on one block: the projection of -h/2 onto the simplex (test_swap_step_exact_solution)
    np.testing.assert_allclose(minimum([0.0, -0.2, 1.0], [1.0, 1.0, 1.0]), [0.45, 0.55, 0.0])
    # a candidate that links to nothing takes what is left at its own cost, 0.1 here
    np.testing.assert_allclose(minimum([0.0, 0.1, 0.5], [1.0, 0.0, 1.0]), [0.05, 0.95, 0.0])
    # ... and nothing when the others fill the simplex below it (lam = 1.1 < 5)
    np.testing.assert_allclose(minimum([0.0, 5.0, 0.2], [1.0, 0.0, 1.0]), [0.55, 0.0, 0.45])
    # a linear block: its cheapest candidate (the first on ties)
    np.testing.assert_array_equal(minimum([0.3, -1.0, -1.0], [0.0, 0.0, 0.0]), [0, 1, 0])


@FAST
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(0, 14),
    kmax=st.integers(1, 8),
    eps=st.sampled_from([1e-2, 1e-4, 1e-8]),
)
def test_the_block_variant_solves_what_swap_solves(seed, n, kmax, eps):
    qp = laplacian_qp(seed, n, kmax)
    res = solve(qp, params=FWParams(variant="block", eps=eps, max_iter=20_000, record_history=True))
    check_result(qp, res, eps)
    assert res.converged
    assert res.steps["block"] == res.iterations and res.steps["swap"] == 0
    assert np.all(np.diff(res.history) <= 1e-12)  # every block step decreases f
    ref = solve(qp, params=FWParams(variant="swap", eps=1e-9, max_iter=200_000))
    assert ref.converged
    assert ref.objective - 1e-9 <= res.objective <= ref.objective + eps + 1e-9


def test_the_block_variant_matches_clarabel():
    for seed in range(6):
        qp = laplacian_qp(seed, 30, 6)
        res = solve(qp, params=FWParams(variant="block", eps=1e-8, max_iter=100_000))
        ref = solve_clarabel(qp)
        assert res.converged
        assert res.objective == pytest.approx(ref.objective, abs=1e-6)


def test_the_block_variant_with_eps_zero_stops_at_round_off():
    for seed in range(20):
        qp = laplacian_qp(seed, 30, 8)
        res = solve(qp, params=FWParams(variant="block", eps=0.0, max_iter=100_000))
        assert res.iterations < 100_000 and res.gap < 1e-9
        check_result(qp, res, 0.0)


def test_the_block_variant_takes_swap_steps_where_a_block_holds_more_than_its_diagonal():
    qp = random_qp(5, 12, 5)  # M M^T: entries between candidates of one block
    block = solve(qp, params=FWParams(variant="block", eps=1e-6))
    swap = solve(qp, params=FWParams(variant="swap", eps=1e-6))
    np.testing.assert_array_equal(block.x, swap.x)
    assert block.iterations == swap.iterations and block.steps == swap.steps


def test_the_block_variant_needs_far_fewer_steps_where_the_optimum_is_inside():
    """The tracker's frames: the relaxed optimum lies inside the simplices, which SWAP steps
    approach one pair of candidates at a time."""
    from tracker.testing import FrameSpec, synthetic_frame_qp

    for seed in range(3):
        qp = synthetic_frame_qp(FrameSpec(n_targets=60), np.random.default_rng(seed))
        assert qp.diagonal is None  # gathered: the check of the blocks runs on Q itself
        swap = solve(qp, params=FWParams(variant="swap", eps=1e-4, max_iter=200_000))
        block = solve(qp, params=FWParams(variant="block", eps=1e-4, max_iter=200_000))
        assert swap.converged and block.converged
        assert block.steps["block"] == block.iterations > 0
        assert 3 * block.iterations < swap.iterations
        assert abs(block.objective - swap.objective) <= 1e-4


def test_bench_track_times_the_block_variant_beside_swap(capsys):
    import json

    from crowdsim.bench import main as bench_main

    assert bench_main("track", ["--quick", "--threads", "1", "--fw-variant", "block"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rows = {(r["method"], r["targets"], tuple(r["frame"])): r for r in report["runs"]}
    assert {m for m, _, _ in rows} == {"bqp dense", "bqp speedup", "ncc", "bqp block"}
    # the packed crowd of 200 (--quick), where the quadratic terms couple the targets
    packed = next(f for m, n, f in rows if m == "bqp block" and n == 200 and f != (1280, 720))
    swap, block = rows["bqp speedup", 200, packed], rows["bqp block", 200, packed]
    assert 0 < block["solver_iterations_per_frame"] < swap["solver_iterations_per_frame"]
    assert abs(block["acc@15"] - swap["acc@15"]) <= 1.0
    with pytest.raises(SystemExit) as exit_:
        bench_main("track", ["--quick", "--fw-variant", "newton"])
    assert exit_.value.code == 2
    assert "--fw-variant: invalid choice: 'newton'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "x0, c, kind, x1",
    [
        # FW: lambda 5/6, f -25/24; SWAP: lambda capped at alpha_y = 0.5, f -1
        ([0.5, 0.5, 0.0], [0.0, 1.0, -1.0], "fw", [1 / 12, 1 / 12, 5 / 6]),
        # FW: lambda 0.94, f -1.486; SWAP: capped at alpha_y = 0.8 (a drop), f -1.6
        ([0.2, 0.8, 0.0], [0.0, 1.0, -1.0], "swap", [0.2, 0.0, 0.8]),
    ],
)
def test_swap_variant_takes_the_step_with_the_larger_decrease(x0, c, kind, x1):
    """Alg. 2 compares ``delta_fw`` and ``delta_swap`` (changes of ``f``, ``<= 0``) and takes
    the best improvement (it prints ``max``, which would take the other). One block of three,
    ``Q = I``, one step from ``x0``: ``g = c + 2 x0``, toward vertex 2, away vertex 1; both
    line searches by hand (``lambda = -g.d / 2 d'd``, clipped)."""
    qp = BlockQP(np.array(c), sp.identity(3, format="csc"), np.array([0, 3]))
    res = solve(qp, x0=np.array(x0), params=FWParams(variant="swap", eps=0.0, max_iter=1))
    assert res.iterations == 1 and res.steps[kind] == 1
    assert res.steps["drop"] == (1 if kind == "swap" else 0)
    np.testing.assert_allclose(res.x, x1, atol=1e-12)
