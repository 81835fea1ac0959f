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


@pytest.mark.parametrize("variant", ["plain", "away", "swap"])
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
