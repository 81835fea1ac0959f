"""BQP tracker specifics: the per-frame QP, groups, speed-up sampling, the motion term."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.baselines.ncc import NCCTracker
from tracker.bqp.params import BQPParams
from tracker.bqp.tracker import BQPTracker
from tracker.testing import make_scene


def _convoy(n_frames=24):
    # a coherent group of three walking right, one walker going left far below
    return make_scene(
        [[10, 20], [22, 20], [16, 30], [110, 80]],
        [[2, 0], [2, 0], [2, 0], [-2, 0]],
        n_frames=n_frames,
        shape=(96, 160),
    )


def test_frame_qps_are_block_simplex_problems():
    sc = _convoy(6)
    tr = BQPTracker(BQPParams(speedup=False), record_qps=True)
    res = tr.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    assert len(tr.recorded_qps) == 5
    k = (2 * tr.radius + 1) ** 2
    for qp in tr.recorded_qps:
        assert qp.n_blocks == 4 and (qp.block_sizes == k).all()
        assert abs(qp.Q - qp.Q.T).max() < 1e-12
        assert np.isfinite(qp.c).all()
    assert set(tr.timings) >= {"appearance", "terms", "solve", "total"}
    np.testing.assert_array_equal(res.positions, sc.points)


def test_groups_refresh_every_tau_frames():
    sc = _convoy(24)
    tr = BQPTracker(BQPParams(group_refresh=10))
    tr.init(sc.frames[0], sc.ids, sc.points[0], sc.template_size)
    for t in range(1, 10):
        tr.step(sc.frames[t])
        assert (tr.groups == -1).all() and len(tr.tree_edges) == 0
    tr.step(sc.frames[10])
    g = tr.groups
    assert g[0] == g[1] == g[2] >= 0 and g[3] == -1
    assert len(tr.tree_edges) == 2  # spanning tree of three targets
    d = np.linalg.norm(
        sc.points[10, tr.tree_edges[:, 0]] - sc.points[10, tr.tree_edges[:, 1]], axis=1
    )
    np.testing.assert_allclose(tr.tree_lengths, d)
    for t in range(11, 24):
        tr.step(sc.frames[t])
    np.testing.assert_array_equal(tr.points, sc.points[23])


def test_speedup_sampling_uses_33_candidates_per_target():
    sc = _convoy(8)
    tr = BQPTracker(BQPParams(speedup=True))
    res = tr.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    assert tr.n_candidates == 7 * 4 * 33
    np.testing.assert_array_equal(res.positions, sc.points)


@pytest.mark.parametrize("variant", ["plain", "away", "swap", "block"])
def test_every_fw_variant_tracks(variant):
    sc = _convoy(8)
    res = BQPTracker(BQPParams(fw_variant=variant)).track(sc.frames, sc.ids, sc.points[0], 8)
    np.testing.assert_array_equal(res.positions, sc.points)


def test_motion_term_carries_a_target_through_a_blank_gap():
    """Eq. 6: while the target is invisible the prediction keeps it on its path."""
    sc = make_scene([[20, 40]], [[3, 0]], n_frames=14, shape=(80, 120))
    bg = make_scene(np.zeros((0, 2)), np.zeros((0, 2)), n_frames=1, shape=(80, 120)).frames[0]
    frames = [f.copy() for f in sc.frames]
    for t in (6, 7):  # the person is hidden (e.g. under a sign) for two frames
        frames[t] = bg.copy()
    bqp = BQPTracker().track(frames, sc.ids, sc.points[0], 8)
    ncc = NCCTracker().track(frames, sc.ids, sc.points[0], 8)
    np.testing.assert_array_equal(bqp.positions[8:], sc.points[8:])
    assert np.abs(ncc.positions[8:] - sc.points[8:]).max() > 3


def test_params_are_used():
    tr = BQPTracker(BQPParams(search_factor=3.0))
    sc = _convoy(3)
    tr.track(sc.frames, sc.ids, sc.points[0], 8)
    assert tr.radius == 8
    with pytest.raises(ValueError):
        BQPParams(search_factor=1.0)


# --------------------------------------------------------------------------- each weight acts
def _tracked_convoy(**params):
    """A dense-candidate BQP tracker 12 frames into the convoy: moving, grouped (tree edges)."""
    import copy

    sc = _convoy(16)
    tr = BQPTracker(BQPParams(speedup=False, group_refresh=5, **params))
    tr.init(sc.frames[0], sc.ids, sc.points[0], sc.template_size)
    for frame in sc.frames[1:12]:
        tr.step(frame)
    assert len(tr.tree_edges) and np.abs(tr.velocities).max() > 0.5
    return tr, sc.frames[12], copy.deepcopy


@pytest.mark.parametrize(
    ("name", "value"), [("zeta", 0.9), ("eta", 0.7), ("w_sp", 1.1), ("w_g", 2.5)]
)
def test_each_term_weight_scales_exactly_its_own_term(name, value):
    """zeta, eta, w_sp and w_g each change the frame's QP by delta times their own term (Eq. 1)
    and nothing else: a weight that is ignored, or applied to another term, fails here."""
    from dataclasses import replace

    from tracker.bqp.quadratic import quadratic_matrix
    from tracker.bqp.terms import motion_cost, neighbourhood_cost, neighbours_in_groups

    tr, frame, copy = _tracked_convoy()
    base, alt = copy(tr), copy(tr)
    alt.set_params(replace(tr.params, **{name: value}))
    delta = value - getattr(tr.params, name)
    c0, _ = base.candidates(frame)
    c1, _ = alt.candidates(frame)
    np.testing.assert_array_equal(c0.positions, c1.positions)  # dense: the same candidates
    q0, q1 = base.quadratic(c0)[0], alt.quadratic(c1)[0]

    p, pos = tr.params, c0.positions
    n, k = pos.shape[:2]
    grid = pos.reshape(n, k, 1, 2)
    sigma = tr._px(p.motion_sigma)
    term_c = np.zeros((n, k))
    term_q = None
    if name == "zeta":
        term_c = motion_cost(grid, tr.points + tr.velocities, sigma).reshape(n, k)
    elif name == "eta":
        nbr, wts = neighbours_in_groups(
            tr.points, tr.groups, p.n_neighbours, tr._px(p.group_radius), tr._px(p.neighbour_scale)
        )
        term_c = neighbourhood_cost(grid, tr.points, tr.velocities, nbr, wts, sigma).reshape(n, k)
    else:
        ref = tr.tree_offsets if p.group_offsets else tr.tree_lengths
        sp_on, g_on = (1.0, 0.0) if name == "w_sp" else (0.0, 1.0)
        term_q = quadratic_matrix(
            pos,
            sp_on,
            tr._px(p.proximity_sigma),
            p.proximity_cutoff,
            g_on,
            tr.tree_edges,
            ref,
            tr._px(p.group_sigma),
            p.group_cutoff,
            p.laplacian_tau,
        )
    assert np.abs(term_c).max() > 1e-3 or abs(term_q).max() > 1e-3  # the term is there
    np.testing.assert_allclose(c1.cost - c0.cost, delta * term_c, rtol=1e-9, atol=1e-12)
    dq = (q1 - q0).toarray()
    want = np.zeros_like(dq) if term_q is None else delta * term_q.toarray()
    np.testing.assert_allclose(dq, want, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("appearance", ["kcf", "ncc"])
@pytest.mark.parametrize("quantile", [0.25, 0.75])
def test_update_threshold_gates_the_appearance_update(appearance, quantile):
    """At non-default thresholds, exactly the targets whose confidence reaches the threshold
    refresh their appearance model in a frame (KCF filters and NCC templates alike)."""
    from dataclasses import replace

    tr, frame, copy = _tracked_convoy(appearance=appearance, ncc_update_every=1)
    # sensor noise spreads the confidences (on the clean frame KCF's peaks all exceed 1)
    noise = np.random.default_rng(0).normal(0, 60, frame.shape)
    frame = np.clip(frame + noise, 0, 255).astype(np.uint8)
    probe = copy(tr)
    probe.step(frame)
    conf = probe.confidence
    threshold = float(np.quantile(conf, quantile))
    assert 0 < (conf >= threshold).sum() < len(conf)  # both kinds of target present

    def model(t):
        app = t.appearance
        return app.xf.copy() if appearance == "kcf" else app.templates.copy()

    run = copy(tr)
    run.set_params(replace(tr.params, update_threshold=threshold))
    before = model(run)
    run.step(frame)
    np.testing.assert_array_equal(run.confidence, conf)  # the threshold acts after scoring
    changed = (model(run) != before).reshape(len(conf), -1).any(axis=1)
    np.testing.assert_array_equal(changed, conf >= threshold)


@pytest.mark.parametrize("variant", ["swap", "block"])
def test_tracks_are_the_same_for_any_number_of_threads(monkeypatch, variant):
    """Parallel terms, FFTs, component solves and numpy passes in chunks (made small here,
    so that this crowd is cut too): 1 and 2 threads give identical tracks, on a spread-out
    crowd whose frames split into independent components."""
    import tracker.appearance as appearance
    import tracker.bqp.frank_wolfe as fw
    import tracker.bqp.quadratic as quadratic
    import tracker.candidates as candidates
    from synth_data.sequence import synthetic_crowd
    from tracker.runner import run_tracker
    from tracker.threads import max_threads

    if max_threads() < 2:
        pytest.skip("needs 2 cores")
    monkeypatch.setattr(appearance, "ROWS_PER_THREAD", 8)
    monkeypatch.setattr(quadratic, "EXP_PER_THREAD", 100)
    monkeypatch.setattr(candidates, "DRAWS_PER_THREAD", 100)
    split = []
    solve_split = fw._solve_split
    monkeypatch.setattr(fw, "_solve_split", lambda *a: split.append(solve_split(*a)) or split[-1])
    crowd = synthetic_crowd(120, 8, 3, 12, size=(480, 270))
    tracks = []
    for threads in (1, 2):
        tr = BQPTracker(BQPParams(fw_variant=variant))
        tr.threads = threads
        tr.parallel_min_targets = 0  # a small crowd, on every thread all the same
        tracks.append(run_tracker(tr, crowd, metrics="none").result.positions)
    assert any(s is not None for s in split)  # some frames were solved component-wise
    np.testing.assert_array_equal(tracks[0], tracks[1])


def test_the_trackers_pair_gaussians_come_from_tables(monkeypatch):
    """The tracker's candidates lie on whole pixels, so every frame's quadratic terms take
    their Gaussians from tables (no exp per entry): a change that moved candidates off the
    pixel grid would quietly lose that."""
    import tracker.bqp.quadratic as quadratic
    from synth_data.sequence import synthetic_crowd
    from tracker.runner import run_tracker

    served = []
    real = quadratic._gauss_tables_for
    monkeypatch.setattr(
        quadratic, "_gauss_tables_for", lambda *a: served.append(real(*a) is not None) or real(*a)
    )
    crowd = synthetic_crowd(150, 12, 1, 12, size=(320, 180), contrast=0.3, noise_sigma=8.0)
    run_tracker(BQPTracker(), crowd, metrics="none")
    assert len(served) == 11 and all(served)


@pytest.mark.parametrize("bad", [0, -1, 1.5, 10**6, "2"])
def test_threads_out_of_range_are_refused(bad):
    tr = BQPTracker()
    with pytest.raises(ValueError, match="threads must be"):
        tr.threads = bad


# --------------------------------------------------------------------------- the paper's forms
def test_the_papers_identity_makes_the_grouping_term_pay_0_2_2():
    """Two targets on one grouping edge, each with a candidate in formation and one far off:
    on binary points today's diagonal (identity only where D > 0) pays 0 for keeping the
    formation, 1 for breaking it on one side and 0 on both (tau 0); the paper's identity on
    every candidate pays 0, 2, 2 (up to the constant it adds, 2). ``laplacian_identity =
    "every"`` is the linear cost less ``Q``'s diagonal, so its binary objective is the
    paper's."""
    from tracker.bqp.quadratic import quadratic_matrix

    cand = np.array([[[0.0, 0.0], [0.0, 60.0]], [[10.0, 0.0], [90.0, 70.0]]])  # a0 a1 / b0 b1
    q, diag = quadratic_matrix(
        cand,
        0.0,
        4.0,
        1.5,
        1.0,
        np.array([[0, 1]]),
        np.array([10.0]),
        2.0,
        1.5,
        0.0,
        diagonal=True,
    )
    np.testing.assert_allclose(diag, [1.0, 0.0, 1.0, 0.0])  # a1, b1 have no neighbour
    q = q.toarray()

    def pay(a, b, every):
        x = np.zeros(4)
        x[[a, 2 + b]] = 1.0
        return x @ q @ x - (diag @ x if every else 0.0) + (2.0 if every else 0.0)

    keep, one, both = (0, 0), (0, 1), (1, 1)
    assert [pay(*c, every=False) for c in (keep, one, both)] == pytest.approx([0, 1, 0])
    assert [pay(*c, every=True) for c in (keep, one, both)] == pytest.approx([0, 2, 2])


def test_the_papers_forms_are_options_that_track_and_change_the_qp():
    sc = _convoy(16)
    runs = {}
    for identity, neighbours in (("linked", "nearest"), ("every", "group")):
        tr = BQPTracker(
            BQPParams(
                speedup=False,
                group_refresh=5,
                laplacian_identity=identity,
                neighbour_set=neighbours,
            ),
            record_qps=True,
        )
        res = tr.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
        np.testing.assert_array_equal(res.positions, sc.points)  # a clean convoy either way
        runs[identity] = tr.recorded_qps
    before, after = runs["linked"][-1], runs["every"][-1]
    assert (before.Q != after.Q).nnz == 0  # the same quadratic terms
    diag = before.Q.diagonal()
    assert diag.max() > 0
    np.testing.assert_allclose(after.c, before.c - diag, atol=1e-12)
    with pytest.raises(ValueError, match="laplacian_identity must be one of"):
        BQPParams(laplacian_identity="paper")
    with pytest.raises(ValueError, match="neighbour_set must be one of"):
        BQPParams(neighbour_set="all")


@pytest.mark.parametrize("a", [0.0, 0.75])
def test_velocity_is_smoothed_with_the_given_weight_on_the_old_velocity(a):
    """``p_dot <- a p_dot + (1 - a) (p_new - p)`` (velocity_smoothing ``a``; 0 = the last
    displacement alone), from ``p_dot = 0`` at init, on the convoy the tracker follows
    exactly (2 px/frame right, 2 left). The default ``a = 0.5`` cannot tell ``a`` from
    ``1 - a``."""
    sc = _convoy(4)
    tr = BQPTracker(BQPParams(speedup=False, velocity_smoothing=a))
    tr.init(sc.frames[0], sc.ids, sc.points[0], sc.template_size)
    v = np.zeros((4, 2))
    for t in (1, 2, 3):
        tr.step(sc.frames[t])
        np.testing.assert_array_equal(tr.points, sc.points[t])
        v = a * v + (1 - a) * (sc.points[t] - sc.points[t - 1])
        np.testing.assert_allclose(tr.velocities, v, rtol=1e-12, atol=1e-12)
