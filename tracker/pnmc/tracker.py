"""PNMC: tracking dense crowds with prominence and neighbourhood motion concurrence (paper 2).

Per frame ``t`` (Sec. 3.4, Algorithm 2):

1. **Likelihood** (Eq. 6-7): every target's colour template is correlated (NCC, ``gamma``)
   over a search region of ``search_factor`` template sizes centred on its constant-velocity
   prediction ``A x_i^{t-1}``; ``p(z | x) = (gamma + 1) / 2``. One ``cv2.matchTemplate`` per
   target, as the NCC baseline (:class:`tracker.appearance.NCCAppearance`). Its
   ``TM_CCOEFF_NORMED`` takes each colour channel's own mean off, where Eq. 7 correlates
   over x, y and colour as one signal with "its mean subtracted", read as one mean (as
   :func:`tracker.pnmc.flow.batched_ncc` does): a window that differs from the template by
   a constant in one channel scores 1 here; ``ncc_mean="joint"`` takes the one mean.
2. **Hierarchical update**: queens (:mod:`tracker.pnmc.queens`) are updated first with the
   self prior ``p_S`` alone (Eq. 1); then breadth-first over the neighbour graph (targets
   within ``neighbour_radius``), each target with the NMC prior ``zeta (p_S + p_N)`` (Eq. 5)
   whose ``p_N`` (Eq. 2) holds a Gaussian at ``x_i^{t-1} + v_j^t`` for every neighbour ``j``
   already updated in this frame (``lambda_j = 1``), weighted by Eq. 3. The MAP position
   (Eq. 8) is the argmax of likelihood times prior over the search grid.
3. **Low confidence**: when ``p(z | x_hat) < tau_i``, the prior is rebuilt from the
   instantaneous flow (:mod:`tracker.pnmc.flow`, Sec. 3.3: ``p_N`` from nearby patches'
   five-frame velocities). If that does not reach ``tau_i`` either, the target goes to the
   back of the queue (delayed update) and its threshold is lowered to the confidence it
   reached; a later visit with an unchanged prior therefore updates it, which is the
   finiteness argument of the paper's Appendix A ("gradually lowers the threshold till the
   individual's position is updated"). The best of the NMC and flow estimates is kept.
4. **Templates** are refreshed every ``update_every`` frames when the update confidence is at
   least ``update_threshold`` (Sec. 4: every 10 frames).

Choices where the paper is silent or the text is ambiguous (recorded here, SPEC §6 agrees
with each formula; the paper is the source where they differ):

* **Algorithm 2's body** is missing from our copy of the paper; steps 2-3 above follow the
  prose of Sec. 3.4 and Appendix A. ``tau`` applies to ``p(z | x_hat) = (gamma + 1) / 2``
  ("if ``p(z^t | x_hat^t)`` for a target is low"), so 0.9 means ``gamma >= 0.8``.
* **Covariances** ``A Sigma A^T`` are isotropic, ``(prior_sigma * s)^2 I`` for every target
  and patch (the paper gives no value). ``p_S`` is weighted by the previous update
  confidence ``p(z^{t-1} | x_hat^{t-1})`` (Eq. 1), floored at 1e-3 so a target that was
  scored 0 still has a self prior.
* **Eq. 3** normalises ``exp(-||x_j - x_i|| / weight_scale)`` over *all* neighbours within the
  radius, updated or not (the sum runs over ``k in Neighbors``), so ``p_N`` carries the
  fraction of the neighbourhood already updated. ``weight_scale = 1`` px is the paper's
  formula as printed.
* **Velocity** ``v_i^t = x_hat_i^t - x_hat_i^{t-1}`` (state transition ``A``: constant
  velocity); ``v = 0`` at birth.
* **Disconnected groups**: when the queue empties before every target is updated, the not yet
  queued target with the highest likelihood peak seeds the next breadth-first pass (a queen
  of its own component).
* **Queens** are selected from the current templates at initialisation and again after
  targets were added, at most every ``queen_every`` frames (the paper: "only when new
  initializations took place, which typically occurred after every fifty frames").

* **Flow** patches are grey levels and their five-frame tracks are re-anchored on the 4 px
  grid at every step so that frame pairs are matched once and cached
  (:mod:`tracker.pnmc.flow`); the flow prior of a target is computed once per frame, and for
  every target whose likelihood peak is already below ``tau`` (all of them will need it) in
  one batch up front (:data:`FLOW_PRIORS_AHEAD`).
* **Flow neighbours** (``flow_select``): by default a target's flow patches are those whose
  track *started* (in the oldest buffered frame, ``flow_frames - 1`` frames before the
  newest and ``flow_frames - 2`` before ``x_i^{t-1}``'s) within ``flow_radius`` of
  ``x_i^{t-1}``, Eq. 3's weights then use their positions in
  ``x_i^{t-1}``'s frame; ``flow_select="last"`` selects by that position too, the paper's
  "nearby patches" (Sec. 3.3). The default is kept so that no figure moves; the bias it
  gives a fast target is measured in :class:`tracker.pnmc.params.PNMCParams`.
* **Camera motion** (``cmc``, beyond the paper, :class:`tracker.base.Tracker`): the positions
  and velocities move with the camera before the likelihood is computed; the flow is looked
  up where the targets were in the uncompensated frame, and the camera's mean shift over the
  flow's frame pairs is taken off its velocities (it is already in the compensated positions).
* **SPEC §6 and the paper** agree on every formula; where the spec abbreviates the prior as
  ``pS + pN``, the paper's Eq. 1-5 are used as written (``p_S`` weighted by the previous
  observation likelihood, ``p_N`` by Eq. 3 and ``lambda_j``).

``confidence`` (base class) is ``p(z | x_hat) = (gamma + 1) / 2`` of the chosen location.

Speed: the breadth-first pass is one compiled loop (:func:`_propagate`, the targets in
Algorithm 2's order, separable Gaussians); likelihoods, the neighbour graph (``cKDTree``),
the flow priors (:func:`_flow_map_cells`), flow matching (numba, read in place from the
buffered frames) and queens (numpy EM) are batched, with no Python loop over targets. The
1,000 packed targets of ``crowdsim bench track`` (``benchmarks/track_stages.py --tracker
pnmc --threads 2``, 2 cores, a slow spell): 12.0-13.6 frames/s, update stage 48-56 ms a
frame (7.4-8.3 frames/s and 90-104 ms with a Python call per target that needed the flow).
"""

from __future__ import annotations

import math
import time
from collections import deque
from types import MappingProxyType

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from tracker.appearance import NCCAppearance, numpy_sum
from tracker.base import Tracker
from tracker.candidates import grid_offsets, search_radius
from tracker.pnmc.flow import InstantaneousFlow
from tracker.pnmc.params import PNMCParams
from tracker.pnmc.queens import select_queens

_PS_FLOOR = 1e-3
"""Smallest weight of ``p_S`` (a previous confidence of 0 would switch the self prior off)."""
FLOW_PRIORS_AHEAD: bool = True
"""Compute the flow priors (Sec. 3.3) of the targets whose best likelihood is below ``tau`` in
one batch before the propagation (they will all ask for it), instead of one at a time as the
propagation asks. The same cells either way (a test compares); on a packed 1,000-target
frame the per-target Python calls took about 40 % of PNMC's update stage."""


@njit(cache=True, nogil=True)
def _map_cell(
    lik: np.ndarray, gx: np.ndarray, gy: np.ndarray, mus: np.ndarray, ws: np.ndarray, sig2: float
) -> int:
    """The MAP cell of one target (Eq. 4 / 8): ``argmax lik * prior`` over its ``(k, k)`` grid
    (cell ``y k + x``; the first of equal cells), where the prior ``sum_j w_j N(mu_j, sigma^2
    I)`` is separable in x and y (``sig2 = 2 sigma^2``). Where the prior underflows
    everywhere, the appearance alone decides (``argmax lik``).

    One target at a time, in the order of Algorithm 2: each target's prior depends on the
    neighbours updated before it, so the per-target step is a compiled call (numpy's small
    arrays took 13 us a target, about a third of a 1,000-target frame).
    """
    k = lik.shape[0]
    m = mus.shape[0]
    ex = np.empty((m, k))
    ey = np.empty((m, k))
    for j in range(m):
        for c in range(k):
            d = gx[c] - mus[j, 0]
            ex[j, c] = np.exp(-(d * d) / sig2)
            d = gy[c] - mus[j, 1]
            ey[j, c] = np.exp(-(d * d) / sig2) * ws[j]
    best = 0
    best_v = -np.inf
    for y in range(k):
        for x in range(k):
            prior = 0.0
            for j in range(m):
                prior += ey[j, y] * ex[j, x]
            v = lik[y, x] * prior
            if v > best_v:
                best_v = v
                best = y * k + x
    if best_v <= 0.0:  # prior underflow: appearance alone
        best = 0
        for q in range(1, k * k):
            if lik.flat[q] > lik.flat[best]:
                best = q
    return best


@njit(cache=True, nogil=True, parallel=True)
def _flow_map_cells(
    targets, ptr, e, fvel, camera_v, pred, prev, ws_self, lik, gx, gy, sig2, cell, conf
):
    """The flow prior (Sec. 3.3) of each target ``targets[t]``, its MAP cell and that cell's
    likelihood into ``cell`` / ``conf`` (left as they are for a target with no patch near).

    The prior mixes the target's own prediction (weight ``ws_self``) with ``prev + v`` for
    every valid flow patch ``ptr[t]:ptr[t+1]`` near it, weighted by ``e / e.sum()``
    (``e``: each patch's ``exp(-(d - d_min) / weight_scale)``, taken by numpy). One target
    per loop iteration; numpy's own summation order (:func:`tracker.appearance.numpy_sum`),
    so the cells are those of the per-target numpy code this replaces, for any threads."""
    k = lik.shape[1]
    for t in prange(targets.shape[0]):
        a, z = ptr[t], ptr[t + 1]
        if a == z:
            continue
        i = targets[t]
        total = numpy_sum(e, a, z - a)
        mus = np.empty((z - a + 1, 2))
        ws = np.empty(z - a + 1)
        mus[0, 0] = pred[i, 0]
        mus[0, 1] = pred[i, 1]
        ws[0] = ws_self[i]
        for q in range(a, z):
            mus[q - a + 1, 0] = prev[i, 0] + (fvel[q, 0] - camera_v[0])
            mus[q - a + 1, 1] = prev[i, 1] + (fvel[q, 1] - camera_v[1])
            ws[q - a + 1] = e[q] / total
        b = _map_cell(lik[i], gx[i], gy[i], mus, ws, sig2)
        cell[i] = b
        conf[i] = lik[i, b // k, b % k]


@njit(cache=True, nogil=True)
def _propagate(
    lik,
    gx,
    gy,
    pred,
    prev,
    ws_self,
    indptr,
    nbr,
    wts,
    weight_scale,
    queens,
    seeds,
    sig2,
    use_flow,
    flow_done,
    flow_cell,
    flow_conf,
    new,
    conf,
    tau,
    updated,
    queued,
    visits,
    used_flow,
    order,
    queue,
    cursor,
):
    """Algorithm 2's hierarchical update with its delayed updates (Appendix A), in place.

    Targets leave the queue (queens first, then the unvisited target of highest appearance
    peak) in turn; each takes its MAP cell under the prior of its own prediction and of the
    neighbours already updated (Eq. 2, 4, 8), or under the flow prior where that is more
    confident and the first falls short of ``tau`` (Sec. 3.3), and is updated once its
    confidence reaches its ``tau`` or it has waited ``len(neighbours) + 2`` visits; else its
    ``tau`` drops to its confidence and it queues again. Updated targets queue their
    unqueued neighbours. The neighbours' weights are ``wts`` (Eq. 3 at ``t - 1``) when
    ``weight_scale`` is 0, else Eq. 3 on their positions at the visit with that length unit
    (``PNMCParams.neighbour_weights = "updated"``).

    Returns -1 when every target is updated, or a target whose flow prior is needed and not
    known yet (``flow_done`` false), without changing any state: the caller fills
    ``flow_cell`` / ``flow_conf`` for it (-1 where no flow is near), sets ``flow_done`` and
    calls again. ``cursor`` is ``(queue head, queue size, next seed, targets updated)``;
    ``queue`` is a ring of ``n`` slots (a target is in it at most once at a time).
    """
    n = lik.shape[0]
    k = lik.shape[1]
    cap = queue.shape[0]
    while cursor[3] < n:
        if cursor[1] == 0:
            while queued[seeds[cursor[2]]]:
                cursor[2] += 1
            t = seeds[cursor[2]]
            queue[(cursor[0] + cursor[1]) % cap] = t
            cursor[1] += 1
            queued[t] = True
        i = queue[cursor[0]]
        visit = visits[i] + 1
        a, z = indptr[i], indptr[i + 1]
        m = 1
        if not (queens[i] and visit == 1):
            for q in range(a, z):
                if updated[nbr[q]]:
                    m += 1
        mus = np.empty((m, 2))
        ws = np.empty(m)
        mus[0, 0] = pred[i, 0]
        mus[0, 1] = pred[i, 1]
        ws[0] = ws_self[i]
        if m > 1:
            if weight_scale > 0.0:  # Eq. 3 on the neighbours' positions now (``new``: the
                # updated ones' at t, the others' still at t - 1), normalised over them all
                dist = np.empty(z - a)
                for q in range(a, z):
                    j = nbr[q]
                    dx = new[j, 0] - prev[i, 0]
                    dy = new[j, 1] - prev[i, 1]
                    dist[q - a] = np.sqrt(dx * dx + dy * dy)
                near = dist.min()
                total = 0.0
                for q in range(z - a):
                    total += np.exp(-(dist[q] - near) / weight_scale)
            r = 1
            for q in range(a, z):
                j = nbr[q]
                if updated[j]:
                    mus[r, 0] = prev[i, 0] + (new[j, 0] - prev[j, 0])
                    mus[r, 1] = prev[i, 1] + (new[j, 1] - prev[j, 1])
                    if weight_scale > 0.0:
                        ws[r] = np.exp(-(dist[q - a] - near) / weight_scale) / total
                    else:
                        ws[r] = wts[q]
                    r += 1
        b = _map_cell(lik[i], gx[i], gy[i], mus, ws, sig2)
        c = lik[i, b // k, b % k]
        via_flow = False
        if c < tau[i] and use_flow:
            if not flow_done[i]:
                return i
            if flow_conf[i] > c:
                b = flow_cell[i]
                c = flow_conf[i]
                via_flow = True
        # commit this visit: leave the queue
        visits[i] = visit
        cursor[0] = (cursor[0] + 1) % cap
        cursor[1] -= 1
        if c >= tau[i] or visit >= z - a + 2:
            new[i, 0] = gx[i, b % k]
            new[i, 1] = gy[i, b // k]
            conf[i] = c
            used_flow[i] = via_flow
            updated[i] = True
            order[cursor[3]] = i
            cursor[3] += 1
            for q in range(a, z):
                j = nbr[q]
                if not queued[j]:
                    queue[(cursor[0] + cursor[1]) % cap] = j
                    cursor[1] += 1
                    queued[j] = True
        else:  # delayed update with a lowered threshold (Algorithm 2, Appendix A)
            tau[i] = c
            queue[(cursor[0] + cursor[1]) % cap] = i
            cursor[1] += 1
    return -1


_QUEEN_FIELDS = frozenset(
    {
        "queen_every",
        "n_clusters",
        "min_cluster_pixels",
        "queen_fraction",
        "fill_fraction",
        "queen_order",
        "queen_mode",
        "gmm_iterations",
        "gmm_samples",
        "gmm_reg",
        "seed",
    }
)
_FLOW_FIELDS = frozenset(
    {"flow_patch", "flow_spacing", "flow_frames", "flow_search", "flow_min_ncc"}
)


class PNMCTracker(Tracker):
    """Prominence + neighbourhood motion concurrence tracker (module docstring).

    Attributes (besides the base class's)
    ----------
    queens : (n,) bool
        Prominent targets (Algorithm 1).
    velocity : (n, 2) float64
        Last displacement of each target, px/frame.
    update_order : (n,) int64
        Order in which the targets were updated in the last frame (indices into ``ids``).
    delayed : (n,) int64
        Times each target went back to the queue in the last frame.
    used_flow : (n,) bool
        Targets whose last update came from the instantaneous-flow prior.
    """

    name = "pnmc"
    params_class = PNMCParams
    camera_state = MappingProxyType({"velocity": "vectors"})
    """With ``cmc``: the velocities behind the predictions ``A x_i^{t-1}`` move with the camera
    (the flow prior is corrected in :meth:`_step`)."""

    def __init__(self, params: PNMCParams | None = None):
        super().__init__()
        self.params = params if params is not None else PNMCParams()

    # ------------------------------------------------------------------ state
    def _init(self, frame: np.ndarray) -> None:
        p = self.params
        self.model = NCCAppearance(
            self.template_size, 1, p.update_threshold, update_every=p.update_every, mean=p.ncc_mean
        )
        self._set_radius()
        self.flow = InstantaneousFlow(
            p.flow_patch, p.flow_spacing, p.flow_frames, self._flow_search(), p.flow_min_ncc
        )
        self.flow.push(frame)
        self.queens = np.zeros(0, bool)
        self._queens_at = -(10**9)  # frame of the last queen selection
        self._queens_due = False
        self.velocity = np.zeros((0, 2))
        self.obs = np.zeros(0)
        self.update_order = np.zeros(0, np.int64)
        self.delayed = np.zeros(0, np.int64)
        self.used_flow = np.zeros(0, bool)
        # with cmc: the camera's last shifts (px), one per frame pair the flow averages over,
        # and the targets' positions before this frame's compensation (the flow's frame)
        self._camera_shifts: deque[np.ndarray] = deque(maxlen=p.flow_frames - 1)
        self._flow_at = np.zeros((0, 2))

    def _set_radius(self) -> None:
        self.radius = search_radius(self.template_size, self.params.search_factor)
        self.model.radius = self.radius
        self.model.window = self.template_size + 2 * self.radius
        self._offsets = grid_offsets(self.radius)

    def _flow_search(self) -> int:
        return max(1, int(round(self.params.flow_search * self.template_size)))

    def _apply_params(self, old: PNMCParams, changed: frozenset[str]) -> None:
        p = self.params
        self.model.update_threshold = float(p.update_threshold)
        self.model.update_every = int(p.update_every)
        self.model.mean = p.ncc_mean
        self._set_radius()
        if changed & _FLOW_FIELDS:
            self.flow.reconfigure(
                p.flow_patch, p.flow_spacing, p.flow_frames, self._flow_search(), p.flow_min_ncc
            )
            self._camera_shifts = deque(self._camera_shifts, maxlen=p.flow_frames - 1)
        if changed & _QUEEN_FIELDS:
            self._select_queens()

    def _select_queens(self) -> None:
        p = self.params
        n = self.model.n
        self._queens_at = self.frame_index
        self._queens_due = False
        rng = np.random.default_rng([int(p.seed), int(self.frame_index)])
        if p.queen_mode == "random":
            q = np.zeros(n, bool)
            if n:
                q[rng.choice(n, max(1, math.ceil(p.queen_fraction * n - 1e-9)), replace=False)] = (
                    True
                )
            self.queens = q
            return
        # templates are BGR; the mixture is indifferent to the channel order
        self.queens = select_queens(
            self.model.templates,
            rng,
            n_clusters=p.n_clusters,
            min_cluster_pixels=p.min_cluster_pixels,
            queen_fraction=p.queen_fraction,
            fill_fraction=p.fill_fraction,
            order=p.queen_order,
            iterations=p.gmm_iterations,
            max_samples=p.gmm_samples,
            reg=p.gmm_reg,
        )

    def _add(self, frame: np.ndarray, points: np.ndarray) -> None:
        m = len(points)
        self.model.add(frame, np.rint(points).astype(np.int64))
        self.velocity = np.concatenate([self.velocity, np.zeros((m, 2))])
        self.obs = np.concatenate([self.obs, np.ones(m)])
        self.queens = np.concatenate([self.queens, np.zeros(m, bool)])
        self._queens_due = True
        self._maybe_select_queens()

    def _maybe_select_queens(self) -> None:
        if self._queens_due and self.frame_index - self._queens_at >= self.params.queen_every:
            t0 = time.perf_counter()
            self._select_queens()
            self._tick("queens", t0)

    def _remove(self, keep: np.ndarray) -> None:
        self.model.keep(keep)
        self.queens = self.queens[keep]
        self.velocity = self.velocity[keep]
        self.obs = self.obs[keep]

    def _predicted(self) -> np.ndarray:
        return self.points + self.velocity

    def motion(self) -> np.ndarray:
        return self.velocity.copy()

    def _compensate(self, frame: np.ndarray) -> None:
        self._flow_at = self.points  # the flow's patches live in the uncompensated frame
        super()._compensate(frame)

    def _camera_moved(self, a: np.ndarray) -> None:
        self._camera_shifts.append(a[:, 2].copy())

    def _flow_origin(self, prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where to look up the flow, and the camera's mean shift in its velocities.

        Returns ``(n, 2)`` positions in the frame before the newest and the ``(2,)`` px/frame
        to take off each flow velocity: the flow averages the image motion over its last
        ``k`` frame pairs, and with ``cmc`` the camera's part of it is already in ``prev``.
        Without ``cmc``: ``prev`` and zero.
        """
        k = len(self.flow.pairs)
        if self.compensator is None or k == 0:
            return prev, np.zeros(2)
        shifts = list(self._camera_shifts)[-k:]
        return self._flow_at, np.sum(shifts, axis=0) / k if shifts else np.zeros(2)

    # ------------------------------------------------------------------ one frame
    def _graph(self, prev: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Neighbour graph ``G`` in CSR form, rows sorted by distance.

        Returns ``indptr (n+1,)``, ``indices (e,)`` and ``weights (e,)`` (Eq. 3, normalised
        over each row).
        """
        n = len(prev)
        p = self.params
        radius = p.neighbour_radius * self.template_size
        if n < 2 or not p.use_neighbours or radius <= 0:
            return np.zeros(n + 1, np.int64), np.zeros(0, np.int64), np.zeros(0)
        pairs = cKDTree(prev).query_pairs(radius, output_type="ndarray")
        if len(pairs) == 0:
            return np.zeros(n + 1, np.int64), np.zeros(0, np.int64), np.zeros(0)
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        dist = np.sqrt(((prev[src] - prev[dst]) ** 2).sum(1))
        order = np.lexsort((dst, dist, src))
        src, dst, dist = src[order], dst[order], dist[order]
        indptr = np.zeros(n + 1, np.int64)
        np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
        dmin = dist[indptr[:-1][src]]  # rows are sorted: first entry is the nearest
        e = np.exp(-(dist - dmin) / p.weight_scale)
        w = e / np.bincount(src, weights=e, minlength=n)[src]
        return indptr, dst, w

    def _step(self, frame: np.ndarray) -> np.ndarray:
        p = self.params
        h, w = self.frame_shape[:2]
        s = self.template_size
        r = self.radius
        n = len(self.points)
        self._maybe_select_queens()
        t0 = time.perf_counter()
        self.flow.push(frame)
        prev = self.points
        pred = prev + self.velocity
        centers = np.rint(pred).astype(np.int64)
        centers[:, 0] = np.clip(centers[:, 0], 0, w - 1)
        centers[:, 1] = np.clip(centers[:, 1], 0, h - 1)
        gamma = self.model.scores(frame, centers)
        lik = (gamma.astype(np.float64) + 1.0) / 2.0  # Eq. 6, (n, k, k)
        d = np.arange(-r, r + 1)
        gx = centers[:, 0:1] + d[None]  # (n, k) x of each grid column
        gy = centers[:, 1:2] + d[None]  # (n, k) y of each grid row
        lik *= ((gy >= 0) & (gy <= h - 1))[:, :, None]
        lik *= ((gx >= 0) & (gx <= w - 1))[:, None, :]
        peak = lik.reshape(n, -1).max(1)
        t0 = self._tick("appearance", t0)

        flow_at, camera_v = self._flow_origin(prev)
        indptr, nbr, wts = self._graph(prev)
        sig2 = 2.0 * (p.prior_sigma * s) ** 2
        ws_self = np.maximum(self.obs, _PS_FLOOR)
        gxf, gyf = gx.astype(np.float64), gy.astype(np.float64)
        flow_done = np.zeros(n, np.bool_)
        flow_cell = np.full(n, -1, np.int64)
        flow_conf = np.full(n, -1.0)

        def flow_priors(targets: np.ndarray) -> None:
            """The flow prior's MAP cell of ``targets`` (Sec. 3.3), all at once."""
            at = flow_at[targets]
            ptr, fpos, fvel = self.flow.near_many(at, p.flow_radius * s, p.flow_select)
            seg = np.repeat(np.arange(len(targets)), np.diff(ptr))
            dist = np.sqrt(((fpos - at[seg]) ** 2).sum(1))
            near = np.flatnonzero(ptr[1:] > ptr[:-1])
            nearest = np.zeros(len(targets))
            if len(near):
                nearest[near] = np.minimum.reduceat(dist, ptr[near])
            e = np.exp(-(dist - nearest[seg]) / p.weight_scale)
            args = (pred, prev, ws_self, lik, gxf, gyf, sig2, flow_cell, flow_conf)
            _flow_map_cells(targets, ptr, e, fvel, np.asarray(camera_v, np.float64), *args)
            flow_done[targets] = True  # the flow prior does not change within a frame

        if p.use_flow and FLOW_PRIORS_AHEAD:
            # a target whose best likelihood is below tau needs its flow prior whatever its
            # neighbours say (865 of 869 that did on a packed 1,000-target frame): all at once
            flow_priors(np.flatnonzero(peak < p.tau))
        # Algorithm 2 runs compiled (:func:`_propagate`); it hands back a target whose
        # appearance and neighbour prior fall short of tau before that target's flow prior
        # is known, the prior is computed here, and the run resumes
        new = prev.copy()
        conf = np.zeros(n)
        tau = np.full(n, float(p.tau))
        updated = np.zeros(n, np.bool_)
        queued = np.zeros(n, np.bool_)
        visits = np.zeros(n, np.int64)
        used_flow = np.zeros(n, np.bool_)
        order = np.zeros(n, np.int64)
        queue = np.zeros(max(n, 1), np.int64)
        queens = np.flatnonzero(self.queens)
        queue[: len(queens)] = queens
        queued[queens] = True
        cursor = np.array([0, len(queens), 0, 0], np.int64)  # head, size, seed, updated
        seeds = np.argsort(-peak, kind="stable")
        scale = p.weight_scale if p.neighbour_weights == "updated" else 0.0
        args = (lik, gxf, gyf, pred, prev, ws_self, indptr, nbr, wts, scale)
        args += (self.queens, seeds, sig2)
        state = (new, conf, tau, updated, queued, visits, used_flow, order, queue, cursor)
        while True:
            i = _propagate(*args, bool(p.use_flow), flow_done, flow_cell, flow_conf, *state)
            if i < 0:
                break
            flow_priors(np.array([i]))
        order = order[: cursor[3]]
        self._tick("update", t0)

        self.velocity = new - prev
        self.obs = conf
        self.confidence = conf.copy()
        self.update_order = np.asarray(order, np.int64)
        self.delayed = visits - 1
        self.used_flow = used_flow
        self.model.update(frame, np.rint(new).astype(np.int64), conf)
        return new
