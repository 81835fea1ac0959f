"""The BQP dense-crowd tracker (paper 1: Dehghan & Shah, BQP solved by Frank-Wolfe with SWAP).

Per frame, for the ``n`` active targets with ``k`` candidates each (Eq. 1):

``min_x  c_a.x + zeta c_m.x + eta c_nm.x + w_sp x^T C_sp x + w_g x^T C_g x``

over one-hot ``x`` per target (Eq. 2-3), relaxed to a product of simplices and solved by
:func:`tracker.bqp.frank_wolfe.solve` (Sec. 5), then rounded per target (Eq. 14).

Stages of a frame (their seconds are accumulated in ``timings``):

``appearance``
    Correlation-filter (or NCC) responses over every target's search window at once
    (:mod:`tracker.appearance`), and the model update of confident targets.
``terms``
    Motion (Eq. 6) and neighbourhood-motion (Eq. 7-8) maps, candidate selection (dense or
    speed-up sampling, :mod:`tracker.candidates`), the sparse quadratic terms (Eq. 9-10,
    :mod:`tracker.bqp.quadratic`) and, every ``group_refresh`` frames, the coherent-motion
    groups and their spanning trees.
``solve``
    Building the :class:`tracker.bqp.qp.BlockQP` and running Frank-Wolfe. Where the targets
    fall into independent groups (no proximity or grouping entry between them), the terms
    build the QP grouped by component and each group is solved apart, in parallel
    (:func:`tracker.bqp.frank_wolfe.solve` with ``components``).

The stages run on the tracker's ``threads`` (:mod:`tracker.threads`); tracks are the same for
any number of threads.

Search windows are centred on the constant-velocity prediction ``p + p_dot`` (with ``cmc``, on
the camera-compensated one: :class:`tracker.base.Tracker`); targets whose prediction leaves the
image are terminated; births come from the caller (ground truth on synthetic data, a points
CSV on real video).
"""

from __future__ import annotations

import time
from types import MappingProxyType

import numpy as np
import scipy.sparse as sp

from tracker.appearance import make_appearance
from tracker.base import Tracker
from tracker.bqp.params import BQPParams
from tracker.bqp.quadratic import quadratic_matrix
from tracker.bqp.terms import coherent_groups, group_trees, linear_cost, neighbours_in_groups
from tracker.candidates import (
    Candidates,
    dense_candidates,
    search_radius,
    speedup_candidates,
)


class BQPTracker(Tracker):
    """Joint tracker of all targets, one binary quadratic program per frame.

    Parameters
    ----------
    params : BQPParams, optional
        All weights and thresholds (default: the paper's values).
    record_qps : bool
        Keep every frame's :class:`tracker.bqp.qp.BlockQP` in ``recorded_qps`` (for the solver
        benchmark: "relaxed QPs taken from real tracking frames"). Where a frame was solved
        by components its blocks are grouped by component (:meth:`quadratic`).

    Attributes
    ----------
    velocities : (n, 2) float64
        Smoothed velocities ``p_dot`` (px/frame) of the state ``s = [p, p_dot]`` (Eq. 6).
    history : (H, n, 2) float64
        Last ``params.history`` positions, oldest first, NaN before a target existed.
    groups : (n,) int64
        Coherent-motion group of each target, ``-1`` for none (refreshed every ``tau``).
    tree_edges : (E, 2) int64, tree_lengths : (E,) float64, tree_offsets : (E, 2) float64
        Spanning-tree edges of the groups, their lengths ``e_ij`` (Eq. 10) and relative
        positions ``p_a - p_b`` at the last refresh, px.
    solver_iterations : int
        Frank-Wolfe iterations summed over frames.
    """

    name = "bqp"
    params_class = BQPParams
    fixed_params = frozenset({"history"})
    """The position history is an array of ``history`` frames; its length is set at init."""
    camera_state = MappingProxyType(
        {"velocities": "vectors", "tree_offsets": "vectors", "tree_lengths": "lengths"}
    )
    """With ``cmc``: the state ``s = [p, p_dot]`` of Eq. 6 and the spanning trees' geometry move
    with the camera. The position ``history`` (coherent groups) stays in image coordinates: in
    dense crowds the estimate takes in part of the crowd's own motion, and moving the history
    with it left the groups residual, noisy motion. On seq6 (ucf9 marathon, static camera)
    moving the history too cost 3.8 points at 15 px (66.6 -> 62.8 %) where leaving it gained
    1.5 (68.1 %); with seq6's 2.3 px shake, 60.6 against 63.5 % (62.5 % without ``cmc``)."""

    _REBUILD_APPEARANCE = frozenset(
        {
            "appearance",
            "search_factor",
            "kcf_label_sigma",
            "kcf_kernel",
            "kcf_target_window",
            "kcf_lambda",
            "kcf_kernel_sigma",
        }
    )
    """Fields that change the shape, the kind or the training of the appearance models:
    changing one of them mid-sequence re-learns every target's model from the last frame at
    its current position (so a change right after init acts as if given at start)."""

    def __init__(self, params: BQPParams | None = None, record_qps: bool = False):
        super().__init__()
        self.params = params if params is not None else BQPParams()
        self.record_qps = record_qps
        self.recorded_qps: list = []
        self.n_candidates = 0

    # ------------------------------------------------------------------ lengths in px
    def _px(self, value: float) -> float:
        return float(value) * self.template_size

    # ------------------------------------------------------------------ hooks
    def _make_appearance(self):
        p = self.params
        self.radius = search_radius(self.template_size, p.search_factor)
        return make_appearance(
            p.appearance,
            self.template_size,
            self.radius,
            update_threshold=p.update_threshold,
            lam=p.kcf_lambda,
            learning_rate=p.kcf_learning_rate,
            label_sigma=p.kcf_label_sigma,
            kernel=p.kcf_kernel,
            kernel_sigma=p.kcf_kernel_sigma,
            target_window=p.kcf_target_window,
            update_every=p.ncc_update_every,
        )

    def _apply_params(self, old: BQPParams, changed: frozenset[str]) -> None:
        p = self.params
        if changed & self._REBUILD_APPEARANCE:
            self.appearance = self._make_appearance()
            self.appearance.add(self._frame, np.rint(self.points).astype(np.int64))
        else:
            # the appearance model copied these at init; every other field is read per frame
            app = self.appearance
            app.update_threshold = float(p.update_threshold)
            if hasattr(app, "learning_rate"):
                app.learning_rate = float(p.kcf_learning_rate)
            if hasattr(app, "update_every"):
                app.update_every = int(p.ncc_update_every)
        if "seed" in changed:
            self.rng = np.random.default_rng(p.seed)

    def stats(self) -> dict[str, float]:
        """The base counters (:meth:`tracker.base.Tracker.stats`) plus ``solver_iterations``
        (Frank-Wolfe iterations summed over the frames so far) and ``group_fraction`` (the
        share of targets now in a coherent-motion group)."""
        out = super().stats()
        out["solver_iterations"] = float(getattr(self, "solver_iterations", 0))
        groups = getattr(self, "groups", np.zeros(0, np.int64))
        out["group_fraction"] = float((groups >= 0).mean()) if len(groups) else 0.0
        return out

    def _init(self, frame: np.ndarray) -> None:
        p = self.params
        self.appearance = self._make_appearance()
        self._frame = frame
        self.velocities = np.zeros((0, 2))
        self.history = np.zeros((p.history, 0, 2))
        self.groups = np.zeros(0, np.int64)
        self.tree_edges = np.zeros((0, 2), np.int64)
        self.tree_lengths = np.zeros(0)
        self.tree_offsets = np.zeros((0, 2))
        self.rng = np.random.default_rng(p.seed)
        self.since_refresh = 0
        self.solver_iterations = 0
        self.recorded_qps = []

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        t0 = time.perf_counter()
        self.appearance.add(frame, np.rint(points).astype(np.int64))
        self._frame = frame
        m = len(points)
        self.velocities = np.concatenate([self.velocities, np.zeros((m, 2))])
        col = np.full((self.params.history, m, 2), np.nan)
        col[-1] = points
        self.history = np.concatenate([self.history, col], axis=1)
        self.groups = np.concatenate([self.groups, np.full(m, -1, np.int64)])
        self._tick("appearance", t0)

    def _remove(self, keep: np.ndarray) -> None:
        n_old = len(self.velocities)
        remap = np.full(n_old, -1, np.int64)
        remap[keep] = np.arange(len(keep))
        self.appearance.keep(keep)
        self.velocities = self.velocities[keep]
        self.history = self.history[:, keep]
        self.groups = self.groups[keep]
        if len(self.tree_edges):
            e = remap[self.tree_edges]
            ok = (e >= 0).all(1)
            self.tree_edges, self.tree_lengths = e[ok], self.tree_lengths[ok]
            self.tree_offsets = self.tree_offsets[ok]

    def _predicted(self) -> np.ndarray:
        return self.points + self.velocities

    def motion(self) -> np.ndarray:
        return self.velocities.copy()

    # ------------------------------------------------------------------ one frame
    def candidates(self, frame: np.ndarray) -> tuple[Candidates, np.ndarray]:
        """Score the search grids and select candidates; returns them and the search centres."""
        p = self.params
        h, w = self.frame_shape[:2]
        t0 = time.perf_counter()
        pred = self.points + self.velocities
        centers = np.rint(pred)
        centers[:, 0] = np.clip(centers[:, 0], 0, w - 1)
        centers[:, 1] = np.clip(centers[:, 1], 0, h - 1)
        centers = centers.astype(np.int64)
        app = self.appearance.scores(frame, centers)
        t0 = self._tick("appearance", t0)

        if p.eta > 0:
            nbr, wts = neighbours_in_groups(
                self.points,
                self.groups,
                p.n_neighbours,
                self._px(p.group_radius),
                self._px(p.neighbour_scale),
                same_group=p.neighbour_set == "group",
            )
        else:
            nbr, wts = np.zeros((len(pred), 0), np.int64), np.zeros((len(pred), 0))
        cost = linear_cost(
            app,
            centers,
            self.radius,
            pred,
            self._px(p.motion_sigma),
            p.zeta,
            p.eta,
            self.points,
            self.velocities,
            nbr,
            wts,
            p.border_penalty,
            (w, h),
        )
        if p.speedup:
            cands = speedup_candidates(
                centers,
                self.radius,
                cost,
                app,
                self.rng,
                p.n_extrema,
                p.n_samples,
                p.sample_window,
                p.distinct_samples,
            )
        else:
            cands = dense_candidates(centers, self.radius, cost, app, p.candidate_stride)
        self._tick("terms", t0)
        return cands, centers

    def quadratic(
        self, cands: Candidates
    ) -> tuple[sp.csc_matrix, np.ndarray, np.ndarray | None, np.ndarray]:
        """``w_sp C_sp + w_g C_g`` (Eq. 9-10) over the candidates, ``(l, l)`` CSC, the
        connected component of every block (no entry of ``Q`` joins two components), the
        target of every block (``None`` when block ``i`` is target ``i``, else the targets
        grouped by component, as the solver will solve them apart) and ``Q``'s diagonal
        (:func:`tracker.bqp.quadratic.quadratic_matrix` with ``split_share`` and ``diagonal``)."""
        from tracker.bqp.frank_wolfe import SPLIT_MAX_SHARE

        p = self.params
        ref = self.tree_offsets if p.group_offsets else self.tree_lengths
        return quadratic_matrix(
            cands.positions,
            p.w_sp,
            self._px(p.proximity_sigma),
            p.proximity_cutoff,
            p.w_g,
            self.tree_edges,
            ref,
            self._px(p.group_sigma),
            p.group_cutoff,
            p.laplacian_tau,
            components=True,
            split_share=SPLIT_MAX_SHARE,
            diagonal=True,
        )

    def _step(self, frame: np.ndarray) -> np.ndarray:
        from tracker.bqp.frank_wolfe import FWParams, solve
        from tracker.bqp.qp import BlockQP

        p = self.params
        n = len(self.points)
        cands, _ = self.candidates(frame)
        t0 = time.perf_counter()
        q, components, order, diagonal = self.quadratic(cands)
        t0 = self._tick("terms", t0)
        cost = (cands.cost if order is None else cands.cost[order]).ravel()
        if p.laplacian_identity == "every":  # the paper's I: a constant on binary points
            cost = cost - diagonal
        qp = BlockQP.from_terms(cost, q, cands.block_ptr, diagonal)
        if self.record_qps:
            self.recorded_qps.append(qp)
        res = solve(
            qp,
            params=FWParams(variant=p.fw_variant, eps=p.fw_eps, max_iter=p.fw_max_iter * n),
            components=None if order is None else components,
        )
        choice = res.choice
        if order is not None:  # block i is target order[i]
            choice = np.empty_like(res.choice)
            choice[order] = res.choice
        self.solver_iterations += res.iterations
        self.n_candidates += cands.n * cands.k
        rows = np.arange(n)
        new = cands.positions[rows, choice]
        conf = cands.appearance[rows, choice]
        self.confidence = conf.astype(np.float64)
        t0 = self._tick("solve", t0)

        self.appearance.update(frame, np.rint(new).astype(np.int64), conf)
        self._frame = frame
        t0 = self._tick("appearance", t0)

        a = p.velocity_smoothing
        self.velocities = a * self.velocities + (1.0 - a) * (new - self.points)
        self.history = np.roll(self.history, -1, axis=0)
        self.history[-1] = new
        self.since_refresh += 1
        if self.since_refresh >= p.group_refresh:
            self.refresh_groups(new)
        self._tick("terms", t0)
        return new

    def refresh_groups(self, positions: np.ndarray | None = None) -> None:
        """Recompute coherent-motion groups and their spanning trees (every ``tau`` frames)."""
        p = self.params
        pos = self.points if positions is None else positions
        self.since_refresh = 0
        self.groups = coherent_groups(
            self.history, self._px(p.group_radius), p.coherence_threshold, p.min_group_speed
        )
        self.tree_edges, self.tree_lengths = group_trees(pos, self.groups, self._px(p.group_radius))
        self.tree_offsets = pos[self.tree_edges[:, 0]] - pos[self.tree_edges[:, 1]]
