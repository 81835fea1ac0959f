"""PNMC tracker (paper 2): queens, NMC prior, instantaneous flow, hierarchical update.

Tiny hand-built scenes with exact ground truth; planted queens; a low-evidence (occluded)
target inside a coherently moving group; every parameter applied mid-sequence.
"""

from __future__ import annotations

import copy
from dataclasses import fields, replace

import numpy as np
import pytest

from tracker.pnmc import PNMCParams, PNMCTracker
from tracker.pnmc.flow import InstantaneousFlow, batched_ncc, ncc_argmax
from tracker.pnmc.queens import QUEEN_ORDERS, back_assign, cluster_order_key, fit_gmm, select_queens
from tracker.registry import make_tracker
from tracker.testing import PALETTE, make_scene

SIZE = 8


def draw(
    paths: np.ndarray,
    colours: np.ndarray,
    shape=(112, 144),
    seed: int = 0,
    occlude: dict[int, int] | None = None,
    occluder: int = 21,
    textured: bool = False,
) -> list[np.ndarray]:
    """Frames of ``make_scene``-style blobs at ``paths`` ``(T, n, 2)`` int px.

    ``occlude[i] = t0``: from frame ``t0`` target ``i`` is covered by a square of side
    ``occluder`` centred on it, flat grey (no appearance evidence at all) or ``textured``
    (a fixed random texture that moves with the target: evidence for the flow only).
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    bg = rng.integers(70, 130, (h, w, 3)).astype(np.uint8)
    cover = (
        rng.integers(0, 255, (occluder, occluder, 3)).astype(np.uint8)
        if textured
        else np.full((occluder, occluder, 3), 100, np.uint8)
    )
    half = (SIZE - 2) // 2
    frames = []
    for t in range(paths.shape[0]):
        f = bg.copy()
        for i, (x, y) in enumerate(paths[t]):
            if occlude and i in occlude and t >= occlude[i]:
                o = occluder // 2
                f[y - o : y + o + 1, x - o : x + o + 1] = cover
                continue
            f[y - half : y + half + 1, x - half : x + half + 1] = colours[i]
            f[y - 1 : y + 1, x - 1 : x + 1] = colours[i] // 4
        frames.append(f)
    return frames


def turning_group(n_frames: int = 14, turn: int = 6) -> np.ndarray:
    """``(T, 7, 2)`` int: a centre and a hexagonal ring (radius 18 px) moving right at 2
    px/frame, then (from frame ``turn``) down at 2 px/frame."""
    ring = 18 * np.stack([np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)], 1)
    start = np.rint(np.concatenate([[[0.0, 0.0]], ring]) + [50, 40]).astype(np.int64)
    step = np.array([[2, 0] if t < turn else [0, 2] for t in range(n_frames - 1)])
    offset = np.concatenate([[[0, 0]], np.cumsum(step, 0)])
    return start[None] + offset[:, None]


GROUP_COLOURS = np.array([[60, 60, 70]] * 7, np.uint8)
GROUP_COLOURS[2] = PALETTE[0]  # one prominent person on the ring: the queen


def track(tracker, frames, points0, births=None):
    ids = np.arange(1, len(points0) + 1)
    return tracker.track(frames, ids, points0, SIZE, births=births)


# ---------------------------------------------------------------------------- exact scenes
def test_exact_recovery_on_tiny_scenes():
    sc = make_scene(
        [[20, 20], [90, 20], [100, 75], [25, 75]], [[2, 1], [-2, 1], [-2, 0], [1, -1]], n_frames=12
    )
    res = PNMCTracker().track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    np.testing.assert_array_equal(res.positions, sc.points)
    # a packed group (neighbours 12 px apart, inside each other's neighbourhoods)
    starts = [[30 + 12 * (i % 3), 30 + 12 * (i // 3)] for i in range(6)]
    sc = make_scene(starts, [[2, 1]] * 6, n_frames=10)
    t = PNMCTracker()
    res = t.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    np.testing.assert_array_equal(res.positions, sc.points)
    assert len(t.update_order) == 6 and sorted(t.update_order) == list(range(6))
    assert t.confidence.min() > 0.95  # (gamma + 1) / 2; the background in a template moves


def test_registry_and_determinism():
    sc = make_scene(
        [[20, 20], [40, 22], [60, 24], [30, 60]], [[1, 1], [1, 1], [1, 1], [-1, 0]], n_frames=8
    )
    runs = [
        make_tracker("pnmc", queen_mode="random", seed=3).track(
            sc.frames, sc.ids, sc.points[0], SIZE
        )
        for _ in range(2)
    ]
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    assert isinstance(make_tracker("pnmc"), PNMCTracker)


# ---------------------------------------------------------------------------- queens
def test_planted_queens_are_found():
    # 16 look-alikes (one clothing colour) and two distinctly coloured people
    starts = [[14 + 16 * (i % 6), 14 + 20 * (i // 6)] for i in range(18)]
    colours = np.tile(np.array([[60, 60, 70]], np.uint8), (18, 1))
    colours[4] = (30, 30, 240)
    colours[13] = (40, 230, 40)
    sc = make_scene(starts, np.zeros((18, 2)), n_frames=2, colours=colours)
    for seed in (0, 1, 2):
        t = PNMCTracker(PNMCParams(seed=seed))
        t.init(sc.frames[0], sc.ids, sc.points[0], SIZE)
        assert np.flatnonzero(t.queens).tolist() == [4, 13]
    # random queens: as many (ceil of 10 %), not the prominent ones for this seed
    t = PNMCTracker(PNMCParams(queen_mode="random", seed=0))
    t.init(sc.frames[0], sc.ids, sc.points[0], SIZE)
    assert t.queens.sum() == 2


def test_select_queens_on_templates():
    rng = np.random.default_rng(0)
    base = np.array([80, 70, 60])
    templates = np.clip(base + rng.normal(0, 4, (20, 8, 8, 3)), 0, 255).astype(np.uint8)
    # the two prominent people wear colours of their own (with the same camera noise)
    for i, colour in ((7, (230, 40, 40)), (17, (40, 220, 230))):
        templates[i, 1:7, 1:7] = np.clip(colour + rng.normal(0, 4, (6, 6, 3)), 0, 255)
    q = select_queens(templates, np.random.default_rng(1), n_clusters=100)
    assert np.flatnonzero(q).tolist() == [7, 17]  # ceil(10 % of 20) = 2
    assert select_queens(templates[:0], rng).shape == (0,)
    assert select_queens(templates[:1], rng).tolist() == [True]


def test_fit_gmm_recovers_separated_clusters():
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [rng.normal([20, 20, 20], 3, (400, 3)), rng.normal([200, 100, 50], 3, (100, 3))]
    )
    gm = fit_gmm(x, 2, np.random.default_rng(0), iterations=50, reg=1e-3)
    order = np.argsort(gm.means[:, 0])
    np.testing.assert_allclose(gm.means[order], [[20, 20, 20], [200, 100, 50]], atol=1.0)
    np.testing.assert_allclose(gm.weights[order], [0.8, 0.2], atol=0.01)
    np.testing.assert_allclose(
        np.sqrt(np.diagonal(gm.covariances[order], axis1=1, axis2=2)), 3.0, rtol=0.3
    )
    labels = gm.predict(x)
    assert (labels[:400] == order[0]).all() and (labels[400:] == order[1]).all()


def test_mixture_posteriors_likelihood_and_volumes_by_hand():
    """Components 10 apart with weights 0.8 / 0.2, covariances ``I`` and ``diag(4, 9, 1)``:
    at the midpoint the posteriors are ``w_k N(x; mu_k, Sigma_k)`` normalised and the
    log-likelihood is the log of their sum, the densities written out by hand; the volume of
    Sec. 3.1 is ``(2 pi)^{3/2} |Sigma|^{1/2}`` (``|Sigma|^{1/2} = 6`` for the second). With
    equal covariances the midpoint's posteriors are the weights."""
    from tracker.pnmc.queens import GaussianMixture

    gm = GaussianMixture(
        np.array([0.8, 0.2]),
        np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]),
        np.stack([np.eye(3), np.diag([4.0, 9.0, 1.0])]),
    )
    lr, ll = gm.log_responsibilities(np.array([[5.0, 0.0, 0.0]]))
    # component 2's density there: exp(-25 / 8) / ((2 pi)^{3/2} 6)
    p1 = np.exp(-12.5) / (2 * np.pi) ** 1.5
    p2 = np.exp(-25 / 8) / ((2 * np.pi) ** 1.5 * 6.0)
    want = np.array([0.8 * p1, 0.2 * p2])
    np.testing.assert_allclose(np.exp(lr[0]), want / want.sum(), rtol=1e-9)
    assert ll[0] == pytest.approx(np.log(want.sum()), rel=1e-12)
    np.testing.assert_allclose(gm.volumes, (2 * np.pi) ** 1.5 * np.array([1.0, 6.0]), rtol=1e-12)
    same = GaussianMixture(gm.weights, gm.means, np.stack([np.eye(3)] * 2))
    lr_same, _ = same.log_responsibilities(np.array([[5.0, 0.0, 0.0]]))
    np.testing.assert_allclose(np.exp(lr_same), [[0.8, 0.2]], rtol=1e-12)


def test_back_assignment_stops_at_the_first_fill():
    # cluster 2 (rank 0) fills templates 0 and 1 at once: both are queens (> 10 %)
    owner = np.repeat(np.arange(4), 3)
    labels = np.array([2, 2, 2, 2, 2, 0, 0, 0, 1, 1, 1, 1])
    q = back_assign(labels, owner, np.array([1, 2, 0]), 4, 3, 0.1, 2 / 3)
    assert q.tolist() == [True, True, False, False]


# ---------------------------------------------------------------------------- NMC prior
def test_nmc_prior_moves_occluded_target_with_its_neighbours():
    paths = turning_group()
    frames = draw(paths, GROUP_COLOURS, occlude={0: 6})
    errs = {}
    for use in (True, False):
        t = PNMCTracker(PNMCParams(use_flow=False, use_neighbours=use, max_lost=0))
        res = track(t, frames, paths[0].astype(float))
        errs[use] = np.abs(res.positions[-1] - paths[-1]).max(1)
        np.testing.assert_array_equal(res.positions[:6], paths[:6])  # before the occlusion
        assert errs[use][1:].max() <= 1  # the visible ring turns with its evidence
    # the occluded centre follows its neighbours' turn with NMC, runs straight on without
    assert errs[True][0] <= 3 < 8 <= errs[False][0]


def test_delayed_update_puts_low_confidence_last():
    paths = turning_group()
    frames = draw(paths, GROUP_COLOURS, occlude={0: 6})
    t = PNMCTracker(PNMCParams(use_flow=False, max_lost=0))
    track(t, frames[:9], paths[0].astype(float))
    q = np.flatnonzero(t.queens)
    assert 0 not in q and len(q) >= 1
    np.testing.assert_array_equal(np.sort(t.update_order[: len(q)]), q)  # queens first
    # the occluded centre went to the back of the queue: updated after most of its ring
    assert t.delayed[0] >= 1 and list(t.update_order).index(0) >= 4
    assert t.confidence[0] < 0.9 <= t.confidence[1:].min()


def test_flow_prior_moves_a_target_against_the_crowd():
    # alone (no neighbours) and covered from frame 1 by a texture moving with it: its
    # template matches nothing, only the instantaneous flow knows where it goes
    n = 12
    path = (np.array([40, 30]) + np.arange(n)[:, None] * np.array([1, 3]))[:, None, :]
    frames = draw(path, GROUP_COLOURS[:1], occlude={0: 1}, textured=True)
    err = {}
    for use in (True, False):
        t = PNMCTracker(PNMCParams(use_flow=use, flow_frames=2, max_lost=0))
        res = track(t, frames, path[0].astype(float))
        err[use] = np.abs(res.positions[-1, 0] - path[-1, 0]).max()
    assert err[True] <= 4 < 10 <= err[False]


def test_flow_prior_is_tried_when_confidence_is_low():
    paths = turning_group()
    frames = draw(paths, GROUP_COLOURS, occlude={0: 6})
    t = PNMCTracker(PNMCParams(tau=0.999))
    track(t, frames[:8], paths[0].astype(float))
    assert t.flow.pairs and t.flow._done.any()  # the flow was computed this frame
    t = PNMCTracker(PNMCParams(use_flow=False, tau=0.999))
    track(t, frames[:8], paths[0].astype(float))
    assert not t.flow._done.any() and not t.used_flow.any()


# ---------------------------------------------------------------------------- flow
def _fast_square(n_frames: int = 13, v: int = -4, s: int = 12) -> tuple[list, np.ndarray]:
    """A ``s`` px random-texture square moving ``v`` px/frame in x over a static random
    texture (96 x 160), with +-2 grey levels of noise per frame so that no NCC peak is 1."""
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 256, (96, 160, 3)).astype(np.uint8)
    tex = rng.integers(0, 256, (s, s, 3)).astype(np.uint8)
    frames, path = [], []
    for t in range(n_frames):
        f = bg.copy()
        x = 120 + v * t
        f[48 - s // 2 : 48 + s // 2, x - s // 2 : x + s // 2] = tex
        noise = rng.integers(-2, 3, f.shape)
        frames.append(np.clip(f.astype(int) + noise, 0, 255).astype(np.uint8))
        path.append((x, 48))
    return frames, np.array(path, np.float64)


def test_flow_select_last_follows_a_fast_target(monkeypatch):
    """The flow prior of a target moving -4 px/frame (``tau`` ~ 1: it is taken every frame)
    from the patches near ``x_i^{t-1}`` by their start four frames back (``flow_select=
    "start"``, the default) or by their position in ``x_i^{t-1}``'s frame (``"last"``, the
    paper's Sec. 3.3 / Eq. 3): the patch-weighted mean x velocity over the frames with a
    full five-frame buffer. By start, no patch on the target is picked (they began 12 px
    back) and the prior is pulled towards the static background; by last, the target's own
    patches (exactly -4) are among them. Pins PNMCParams.flow_select's documented numbers."""
    import tracker.pnmc.tracker as pnmc

    frames, path = _fast_square()
    real = pnmc._flow_map_cells
    seen = []

    def spy(targets, ptr, e, fvel, camera_v, *args):
        if len(targets):
            q = slice(ptr[0], ptr[1])
            seen.append(((e[q] / e[q].sum()) @ fvel[q, 0], fvel[q, 0].copy()))
        return real(targets, ptr, e, fvel, camera_v, *args)

    monkeypatch.setattr(pnmc, "_flow_map_cells", spy)
    mean, own = {}, {}
    for sel in ("start", "last"):
        t = PNMCTracker(PNMCParams(tau=0.99999, max_lost=0, flow_select=sel))
        t.init(frames[0], np.array([1]), path[:1], 12)
        got = []
        for k, f in enumerate(frames[1:], 1):
            seen.clear()
            t.step(f)
            np.testing.assert_array_equal(t.points[0], path[k])
            assert len(seen) == 1
            if len(t.flow.pairs) == 4:
                got.append(seen[0])
        assert len(got) == len(frames) - 4
        mean[sel] = float(np.mean([g[0] for g in got]))
        own[sel] = min(int(np.sum(g[1] == -4.0)) for g in got)
    assert own["start"] == 0 and own["last"] >= 4  # the 2 x 2 patches inside the target
    assert mean["start"] == pytest.approx(-1.20, abs=0.02)
    assert mean["last"] == pytest.approx(-2.68, abs=0.02)


def test_flow_select_last_takes_every_patch_within_the_radius_at_t_minus_1():
    """``near_many(by="last")``: exactly the valid tracks (over the whole grid) whose
    position in the frame before the newest lies within the radius, in start-cell order."""
    frames, _ = _fast_square(6)
    flow = InstantaneousFlow(patch=4, spacing=4, frames=5, search=6, min_ncc=0.5)
    for f in frames:
        flow.push(f)
    centres = np.array([[104.0, 48.0], [60.0, 30.0], [2.0, 2.0]])
    ptr, pos, vel = flow.near_many(centres, 9.0, "last")
    gh, gw = flow._shape
    flow.near_many(np.array([[80.0, 48.0]]), 1000.0)  # every track
    assert flow._done.all()
    for t, c in enumerate(centres):
        ok = flow._valid & (((flow._last - c) ** 2).sum(-1) <= 81.0)
        np.testing.assert_array_equal(pos[ptr[t] : ptr[t + 1]], flow._last[ok])
        np.testing.assert_array_equal(vel[ptr[t] : ptr[t + 1]], flow._vel[ok])
    assert (vel[ptr[0] : ptr[1], 0] == -4.0).sum() >= 4
    with pytest.raises(ValueError, match="by must be one of"):
        flow.near_many(centres, 9.0, "first")


def _one_visit(wts: np.ndarray, weight_scale: float) -> np.ndarray:
    """Target 0's new position after one visit of Algorithm 2 (:func:`_propagate`) on a flat
    likelihood, its neighbours 1 and 2 already updated: 1 was 10 px away and moved 3 px
    away from it, 2 was 10.5 px away and moved 3 px towards it."""
    from tracker.pnmc.tracker import _propagate

    prev = np.array([[50.0, 50.0], [60.0, 50.0], [50.0, 39.5]])
    new = prev.copy()
    new[1] += [3.0, 0.0]
    new[2] += [0.0, 3.0]
    k = 21
    d = np.arange(k, dtype=np.float64) - k // 2
    lik = np.ones((3, k, k))
    gx = prev[:, :1] + d[None]
    gy = prev[:, 1:] + d[None]
    updated = np.array([False, True, True])
    queued = np.array([True, False, False])
    queue = np.zeros(3, np.int64)
    cursor = np.array([0, 1, 0, 2], np.int64)
    _propagate(
        lik, gx, gy, prev.copy(), prev, np.full(3, 1e-9), np.array([0, 2, 2, 2]),
        np.array([1, 2]), wts, weight_scale, np.zeros(3, np.bool_), np.arange(3), 2.0,
        False, np.zeros(3, np.bool_), np.full(3, -1), np.full(3, -1.0), new, np.zeros(3),
        np.full(3, 0.5), updated, queued, np.zeros(3, np.int64), np.zeros(3, np.bool_),
        np.zeros(3, np.int64), queue, cursor,
    )  # fmt: skip
    assert updated.all()
    return new[0]


def test_neighbour_weights_updated_measures_the_neighbours_at_t():
    """Eq. 3 at ``t - 1`` (the default) weighs neighbour 1 (10 px then) over 2 (10.5 px): the
    target takes 1's motion. The paper's form measures the updated neighbours at ``t``: 2,
    now 7.5 px from the target's last position against 1's 13, takes the weight."""
    e = np.exp(-np.array([0.0, 0.5]))  # PNMCTracker._graph's weights, weight_scale 1
    assert np.array_equal(_one_visit(e / e.sum(), 0.0), [53.0, 50.0])
    assert np.array_equal(_one_visit(e / e.sum(), 1.0), [50.0, 53.0])
    # the weights of the paper's form do not come from the graph's
    assert np.array_equal(_one_visit(np.array([1.0, 0.0]), 1.0), [50.0, 53.0])


def _visit_between(obs0: float, queen0: bool = False, tau0: float = 0.5) -> tuple[list, int]:
    """Target 0 (at (50, 50), own velocity +3 px in x, previous confidence ``obs0``) visited
    by :func:`_propagate` on a flat likelihood between neighbour 1 (10 px right, updated,
    moved +3 px in y) and neighbour 2 (10 px left, not updated): Eq. 3 at ``t - 1`` gives
    each 0.5. Returns target 0's new position and its number of visits."""
    from tracker.pnmc.tracker import _propagate

    prev = np.array([[50.0, 50.0], [60.0, 50.0], [40.0, 50.0]])
    pred = prev.copy()
    pred[0] += [3.0, 0.0]
    new = prev.copy()
    new[1] += [0.0, 3.0]
    k = 21
    d = np.arange(k, dtype=np.float64) - k // 2
    lik = np.ones((3, k, k))
    gx = prev[:, :1] + d[None]
    gy = prev[:, 1:] + d[None]
    updated = np.array([False, True, False])
    visits = np.zeros(3, np.int64)
    _propagate(
        lik, gx, gy, pred, prev, np.array([obs0, 1.0, 1.0]), np.array([0, 2, 3, 4]),
        np.array([1, 2, 0, 0]), np.array([0.5, 0.5, 1.0, 1.0]), 0.0,
        np.array([queen0, False, False]), np.arange(3), 2.0, False, np.zeros(3, np.bool_),
        np.full(3, -1), np.full(3, -1.0), new, np.zeros(3), np.array([tau0, 0.5, 0.5]),
        updated, np.array([True, True, False]), visits, np.zeros(3, np.bool_),
        np.zeros(3, np.int64), np.zeros(3, np.int64), np.array([0, 1, 0, 1], np.int64),
    )  # fmt: skip
    assert updated.all()
    return new[0].tolist(), int(visits[0])


def test_nmc_prior_weighs_self_by_last_confidence_and_neighbours_by_eq3():
    """Eq. 5's ``p_S + p_N``: ``p_S`` (at ``A x_i^{t-1}``) carries the previous update
    confidence (Eq. 1), ``p_N``'s Gaussian at ``x_i^{t-1} + v_j^t`` (Eq. 2) the updated
    neighbour's Eq. 3 weight normalised over all neighbours (0.5 here, not 1): the heavier
    mode wins."""
    assert _visit_between(0.6) == ([53.0, 50.0], 1)
    assert _visit_between(0.4) == ([50.0, 53.0], 1)


def test_queen_ignores_its_neighbours_on_its_first_visit_only():
    """A queen is predicted by ``p_S`` alone (Sec. 3.4); once it failed ``tau`` and came
    back, it is treated as a non-queen with the NMC prior (Appendix A)."""
    assert _visit_between(0.4, queen0=True) == ([53.0, 50.0], 1)
    assert _visit_between(0.4, queen0=True, tau0=1.5) == ([50.0, 53.0], 2)


def test_flow_track_starts_flow_frames_minus_2_before_the_frame_before_the_newest():
    """With ``flow_frames = 5`` a patch track starts in the oldest buffered frame, four
    frames before the newest and three before the frame of ``x_i^{t-1}``, where ``near``
    gives its position: a texture moving +1 px a frame puts the patch that started at
    (30, 30) at (33, 30)."""
    base = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    flow = InstantaneousFlow(patch=4, spacing=4, frames=5, search=2, min_ncc=0.5)
    for t in range(7):
        flow.push(np.ascontiguousarray(np.roll(base, t, axis=1)))
    pos, vel = flow.near(np.array([30.0, 30.0]), 0.1, "start")
    np.testing.assert_array_equal(pos, [[33.0, 30.0]])
    np.testing.assert_array_equal(vel, [[1.0, 0.0]])


def test_likelihood_takes_each_channels_mean_off_where_eq7_takes_one():
    """PNMC's ``gamma`` (``cv2.TM_CCOEFF_NORMED``, module docstring) is blind to a constant
    added to one colour channel; Eq. 7's one mean over x, y and colour (the flow's
    :func:`batched_ncc`) is not."""
    from tracker.appearance import NCCAppearance

    rng = np.random.default_rng(0)
    frame = rng.integers(60, 120, (20, 20, 3)).astype(np.uint8)
    model = NCCAppearance(6, 1, 0.8)
    model.add(frame, np.array([[10, 10]]))
    shifted = frame.copy()
    shifted[..., 2] += 100
    assert model.scores(shifted, np.array([[10, 10]]))[0, 1, 1] == pytest.approx(1.0, abs=1e-5)
    tpl = model.templates[0].transpose(2, 0, 1)[None].astype(np.float32)
    win = shifted[7:13, 7:13].transpose(2, 0, 1)[None].astype(np.float32)
    eq7 = batched_ncc(tpl, win)[0, 0, 0]
    assert eq7 < 0.5
    # ncc_mean="joint" (NCCAppearance(mean="joint")) takes Eq. 7's one mean: the flow's value
    joint = NCCAppearance(6, 1, 0.8, mean="joint")
    joint.add(frame, np.array([[10, 10]]))
    assert joint.scores(shifted, np.array([[10, 10]]))[0, 1, 1] == pytest.approx(eq7, abs=1e-5)
    assert joint.scores(frame, np.array([[10, 10]]))[0, 1, 1] == pytest.approx(1.0, abs=1e-5)
    flat = np.full_like(frame, 90)  # a flat window has no information: 0, as OpenCV's NaN
    assert joint.scores(flat, np.array([[10, 10]]))[0, 1, 1] == 0.0


def test_ncc_mean_joint_scores_stay_within_minus_one_and_one():
    """A near-flat template (values 100-102) matched where it was cut: the float32
    correlation's rounding had put the joint mean's score at 1.0006 (a likelihood past 1);
    the per-channel path clips to [-1, 1], and so does the joint one."""
    from tracker.appearance import NCCAppearance

    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (80, 80, 3), dtype=np.uint8)
    frame[20:60, 20:60] = rng.integers(100, 103, (40, 40, 3), dtype=np.uint8)
    centers = rng.integers(30, 50, (30, 2))
    for mean in ("channel", "joint"):
        model = NCCAppearance(12, 4, mean=mean)
        model.add(frame, centers)
        got = model.scores(frame, centers)
        assert got.max() <= 1.0 and got.min() >= -1.0, (mean, got.max(), got.min())
        assert got[:, 4, 4].min() > 0.99  # each template's own window: a match


def test_ncc_mean_joint_is_a_pnmc_option_that_tracks():
    """``--set ncc_mean=joint`` goes through the parameters, reaches the model mid-run, and
    follows the walkers of the plant-and-recover scene as the default does."""
    from tracker.pnmc.params import PNMCParams

    with pytest.raises(ValueError, match="ncc_mean must be one of"):
        PNMCParams(ncc_mean="grey")
    sc = make_scene(
        [[20, 20], [90, 20], [100, 75], [25, 75]], [[2, 1], [-2, 1], [-2, 0], [1, -1]], n_frames=12
    )
    t = PNMCTracker(PNMCParams(ncc_mean="joint"))
    res = t.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    # the flat blobs' joint-mean peak is flatter: the still prior of the first frames holds
    # one target a pixel back on frames 1 and 2
    assert np.abs(res.positions - sc.points).max() <= 1
    np.testing.assert_array_equal(res.positions[3:], sc.points[3:])
    assert t.model.mean == "joint"
    t.set_params(PNMCParams())
    assert t.model.mean == "channel"


def test_flow_recovers_a_translation():
    rng = np.random.default_rng(0)
    tex = rng.integers(0, 255, (80, 100, 3)).astype(np.uint8)
    flow = InstantaneousFlow(patch=4, spacing=4, frames=5, search=3, min_ncc=0.5)
    for k in range(6):
        flow.push(np.ascontiguousarray(np.roll(tex, (k, 2 * k), axis=(0, 1))))
    pos, vel = flow.near(np.array([50.0, 40.0]), 8.0)
    assert len(vel) >= 10
    np.testing.assert_array_equal(vel, np.tile([2.0, 1.0], (len(vel), 1)))
    # flat frames: no valid patch
    flat = InstantaneousFlow()
    for _ in range(3):
        flat.push(np.full((40, 40, 3), 90, np.uint8))
    assert len(flat.near(np.array([20.0, 20.0]), 8.0)[0]) == 0


def test_near_many_gives_each_centres_patches_as_a_lone_call_would():
    """:meth:`InstantaneousFlow.near_many`: per centre, the valid patches whose start lies
    within the radius, in row-major order (checked against every cell of the grid), with the
    same tracks as when each centre is asked for alone on a fresh flow; centres off the
    frame and with no patch near get empty segments."""
    rng = np.random.default_rng(1)
    tex = rng.integers(0, 255, (80, 100, 3)).astype(np.uint8)
    tex[30:50, 60:90] = 90  # a flat region: its patches are not valid

    def fresh():
        flow = InstantaneousFlow(patch=4, spacing=4, frames=5, search=3, min_ncc=0.5)
        for k in range(6):
            flow.push(np.ascontiguousarray(np.roll(tex, (k, 2 * k), axis=(0, 1))))
        return flow

    centres = np.array([[50.0, 40.0], [3.0, 2.0], [75.0, 40.0], [-40.0, 10.0], [51.5, 39.0]])
    flow = fresh()
    ptr, pos, vel = flow.near_many(centres, 9.0)
    gh, gw = flow._shape
    rows, cols = np.divmod(np.arange(gh * gw), gw)
    assert ptr[0] == 0 and ptr[-1] == len(pos) == len(vel)
    for t, (cx, cy) in enumerate(centres):
        inside = (cols * 4 + 2.0 - cx) ** 2 + (rows * 4 + 2.0 - cy) ** 2 <= 81.0
        r, c = rows[inside], cols[inside]
        ok = flow._valid[r, c]
        np.testing.assert_array_equal(pos[ptr[t] : ptr[t + 1]], flow._last[r[ok], c[ok]])
        np.testing.assert_array_equal(vel[ptr[t] : ptr[t + 1]], flow._vel[r[ok], c[ok]])
        alone = fresh().near(centres[t], 9.0)
        np.testing.assert_array_equal(alone[0], pos[ptr[t] : ptr[t + 1]])
        np.testing.assert_array_equal(alone[1], vel[ptr[t] : ptr[t + 1]])
    assert ptr[4] - ptr[3] == 0  # off the frame
    assert ptr[1] - ptr[0] >= 4 and ptr[3] - ptr[2] < ptr[1] - ptr[0]  # the flat region
    empty = fresh().near_many(np.zeros((0, 2)), 9.0)
    assert empty[0].tolist() == [0] and empty[1].shape == (0, 2)


def test_patches_matched_in_place_are_the_gathered_patches_matches():
    """The flow matches each patch in its window read in place from the padded frames, each
    moved back inside the frame where it reaches past it: the same offsets and NCC, bit for
    bit, as :func:`ncc_argmax` on gathered, clipped copies."""
    from tracker.pnmc.flow import _ncc_argmax_in

    rng = np.random.default_rng(2)
    prev = rng.integers(0, 255, (1, 40, 50)).astype(np.float32)
    nxt = np.roll(prev, (1, -2), axis=(1, 2)) + rng.integers(-3, 4, prev.shape)
    nxt = nxt.astype(np.float32)
    prev[0, 10:20, 10:20] = 7.0  # flat patches: score 0
    p, r = 4, 3
    tl = np.stack([rng.integers(-6, 52, 300), rng.integers(-6, 42, 300)], 1)

    def gather(frame, top_left, size):
        x = np.clip(top_left[:, 0], 0, frame.shape[2] - size)
        y = np.clip(top_left[:, 1], 0, frame.shape[1] - size)
        d = np.arange(size)
        out = frame[:, (y[:, None] + d)[:, :, None], (x[:, None] + d)[:, None, :]]
        return np.ascontiguousarray(out.transpose(1, 0, 2, 3))

    best, score = _ncc_argmax_in(prev, nxt, tl, p, r)
    want = ncc_argmax(gather(prev, tl, p), gather(nxt, tl - r, p + 2 * r))
    np.testing.assert_array_equal(best, want[0])
    assert score.tobytes() == want[1].tobytes()
    assert (score == 0).any() and (score > 0.9).mean() > 0.5


def test_flow_priors_taken_ahead_in_one_batch_are_those_taken_one_at_a_time(monkeypatch):
    """The flow priors of every target whose likelihood peak is below ``tau``, taken in one
    batch before the propagation (:data:`tracker.pnmc.tracker.FLOW_PRIORS_AHEAD`), give, on
    every frame, the positions, update order, delays and flow choices of taking each one
    when the propagation asks for it."""
    import tracker.pnmc.tracker as pnmc
    from synth_data.sequence import synthetic_crowd

    crowd = synthetic_crowd(60, 12, 0, 12, size=(220, 160), contrast=0.3, noise_sigma=8.0)
    frames = list(crowd.frames())
    ids, points = crowd.gt_points()
    start = np.isfinite(points[0]).all(1)
    batches = []
    real = pnmc._flow_map_cells

    def counted(targets, *args):
        batches.append(len(targets))
        return real(targets, *args)

    monkeypatch.setattr(pnmc, "_flow_map_cells", counted)
    trackers = {ahead: PNMCTracker(PNMCParams(tau=0.95)) for ahead in (True, False)}
    for t in trackers.values():
        t.init(frames[0], ids[start], points[0, start], 12)
    used = 0
    for frame in frames[1:]:
        seen = {}
        for ahead, t in trackers.items():
            monkeypatch.setattr(pnmc, "FLOW_PRIORS_AHEAD", ahead)
            batches.clear()
            t.step(frame)
            seen[ahead] = (t.ids, t.points, t.update_order, t.delayed, t.used_flow, batches[:])
        for a, b in zip(seen[True][:5], seen[False][:5], strict=True):
            assert a.tobytes() == b.tobytes()
        assert set(seen[False][5]) <= {1}  # one target at a time when asked
        used += int(seen[True][4].sum())
        if seen[True][4].any():
            assert max(seen[True][5]) >= 2  # ahead: one batch of several
    assert used >= 10


def test_batched_ncc_matches_the_definition():
    rng = np.random.default_rng(0)
    win = rng.random((2, 1, 8, 8)).astype(np.float32)
    templ = win[:, :, 2:6, 3:7].copy()
    score = batched_ncc(templ, win)
    assert score.shape == (2, 5, 5)
    assert np.all(score.reshape(2, -1).argmax(1) == 2 * 5 + 3)
    np.testing.assert_allclose(score[:, 2, 3], 1.0, atol=1e-5)
    # the fused numba kernel agrees with the numpy reference, flat cases included
    win = rng.integers(0, 255, (50, 1, 10, 10)).astype(np.float32)
    templ = rng.integers(0, 255, (50, 1, 4, 4)).astype(np.float32)
    win[0] = 7.0
    templ[1] = 3.0
    ref = batched_ncc(templ, win).reshape(50, -1)
    best, top = ncc_argmax(templ, win)
    np.testing.assert_array_equal(best, ref.argmax(1))
    np.testing.assert_allclose(top, ref.max(1), atol=1e-5)
    assert top[0] == 0.0 and top[1] == 0.0


# ---------------------------------------------------------------------------- parameters
CHANGES = {
    "search_factor": 3.0,
    "tau": 0.5,
    "prior_sigma": 0.2,
    "weight_scale": 20.0,
    "neighbour_radius": 1.0,
    "neighbour_weights": "updated",
    "ncc_mean": "joint",
    "use_neighbours": False,
    "use_flow": False,
    "n_clusters": 3,
    "min_cluster_pixels": 200,
    "queen_fraction": 0.5,
    "fill_fraction": 0.3,
    "queen_order": "mass",
    "queen_mode": "random",
    "queen_every": 2,
    "gmm_iterations": 2,
    "gmm_samples": 50,
    "gmm_reg": 400.0,
    "flow_patch": 6,
    "flow_spacing": 3,
    "flow_frames": 3,
    "flow_search": 0.25,
    "flow_radius": 2.0,
    "flow_select": "last",
    "flow_min_ncc": 0.95,
    "update_every": 2,
    "update_threshold": 0.95,
    "seed": 5,
    "lost_ratio": 0.99,
    "max_lost": 0,
    "cmc": True,
    "cmc_method": "ecc",
}
# fields whose change must alter what the tracker does on the occlusion scene below
MATTERS = {
    "search_factor",
    "tau",
    "prior_sigma",
    "use_neighbours",
    "queen_fraction",
    "queen_mode",
    "flow_patch",
    "flow_spacing",
    "flow_frames",
    "flow_search",
    "flow_min_ncc",
    "update_every",
    "update_threshold",
    "lost_ratio",
}


def _snapshot(t: PNMCTracker) -> tuple:
    f = t.flow
    return (
        t.points.tobytes(),
        t.confidence.tobytes(),
        t.queens.tobytes(),
        t.velocity.tobytes(),
        t.update_order.tobytes(),
        t.delayed.tobytes(),
        t.used_flow.tobytes(),
        t.radius,
        t.model.update_every,
        t.model.update_threshold,
        t.model.templates.tobytes(),
        f.patch,
        f.spacing,
        f.search,
        f.min_ncc,
        f.buffer.maxlen,
    )


def _run(params: PNMCParams, switch_to: PNMCParams | None, frames, p0) -> list[tuple]:
    t = PNMCTracker(params)
    t.init(frames[0], np.arange(1, len(p0) + 1), p0, SIZE)
    if switch_to is not None:
        t.set_params(switch_to)
    out = []
    for f in frames[1:]:
        t.step(f)
        out.append(_snapshot(t))
    return out


def test_every_parameter_takes_effect_mid_sequence():
    assert set(CHANGES) == {f.name for f in fields(PNMCParams)}
    paths = turning_group(n_frames=12)
    frames = draw(paths, GROUP_COLOURS, occlude={0: 6})
    p0 = paths[0].astype(float)
    default = PNMCParams(use_flow=True)
    base = _run(default, None, frames, p0)
    differs = set()
    for name, value in CHANGES.items():
        new = replace(default, **{name: value})
        switched = _run(default, new, frames, p0)
        # changing a field after init == having had it from the start
        assert switched == _run(new, None, frames, p0), name
        if switched != base:
            differs.add(name)
    assert MATTERS <= differs, MATTERS - differs


def test_set_params_refuses_other_types():
    t = PNMCTracker()
    with pytest.raises(ValueError, match="PNMCParams"):
        t.set_params(object())


# ---------------------------------------------------------------------------- edge cases
def test_zero_one_and_flat():
    sc = make_scene(np.zeros((0, 2)), np.zeros((0, 2)), n_frames=3)
    res = PNMCTracker().track(sc.frames, [], np.zeros((0, 2)), SIZE)
    assert res.positions.shape == (3, 0, 2)
    sc = make_scene([[40, 40]], [[2, -1]], n_frames=8)
    t = PNMCTracker()
    res = t.track(sc.frames, sc.ids, sc.points[0], SIZE)
    np.testing.assert_array_equal(res.positions, sc.points)
    assert t.queens.tolist() == [True]
    flat = [np.full((60, 80, 3), 100, np.uint8)] * 5
    res = PNMCTracker().track(flat, [1, 2], np.array([[20.0, 20.0], [60.0, 40.0]]), SIZE)
    assert np.isfinite(res.positions).all()
    assert np.abs(res.positions - res.positions[0]).max() <= 4 * 5


def test_births_reselect_queens_and_copy_is_independent():
    sc = make_scene(
        [[20, 20], [60, 30], [100, 40]],
        [[1, 0], [1, 0], [-1, 0]],
        n_frames=6,
        birth_frames=[0, 0, 3],
    )
    t = PNMCTracker(PNMCParams(queen_every=1))
    births = {3: (np.array([3]), sc.points[3, 2:3])}
    res = track(t, sc.frames, sc.points[0, :2], births=births)
    np.testing.assert_array_equal(res.positions[3:], sc.points[3:])
    assert len(t.queens) == 3 and t._queens_at == 3  # selected again after the birth
    clone = copy.deepcopy(t)
    clone.step(sc.frames[-1])
    assert t.frame_index == 5


@pytest.mark.parametrize(
    "field,value",
    [
        ("tau", 1.0),
        ("tau", -0.1),
        ("prior_sigma", 0.0),
        ("search_factor", 1.0),
        ("n_clusters", 0),
        ("n_clusters", 2.5),
        ("queen_fraction", 0.0),
        ("fill_fraction", 1.5),
        ("queen_order", "size"),
        ("queen_mode", "all"),
        ("use_flow", "yes"),
        ("flow_patch", 1),
        ("flow_frames", 1),
        ("weight_scale", float("nan")),
        ("flow_select", "first"),
        ("neighbour_weights", "now"),
        ("update_every", 0),
        ("seed", -1),
    ],
)
def test_bad_params_name_field_and_value(field, value):
    with pytest.raises(ValueError, match=rf"PNMCParams\.{field} .*got {value!r}"):
        PNMCParams(**{field: value})


def test_cluster_order_keys_by_hand():
    mass, volume = np.array([2, 3]), np.array([4.0, 0.5])
    want = {
        "density": [0.5, 6.0],
        "mass": [2.0, 3.0],
        "volume": [4.0, 0.5],
        "mass_volume": [8.0, 1.5],
        "inverse_density": [2.0, 1.0 / 6.0],
    }
    assert set(want) == set(QUEEN_ORDERS)
    for order, key in want.items():
        np.testing.assert_allclose(cluster_order_key(mass, volume, order), key, rtol=1e-15)


def _sliding_texture(n_frames: int, min_ncc: float = 0.5) -> InstantaneousFlow:
    """A random texture moving +1 px in x per frame, pushed into a 3-frame flow."""
    base = np.random.default_rng(0).integers(0, 256, (60, 60, 3), dtype=np.uint8)
    flow = InstantaneousFlow(patch=4, spacing=4, frames=3, search=2, min_ncc=min_ncc)
    for t in range(n_frames):
        flow.push(np.ascontiguousarray(np.roll(base, t, axis=1)))
    return flow


def test_flow_disc_includes_patches_exactly_at_the_radius():
    """near() takes every grid patch whose centre is within radius px, the boundary included."""
    positions, velocities = _sliding_texture(3).near(np.array([30.0, 30.0]), 4.0)
    assert len(positions) == 5
    np.testing.assert_array_equal(velocities, np.tile([1.0, 0.0], (5, 1)))


def test_flow_positions_are_in_the_frame_before_the_newest():
    """near() gives patch positions in the frame before the newest, not the newest."""
    positions, velocities = _sliding_texture(3).near(np.array([30.0, 30.0]), 5.0)
    expect = np.array([[30, 26], [26, 30], [30, 30], [34, 30], [30, 34]], np.float64) + [1.0, 0.0]
    np.testing.assert_array_equal(positions, expect)
    np.testing.assert_array_equal(velocities, np.tile([1.0, 0.0], (5, 1)))


def test_flow_keeps_tracks_whose_worst_ncc_equals_min_ncc():
    """A track whose worst NCC equals min_ncc is still valid (>=, not >)."""
    probe = _sliding_texture(3, min_ncc=0.0)
    assert len(probe.near(np.array([30.0, 30.0]), 5.0)[0]) == 5
    worst = min(float(score[done].min()) for done, _, score in probe.pairs)
    assert worst > 0.9
    positions, _ = _sliding_texture(3, min_ncc=worst).near(np.array([30.0, 30.0]), 5.0)
    assert len(positions) == 5
