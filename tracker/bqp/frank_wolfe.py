"""Frank-Wolfe solvers for the relaxed BQP (paper Sec. 5, Alg. 1 and 2).

One implementation serves four variants, selected by :attr:`FWParams.variant`:

``"plain"``
    Frank-Wolfe (Alg. 1): move towards the toward vertex ``s`` (argmin of the gradient).
``"away"``
    Away-step Frank-Wolfe (Lacoste-Julien & Jaggi 2015, the paper's ref. [42]): take the FW
    step or the away step ``x - y`` (``y`` = argmax of the gradient over the active set),
    whichever has the steeper descent ``-g.d``.
``"swap"``
    FW with SWAP steps (Alg. 2, the paper's method): line-search both the FW step and the
    SWAP (pairwise) step ``s - y`` and take the one with the larger decrease of ``f``
    (``delta_fw`` vs ``delta_swap``: Alg. 2 prints ``max`` of these changes, which are ``<= 0``,
    where its text asks for the best improvement); the SWAP step is clipped at ``alpha_y``
    (SWAP-drop).
``"block"``
    SWAP steps on the chosen block until its gap closes, taken at once (our addition, for
    thousands of targets; the objective, the choice of block and the stopping test are
    Alg. 2's). Where ``Q``'s only entries inside a block are its diagonal, as for the
    tracker's terms (Eq. 9 and 10 link candidates of different targets), ``f`` with the
    other blocks held is a separable quadratic on the block's simplex, and the minimum that
    repeated SWAP steps there approach has a closed form (:func:`_block_minimum`). A step
    then costs the columns of the block's old and new support instead of two, but on a
    packed crowd's frames, whose relaxed optimum lies inside the simplices, SWAP steps
    reach it one pair of candidates at a time: recorded 1,000-target frames took about
    2,000 block steps (10 ms on one thread) against 20,000 SWAP steps (40 ms) to the same
    gap of 0.01. Where a block holds other entries, SWAP steps are taken instead.

Domain and bookkeeping
----------------------
The domain is a product of simplices (one per target, see :class:`tracker.bqp.qp.BlockQP`). A
block's values ``x_b`` are its own barycentric coordinates over the block's vertices, so
the active set ``S`` of Alg. 2 is simply the support of ``x_b`` and ``alpha_y = x_y``; a drop
step sets ``x_y = 0`` exactly. Per block we keep the toward index ``s_b`` (argmin ``g`` in the
block), the away index ``y_b`` (argmax ``g`` over the support), ``g . x_b`` and the block gap
``g . x_b - g_{s_b} >= 0``. The duality gap of the whole problem is the sum of block gaps,
and the solver stops when it is ``<= eps`` (Alg. 2's ``duality gap(z) > eps`` loop test).

Which block moves (our choice, stated because Alg. 2 is written for the whole domain)
---------------------------------------------------------------------------------------
Alg. 2 is written with one toward vertex ``s in D`` for the whole product domain. On a
product of simplices the linear minimisation decouples per block, so a full FW step is the
sum of per-block FW steps sharing one ``lambda``; the SWAP step likewise would need one
``lambda`` clipped by the *smallest* ``alpha_y`` over all blocks, which with a thousand
targets makes almost every SWAP a tiny drop step. We therefore apply Alg. 2 block by block
(block-coordinate Frank-Wolfe, Lacoste-Julien et al. 2013), choosing the block with the
largest block gap (gap-greedy selection, Osokin et al. 2016: the stopping test is the sum
of block gaps, and a block's gap bounds the decrease a step there can make). Each iteration
then changes at most the support of one block (SWAP: exactly two coordinates), so keeping
``g = c + 2Qx`` current is a rank-2 (SWAP) or support-sized (FW, away, block) column update
of the CSC matrix. The cost of an iteration is O(nnz of the touched columns): the statistics
of the other blocks those columns reach are updated per touched row, and a block is rescanned
(O(its size)) only when its toward or away vertex got worse; plus O(log n) per reached
block for the max-gap tree. ``iterations`` counts block steps, for every variant alike, so
Fig. 13-style comparisons are like for like.

Line search (Eq. 13) is exact: ``f(x + lam d) = f(x) + lam g.d + lam^2 d^T Q d``, so
``lam = -g.d / (2 d^T Q d)`` clipped to ``[0, lam_max]``; ``lam_max`` is 1 for FW steps,
``alpha_y / (1 - alpha_y)`` for away steps and ``alpha_y`` for SWAP steps (Alg. 2 prints
``max(lambda_swap, alpha_y)``; staying in D needs the min). ``d^T Q d`` needs only the
block's own entries of ``Q``: ``Q_ss, Q_sy, Q_yy`` and ``Q x_b`` on the block's rows. They are
gathered once per solve into a compact block-diagonal copy (a binary search per column, as
the rows of a CSC column are sorted), so line searches never touch the big arrays.

Rounding (Eq. 14) is the argmax of ``x`` within each block.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from crowdsim.checks import require_choice, require_number
from tracker.bqp.qp import BlockQP

VARIANTS: tuple[str, ...] = ("plain", "away", "swap", "block")
_VARIANT_CODE = {name: i for i, name in enumerate(VARIANTS)}
_PLAIN, _AWAY, _SWAP, _BLOCK = 0, 1, 2, 3
STALL_RTOL: float = 1e-13
"""A largest block gap below this times the size of the gradient entries it is computed
from is round-off: the solver stops (``converged`` then says whether ``eps`` was met)."""
SPLIT_MAX_SHARE: float = 0.9
""":func:`solve` with ``components`` solves the components apart only when the largest holds
less than this share of the blocks; otherwise one problem (the permutation would cost more
than the threads gain)."""


def solved_apart(sizes: np.ndarray, share: float = SPLIT_MAX_SHARE) -> bool:
    """Whether components of these ``sizes`` (blocks each) are solved apart: the largest
    holds less than ``share`` of the blocks (the one rule of :func:`solve` and of
    :func:`tracker.bqp.quadratic.quadratic_matrix`'s grouping)."""
    return len(sizes) > 0 and sizes.max() < share * sizes.sum()


STEP_KINDS: tuple[str, ...] = ("fw", "away", "swap", "drop", "block")
"""Kinds counted in :attr:`FWResult.steps` (``drop``: away/SWAP steps that emptied ``alpha_y``;
``block``: the ``"block"`` variant's steps to a block's minimum)."""
_N_KINDS = len(STEP_KINDS)


@dataclass(frozen=True, kw_only=True)
class FWParams:
    """Parameters of the Frank-Wolfe solver (paper Sec. 5, Alg. 2).

    Attributes
    ----------
    variant : {"plain", "away", "swap", "block"}
        Plain FW (Alg. 1), away-step FW (ref. [42]), FW with SWAP steps (Alg. 2), or SWAP
        steps on the chosen block until its gap closes, in closed form (see the module).
    eps : float
        Duality-gap stopping threshold ``epsilon`` of Alg. 2 (absolute, objective units;
        the gap bounds ``f(x) - f*``). The paper uses 0.01 when tracking.
    max_iter : int
        Maximum number of iterations, counted in block steps (see the module docstring).
        Dense 1,000-target frames need about 25 steps per target at ``eps = 0.01`` with
        SWAP steps (30 with away steps, ~600 plain), so the default 10,000 suits up to a few
        hundred targets; pass about ``50 * n`` for larger frames.
    record_history : bool
        Keep the objective and the duality gap after every iteration (for plots); costs
        two ``(max_iter + 1,)`` float arrays.
    """

    variant: str = "swap"
    eps: float = 0.01
    max_iter: int = 10_000
    record_history: bool = False

    def __post_init__(self) -> None:
        require_choice("FWParams", "variant", self.variant, VARIANTS)
        require_number("FWParams", "eps", self.eps, lo=0)
        require_number("FWParams", "max_iter", self.max_iter, lo=0, integer=True)


@dataclass
class FWResult:
    """Output of :func:`solve`.

    Attributes
    ----------
    x : (l,) float64
        Relaxed solution, in the product of simplices.
    choice : (n,) int64
        Rounded assignment (Eq. 14): per block the local index of the largest ``x``.
    objective : float
        ``f(x)`` of the relaxed solution.
    rounded_objective : float
        ``f`` at the one-hot vertex of ``choice``.
    gap : float
        Duality gap ``sum_b (g.x_b - min_b g)`` at ``x`` (upper bound on ``f(x) - f*``).
    iterations : int
        Block steps taken.
    converged : bool
        ``gap <= eps`` was reached (else ``max_iter`` stopped the solver).
    history : (iterations + 1,) float64 or None
        ``f`` after each iteration (index 0: the start), if ``record_history``.
    gap_history : (iterations + 1,) float64 or None
        Duality gap after each iteration (tracked incrementally), if ``record_history``.
    steps : dict[str, int]
        Count of FW, away, SWAP and drop steps.
    """

    x: np.ndarray
    choice: np.ndarray
    objective: float
    rounded_objective: float
    gap: float
    iterations: int
    converged: bool
    history: np.ndarray | None = None
    gap_history: np.ndarray | None = None
    steps: dict[str, int] = field(default_factory=dict)


# --------------------------------------------------------------------------- numba kernels
@njit(cache=True)
def _block_argext(v, block_ptr, want_max):
    """Per block, local index of the min (or max) of ``v`` (first on ties)."""
    n = block_ptr.shape[0] - 1
    out = np.empty(n, dtype=np.int64)
    for b in range(n):
        lo = block_ptr[b]
        best = v[lo]
        arg = 0
        for j in range(lo + 1, block_ptr[b + 1]):
            if (v[j] > best) if want_max else (v[j] < best):
                best = v[j]
                arg = j - lo
        out[b] = arg
    return out


@njit(cache=True)
def _tree_update(tree, size, i, v):
    """Set leaf ``i`` of the max-tree to ``v`` and repair its ancestors, stopping at the
    first one whose maximum did not change (the ones above it cannot change either)."""
    node = size + i
    tree[node] = v
    node //= 2
    while node >= 1:
        a = tree[2 * node]
        b = tree[2 * node + 1]
        m = a if a >= b else b
        if tree[node] == m:
            break
        tree[node] = m
        node //= 2


@njit(cache=True)
def _tree_argmax(tree, size):
    node = 1
    while node < size:
        node = 2 * node if tree[2 * node] >= tree[2 * node + 1] else 2 * node + 1
    return node - size


@njit(cache=True)
def _refresh_block(b, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size):
    """Recompute toward/away indices, ``g.x_b`` and the block gap; return the gap change."""
    lo = block_ptr[b]
    hi = block_ptr[b + 1]
    gmin = np.inf
    gmax = -np.inf
    smin = lo
    ymax = lo
    gxs = 0.0
    for j in range(lo, hi):
        gj = g[j]
        if gj < gmin:
            gmin = gj
            smin = j
        xj = x[j]
        if xj > 0.0:
            gxs += gj * xj
            if gj > gmax:
                gmax = gj
                ymax = j
    gap = gxs - gmin
    if gap < 0.0:
        gap = 0.0
    change = gap - gaps[b]
    gaps[b] = gap
    s_idx[b] = smin
    y_idx[b] = ymax
    gx[b] = gxs
    _tree_update(tree, size, b, gap)
    return change


@njit(cache=True)
def _rebuild(indptr, indices, data, c, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size):
    """Exact ``g = c + 2Qx`` and all block statistics from scratch; return the total gap."""
    l = c.shape[0]
    for i in range(l):
        g[i] = c[i]
    for j in range(l):
        xj = x[j]
        if xj != 0.0:
            for p in range(indptr[j], indptr[j + 1]):
                g[indices[p]] += 2.0 * data[p] * xj
    total = 0.0
    for b in range(block_ptr.shape[0] - 1):
        gaps[b] = 0.0
        total += _refresh_block(b, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size)
    return total


@njit(cache=True)
def _lower_bound(indices, start, end, value):
    """First position in the sorted ``indices[start:end]`` holding a row ``>= value``."""
    while start < end:
        mid = (start + end) // 2
        if indices[mid] < value:
            start = mid + 1
        else:
            end = mid
    return start


@njit(cache=True)
def _intra_block(indptr, indices, data, block_ptr, block_of):
    """The block-diagonal part of ``Q`` as a compact CSC with block-local row indices.

    The line searches only need ``Q``'s entries inside the stepped block; gathering them
    once (a binary search per column, O(l log)) keeps the hot loop away from the big
    arrays, where every lookup would be a cache miss.
    """
    l = indptr.shape[0] - 1
    ptr = np.zeros(l + 1, dtype=np.int64)
    cap = 2 * l + 16
    rows = np.empty(cap, dtype=np.int64)
    vals = np.empty(cap)
    m = 0
    for j in range(l):
        b = block_of[j]
        lo = block_ptr[b]
        hi = block_ptr[b + 1]
        end = indptr[j + 1]
        p = _lower_bound(indices, indptr[j], end, lo)
        while p < end and indices[p] < hi:
            if m == cap:
                cap *= 2
                nr = np.empty(cap, dtype=np.int64)
                nv = np.empty(cap)
                nr[:m] = rows[:m]
                nv[:m] = vals[:m]
                rows = nr
                vals = nv
            rows[m] = indices[p] - lo
            vals[m] = data[p]
            m += 1
            p += 1
        ptr[j + 1] = m
    return ptr, rows[:m], vals[:m]


@njit(cache=True)
def _intra_diagonal(diagonal, block_ptr, block_of):
    """:func:`_intra_block`'s arrays where ``Q``'s only entries inside a block are its
    diagonal (``diagonal``, stored where it is not 0): O(l), no search of the columns."""
    l = diagonal.shape[0]
    ptr = np.zeros(l + 1, dtype=np.int64)
    rows = np.empty(l, dtype=np.int64)
    vals = np.empty(l)
    m = 0
    for j in range(l):
        if diagonal[j] != 0.0:
            rows[m] = j - block_ptr[block_of[j]]
            vals[m] = diagonal[j]
            m += 1
        ptr[j + 1] = m
    return ptr, rows[:m], vals[:m]


def _intra(indptr, indices, data, block_ptr, block_of, diagonal):
    """The blocks' own entries of the CSC ``Q``: from its ``diagonal`` when that is all
    there is inside a block (:attr:`BlockQP.diagonal`; the search of :func:`_intra_block`
    took 10 ms a frame at 7,800 targets), else gathered (``diagonal`` None)."""
    if diagonal is None:
        return _intra_block(indptr, indices, data, block_ptr, block_of)
    return _intra_diagonal(diagonal, block_ptr, block_of)


@njit(cache=True)
def _intra_entry(ptr, rows, vals, col, local_row):
    """``Q[lo + local_row, col]`` from the block-diagonal part (columns are tiny)."""
    for q in range(ptr[col], ptr[col + 1]):
        if rows[q] == local_row:
            return vals[q]
    return 0.0


@njit(cache=True)
def _line_search(gd, dqd, lam_max):
    """Exact line search of Eq. 13 on ``f(x + lam d)``; returns ``(lam, f change)``."""
    if gd >= 0.0 or lam_max <= 0.0:
        return 0.0, 0.0
    if dqd > 0.0:
        lam = -gd / (2.0 * dqd)
        if lam > lam_max:
            lam = lam_max
    else:
        lam = lam_max
    return lam, lam * gd + lam * lam * dqd


@njit(cache=True)
def _block_minimum(g, x, diag, lo, k, h, order, xn):
    """The exact minimiser ``xn[:k]`` of ``f`` over the simplex of the block ``lo:lo + k``,
    the other blocks held, where ``Q``'s only entries inside the block are its diagonal
    ``diag[lo:lo + k] >= 0``; returns the change of ``f``.

    Held, the block's part of ``f`` is ``sum_a h_a z_a + d_a z_a^2`` with ``h = g - 2 d x``
    (``g = c + 2Qx``): separable. Its KKT conditions give ``z_a = max(0, (lam - h_a) /
    (2 d_a))`` where ``d_a > 0``, with ``lam`` where the ``z`` sum to 1 (found over the
    ``h_a`` in ascending order). A candidate with ``d_a = 0`` holds mass only at ``h_a =
    lam``: ``lam`` is at most the least such ``h_a``, and that candidate (the first on ties)
    takes what the others leave. ``h`` and ``order`` are scratch arrays of ``k`` or more.
    """
    m0 = np.inf  # the least h over the candidates with d = 0
    a0 = -1
    npos = 0
    for i in range(k):
        d = diag[lo + i]
        h[i] = g[lo + i] - 2.0 * d * x[lo + i]
        if d > 0.0:
            p = npos  # insertion sort by h (k is a few dozen at most)
            while p > 0 and h[order[p - 1]] > h[i]:
                order[p] = order[p - 1]
                p -= 1
            order[p] = i
            npos += 1
        elif h[i] < m0:
            m0 = h[i]
            a0 = i
    lam = m0
    sa = 0.0  # sum of 1 / 2d over the active candidates
    sb = 0.0  # sum of h / 2d
    for p in range(npos):
        i = order[p]
        if h[i] >= lam:
            break
        sa += 0.5 / diag[lo + i]
        sb += 0.5 * h[i] / diag[lo + i]
        cand = (1.0 + sb) / sa  # lam where these candidates' z sum to 1
        nxt = h[order[p + 1]] if p + 1 < npos else np.inf
        if cand <= nxt and cand <= m0:
            lam = cand
            break
    rest = 1.0
    df = 0.0
    for i in range(k):
        d = diag[lo + i]
        z = 0.0
        if d > 0.0 and lam > h[i]:
            z = (lam - h[i]) / (2.0 * d)
            rest -= z
        xn[i] = z
    if a0 >= 0 and rest > 0.0:
        xn[a0] = rest
    for i in range(k):
        xo = x[lo + i]
        df += h[i] * (xn[i] - xo) + diag[lo + i] * (xn[i] * xn[i] - xo * xo)
    return df


@njit(cache=True)
def _vertex_objective(indptr, indices, data, c, block_ptr, choice):
    """``f`` at the one-hot vertex of ``choice``: O(nnz of the chosen columns)."""
    l = c.shape[0]
    chosen = np.zeros(l, dtype=np.bool_)
    n = block_ptr.shape[0] - 1
    for b in range(n):
        chosen[block_ptr[b] + choice[b]] = True
    f = 0.0
    for b in range(n):
        j = block_ptr[b] + choice[b]
        f += c[j]
        for p in range(indptr[j], indptr[j + 1]):
            if chosen[indices[p]]:
                f += data[p]
    return f


@njit(cache=True)
def _fw_loop(
    indptr,
    indices,
    data,
    in_ptr,
    in_rows,
    in_vals,
    c,
    block_ptr,
    block_of,
    x,
    variant,
    eps,
    max_iter,
    hist_f,
    hist_gap,
):
    """The shared FW / away / SWAP loop; ``x`` is updated in place. ``in_*`` are the blocks'
    own entries of ``Q`` (:func:`_intra_block`).

    Returns ``(iterations, converged, gap, f(x), counts)`` with ``gap`` and ``f`` computed
    from an exact (not incrementally updated) gradient.
    """
    l = c.shape[0]
    n = block_ptr.shape[0] - 1
    kmax = 0
    for b in range(n):
        kb = block_ptr[b + 1] - block_ptr[b]
        if kb > kmax:
            kmax = kb
    size = 1
    while size < n:
        size *= 2
    tree = np.full(2 * size, -1.0)
    g = np.empty(l)
    s_idx = np.empty(n, dtype=np.int64)
    y_idx = np.empty(n, dtype=np.int64)
    gx = np.empty(n)
    gaps = np.zeros(n)
    stamp = np.full(n, -1, dtype=np.int64)
    rescan = np.zeros(n, dtype=np.bool_)
    dirty = np.empty(n, dtype=np.int64)
    w = np.empty(kmax)
    xn = np.empty(kmax)
    counts = np.zeros(_N_KINDS, dtype=np.int64)
    record = hist_f.shape[0] > 0
    # the exact block step needs Q's entries inside every block to be its diagonal alone,
    # and that diagonal >= 0 (as a PSD Q's is); otherwise the variant takes SWAP steps
    exact = variant == _BLOCK
    qdiag = np.zeros(l if exact else 0)
    if exact:
        for j in range(l):
            lo_j = block_ptr[block_of[j]]
            for q in range(in_ptr[j], in_ptr[j + 1]):
                if in_rows[q] != j - lo_j or in_vals[q] < 0.0:
                    exact = False
                qdiag[j] = in_vals[q]
        if not exact:
            variant = _SWAP
    order = np.empty(kmax, dtype=np.int64)

    total = _rebuild(indptr, indices, data, c, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size)
    fresh = True
    f = 0.0
    for j in range(l):
        f += 0.5 * (c[j] + g[j]) * x[j]  # f = c.x + x'Qx = (c.x + g.x) / 2
    if record:
        hist_f[0] = f
        hist_gap[0] = total
    it = 0
    converged = False
    while True:
        if total <= eps:
            # The incrementally kept gradient drifts; confirm on exact values before stopping.
            if not fresh:
                total = _rebuild(
                    indptr, indices, data, c, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size
                )
                fresh = True
            if total <= eps:
                converged = True
                break
        if it >= max_iter:
            break
        b = _tree_argmax(tree, size)
        lo = block_ptr[b]
        hi = block_ptr[b + 1]
        k = hi - lo
        s = s_idx[b]
        y = y_idx[b]
        gs = g[s]
        gy = g[y]
        gxb = gx[b]

        moved = True
        lam = 0.0
        if exact:
            # the block's minimum with the others held, in closed form (see _block_minimum)
            delta = _block_minimum(g, x, qdiag, lo, k, w, order, xn)
            moved = False
            for i in range(k):
                if xn[i] != x[lo + i]:
                    moved = True
        else:
            # w = (Q x_b) on the block's own rows: only the block-diagonal part of Q is needed.
            for i in range(k):
                w[i] = 0.0
            for j in range(lo, hi):
                xj = x[j]
                if xj != 0.0:
                    for q in range(in_ptr[j], in_ptr[j + 1]):
                        w[in_rows[q]] += in_vals[q] * xj
            xqx = 0.0
            for i in range(k):
                xqx += x[lo + i] * w[i]
            q_ss = _intra_entry(in_ptr, in_rows, in_vals, s, s - lo)

            # FW (toward) step, d = e_s - x_b: g.d = -(block gap); d'Qd from w (Eq. 13).
            gd_fw = gs - gxb
            lam, delta = _line_search(gd_fw, q_ss - 2.0 * w[s - lo] + xqx, 1.0)
            mode = 0
            alpha_y = x[y]
            lam_cap = 1.0
            if variant == _AWAY and alpha_y < 1.0:
                # Away step d = x_b - e_y, taken when it is the steeper descent direction.
                gd_aw = gxb - gy
                if -gd_aw > -gd_fw:
                    q_yy = _intra_entry(in_ptr, in_rows, in_vals, y, y - lo)
                    lam_cap = alpha_y / (1.0 - alpha_y)
                    lam, delta = _line_search(gd_aw, xqx - 2.0 * w[y - lo] + q_yy, lam_cap)
                    mode = 1
            elif variant == _SWAP and s != y:
                # SWAP step d = e_s - e_y (Alg. 2): keep whichever of FW/SWAP decreases f more.
                q_yy = _intra_entry(in_ptr, in_rows, in_vals, y, y - lo)
                q_sy = _intra_entry(in_ptr, in_rows, in_vals, y, s - lo)
                lam_sw, delta_sw = _line_search(gs - gy, q_ss + q_yy - 2.0 * q_sy, alpha_y)
                if delta_sw < delta:
                    lam = lam_sw
                    delta = delta_sw
                    lam_cap = alpha_y
                    mode = 2
        stalled = not moved if exact else lam <= 0.0
        if stalled or gxb - gs <= STALL_RTOL * (abs(gs) + abs(gxb)):
            # No decrease left above round-off (reachable with eps ~ 0): refresh the exact
            # statistics once, then stop rather than spin until max_iter.
            if fresh:
                break
            total = _rebuild(
                indptr, indices, data, c, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size
            )
            fresh = True
            continue

        if exact:
            counts[4] += 1
        else:
            # New block values; drop steps set alpha_y to exactly 0 (active-set removal).
            if mode == 0:
                if lam >= 1.0:
                    for i in range(k):
                        xn[i] = 0.0
                    xn[s - lo] = 1.0
                else:
                    for i in range(k):
                        xn[i] = (1.0 - lam) * x[lo + i]
                    xn[s - lo] += lam
                counts[0] += 1
            elif mode == 1:
                for i in range(k):
                    xn[i] = (1.0 + lam) * x[lo + i]
                if lam >= lam_cap:
                    xn[y - lo] = 0.0
                    counts[3] += 1
                else:
                    xn[y - lo] -= lam
                counts[1] += 1
            else:
                for i in range(k):
                    xn[i] = x[lo + i]
                if lam >= lam_cap:
                    xn[s - lo] += alpha_y
                    xn[y - lo] = 0.0
                    counts[3] += 1
                else:
                    xn[s - lo] += lam
                    xn[y - lo] -= lam
                counts[2] += 1

        # g += 2 Q dx over the changed columns (rank-2 for a SWAP step). The statistics of
        # the other blocks these columns reach are updated per touched row; a block is
        # rescanned only if its argmin (or away vertex) got worse.
        it += 1
        stamp[b] = it
        rescan[b] = True
        nd = 1
        dirty[0] = b
        for i in range(k):
            j = lo + i
            dxj = xn[i] - x[j]
            if dxj == 0.0:
                continue
            x[j] = xn[i]
            for p in range(indptr[j], indptr[j + 1]):
                r = indices[p]
                dg = 2.0 * data[p] * dxj
                g[r] += dg
                a = block_of[r]
                if stamp[a] != it:
                    stamp[a] = it
                    rescan[a] = False
                    dirty[nd] = a
                    nd += 1
                if rescan[a]:
                    continue
                xr = x[r]
                gr = g[r]
                sa = s_idx[a]
                if r == sa:
                    if dg > 0.0:
                        rescan[a] = True
                        continue
                elif gr < g[sa]:
                    s_idx[a] = r
                if xr > 0.0:
                    gx[a] += dg * xr
                    ya = y_idx[a]
                    if r == ya:
                        if dg < 0.0:
                            rescan[a] = True
                    elif gr > g[ya]:
                        y_idx[a] = r
        for t in range(nd):
            a = dirty[t]
            if rescan[a]:
                total += _refresh_block(a, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size)
            else:
                gap = gx[a] - g[s_idx[a]]
                if gap < 0.0:
                    gap = 0.0
                total += gap - gaps[a]
                gaps[a] = gap
                _tree_update(tree, size, a, gap)
        if total < 0.0:
            total = 0.0
        fresh = False
        f += delta
        if record:
            hist_f[it] = f
            hist_gap[it] = total

    if not fresh:
        total = _rebuild(
            indptr, indices, data, c, x, g, block_ptr, s_idx, y_idx, gx, gaps, tree, size
        )
        converged = total <= eps
    f = 0.0
    for j in range(l):
        f += 0.5 * (c[j] + g[j]) * x[j]
    return it, converged, total, f, counts


# ------------------------------------------------------------------ independent components
@njit(cache=True, nogil=True, parallel=True)
def _permute_csc(indptr, indices, data, var_order, var_rank, new_indptr, new_indices, new_data):
    """``Q[var_order][:, var_order]`` where the order keeps each component's variables in
    their original order: every column's rows stay in one component, so the renamed rows of
    a sorted column are still sorted. One column per loop iteration."""
    for jn in prange(var_order.shape[0]):
        j = var_order[jn]
        q = new_indptr[jn]
        for p in range(indptr[j], indptr[j + 1]):
            new_indices[q] = var_rank[indices[p]]
            new_data[q] = data[p]
            q += 1


@njit(cache=True, nogil=True)
def _linear_gap(c, block_ptr, x, b0, b1):
    """Duality gap and ``f`` of blocks ``b0:b1`` where ``Q`` has no entry (``g = c``), summed
    as :func:`_rebuild` and :func:`_fw_loop` sum them (so a component that needs no step
    gets the same figures as from the loop)."""
    total = 0.0
    for b in range(b0, b1):
        gmin = np.inf
        gxs = 0.0
        for j in range(block_ptr[b], block_ptr[b + 1]):
            gmin = min(gmin, c[j])
            if x[j] > 0.0:
                gxs += c[j] * x[j]
        total += max(gxs - gmin, 0.0)
    f = 0.0
    for j in range(block_ptr[b0], block_ptr[b1]):
        f += 0.5 * (c[j] + c[j]) * x[j]
    return total, f


@njit(cache=True, nogil=True, parallel=True)
def _fw_components(
    indptr,
    indices,
    data,
    in_ptr,
    in_rows,
    in_vals,
    c,
    block_ptr,
    x,
    variant,
    eps,
    max_iter,
    comp_ptr,
    out_it,
    out_conv,
    out_gap,
    out_f,
    out_counts,
):
    """Frank-Wolfe on each component (blocks ``comp_ptr[i]:comp_ptr[i + 1]``, contiguous
    with its variables) on its own, one component per loop iteration.

    A component of ``n_i`` of the ``n`` blocks stops at gap ``eps n_i / n`` or after
    ``ceil(max_iter n_i / n)`` block steps: the gaps then sum to ``eps`` at most, the
    stopping test of the whole problem, and no stopping rule depends on another component
    (so the result does not depend on the number of threads).
    """
    n = block_ptr.shape[0] - 1
    for ci in prange(comp_ptr.shape[0] - 1):
        b0 = comp_ptr[ci]
        b1 = comp_ptr[ci + 1]
        v0 = block_ptr[b0]
        v1 = block_ptr[b1]
        e0 = indptr[v0]
        e1 = indptr[v1]
        if e1 == e0:
            # no quadratic entry (a lone target): a linear problem, usually solved at the
            # start already; then _fw_loop's answer without its set-up
            gap, f = _linear_gap(c, block_ptr, x, b0, b1)
            if gap <= eps * (b1 - b0) / n:
                out_it[ci] = 0
                out_conv[ci] = True
                out_gap[ci] = gap
                out_f[ci] = f
                for s in range(_N_KINDS):
                    out_counts[ci, s] = 0
                continue
        sub_indptr = indptr[v0 : v1 + 1] - e0
        sub_indices = indices[e0:e1] - v0
        sub_bp = block_ptr[b0 : b1 + 1] - v0
        nb = b1 - b0
        sub_of = np.empty(v1 - v0, np.int64)
        for b in range(nb):
            for j in range(sub_bp[b], sub_bp[b + 1]):
                sub_of[j] = b
        none = np.zeros(0)
        i0 = in_ptr[v0]
        i1 = in_ptr[v1]
        it, conv, gap, f, counts = _fw_loop(
            sub_indptr,
            sub_indices,
            data[e0:e1],
            in_ptr[v0 : v1 + 1] - i0,
            in_rows[i0:i1],
            in_vals[i0:i1],
            c[v0:v1],
            sub_bp,
            sub_of,
            x[v0:v1],
            variant,
            eps * nb / n,
            (max_iter * nb + n - 1) // n,
            none,
            none,
        )
        out_it[ci] = it
        out_conv[ci] = conv
        out_gap[ci] = gap
        out_f[ci] = f
        for s in range(_N_KINDS):
            out_counts[ci, s] = counts[s]


# --------------------------------------------------------------------------------- public
def default_start(qp: BlockQP) -> np.ndarray:
    """Per block the vertex with the smallest linear cost ``c`` (ties: first)."""
    if qp.n_blocks == 0:
        return np.zeros(0)
    return qp.vertex(_block_argext(qp.c, qp.block_ptr, False))


def round_choice(qp: BlockQP, x: np.ndarray) -> np.ndarray:
    """Rounding of Eq. 14: (n,) int64 local argmax of ``x`` per block."""
    if qp.n_blocks == 0:
        return np.zeros(0, dtype=np.int64)
    return _block_argext(np.ascontiguousarray(x, dtype=np.float64), qp.block_ptr, True)


def solve(
    qp: BlockQP,
    x0: np.ndarray | None = None,
    params: FWParams | None = None,
    components: np.ndarray | None = None,
) -> FWResult:
    """Minimise ``qp`` over its product of simplices with Frank-Wolfe (plain/away/SWAP).

    Parameters
    ----------
    qp : BlockQP
        The relaxed problem (``Q`` PSD is the caller's guarantee).
    x0 : (l,) float, optional
        Feasible start (``>= 0``, sums to 1 per block up to 1e-8 per entry). Default: per
        block the vertex with the smallest linear cost.
    params : FWParams, optional
        Variant, ``eps``, ``max_iter``; default ``FWParams()`` (SWAP, eps 0.01).
    components : (n,) int, optional
        A label per block such that ``Q`` has no entry between blocks of different labels
        (:func:`tracker.bqp.quadratic.quadratic_matrix` with ``components=True``). The
        components are then independent problems: when the largest holds less than
        :data:`SPLIT_MAX_SHARE` of the blocks they are solved apart, in parallel on numba's
        threads, each with its share of ``eps`` and ``max_iter`` (the gaps still sum to at
        most ``eps``). The result does not depend on the number of threads. Where the labels
        are non-decreasing (the blocks already grouped by component, as ``quadratic_matrix``
        builds them with ``split_share``) the components are solved in place, with no
        permuted copy of ``Q``. Ignored with ``record_history``.

    Returns
    -------
    FWResult

    Raises
    ------
    ValueError
        If ``x0`` has the wrong shape or is infeasible (the message names ``x0``).
    """
    if params is None:
        params = FWParams()
    if not isinstance(qp, BlockQP):
        raise ValueError(f"qp must be a BlockQP, got {type(qp).__name__}")
    x = default_start(qp) if x0 is None else qp.check_feasible(x0, name="x0")
    n = qp.n_blocks
    if n == 0:
        hist = np.zeros(1) if params.record_history else None
        return FWResult(
            x=x,
            choice=np.zeros(0, dtype=np.int64),
            objective=0.0,
            rounded_objective=0.0,
            gap=0.0,
            iterations=0,
            converged=True,
            history=hist,
            gap_history=None if hist is None else hist.copy(),
            steps=dict.fromkeys(STEP_KINDS, 0),
        )
    if components is not None and not params.record_history:
        split = _solve_split(qp, x, params, components)
        if split is not None:
            return split
    m = params.max_iter + 1 if params.record_history else 0
    hist_f = np.zeros(m)
    hist_gap = np.zeros(m)
    Q = qp.Q
    it, converged, gap, f, counts = _fw_loop(
        Q.indptr,
        Q.indices,
        Q.data,
        *_intra(Q.indptr, Q.indices, Q.data, qp.block_ptr, qp.block_of, qp.diagonal),
        qp.c,
        qp.block_ptr,
        qp.block_of,
        x,
        _VARIANT_CODE[params.variant],
        float(params.eps),
        int(params.max_iter),
        hist_f,
        hist_gap,
    )
    return _result(
        qp,
        x,
        f,
        gap,
        it,
        converged,
        counts,
        history=hist_f[: it + 1].copy() if params.record_history else None,
        gap_history=hist_gap[: it + 1].copy() if params.record_history else None,
    )


def _result(
    qp: BlockQP,
    x: np.ndarray,
    objective: float,
    gap: float,
    iterations: int,
    converged: bool,
    counts: np.ndarray,
    history: np.ndarray | None = None,
    gap_history: np.ndarray | None = None,
) -> FWResult:
    """The :class:`FWResult` of a solved ``x``: its rounding (Eq. 14) and that vertex's ``f``."""
    Q = qp.Q
    choice = _block_argext(x, qp.block_ptr, True)
    return FWResult(
        x=x,
        choice=choice,
        objective=float(objective),
        rounded_objective=float(
            _vertex_objective(Q.indptr, Q.indices, Q.data, qp.c, qp.block_ptr, choice)
        ),
        gap=float(gap),
        iterations=int(iterations),
        converged=bool(converged),
        history=history,
        gap_history=gap_history,
        steps=dict(zip(STEP_KINDS, (int(v) for v in counts), strict=True)),
    )


def _solve_split(
    qp: BlockQP, x: np.ndarray, params: FWParams, components: np.ndarray
) -> FWResult | None:
    """:func:`solve` component by component; ``None`` when one component dominates."""
    n = qp.n_blocks
    labels = np.asarray(components)
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(
            f"components must be ({n},) integer labels, one per block, got "
            f"shape {labels.shape} dtype {labels.dtype}"
        )
    # already grouped (quadratic_matrix with split_share): the components are slices
    grouped = bool((labels[1:] >= labels[:-1]).all())
    if grouped:
        sizes = np.diff(np.flatnonzero(np.r_[True, labels[1:] != labels[:-1], True]))
    else:
        _, labels, sizes = np.unique(labels, return_inverse=True, return_counts=True)
    if not solved_apart(sizes):
        return None
    comp_ptr = np.zeros(len(sizes) + 1, np.int64)
    np.cumsum(sizes, out=comp_ptr[1:])
    Q = qp.Q
    if grouped:
        it, conv, gap, f, counts = _run_components(
            Q.indptr,
            Q.indices,
            Q.data,
            qp.c,
            qp.block_ptr,
            qp.block_of,
            qp.diagonal,
            x,
            params,
            comp_ptr,
        )
        return _result(qp, x, f, gap, it, conv, counts)
    # blocks grouped by component, each component's blocks (and variables) in their order
    block_order = np.argsort(labels, kind="stable")
    bsizes = qp.block_sizes[block_order]
    new_bp = np.zeros(n + 1, np.int64)
    np.cumsum(bsizes, out=new_bp[1:])
    starts = qp.block_ptr[:-1][block_order]
    var_order = np.repeat(starts - new_bp[:-1], bsizes) + np.arange(qp.n_vars)
    var_rank = np.empty_like(var_order)
    var_rank[var_order] = np.arange(qp.n_vars)
    col_nnz = np.diff(Q.indptr)[var_order]
    new_indptr = np.zeros(qp.n_vars + 1, np.int64)
    np.cumsum(col_nnz, out=new_indptr[1:])
    new_indices = np.empty(Q.nnz, np.int64)
    new_data = np.empty(Q.nnz)
    _permute_csc(
        Q.indptr, Q.indices, Q.data, var_order, var_rank, new_indptr, new_indices, new_data
    )
    xp = np.ascontiguousarray(x[var_order])
    it, conv, gap, f, counts = _run_components(
        new_indptr,
        new_indices,
        new_data,
        np.ascontiguousarray(qp.c[var_order]),
        new_bp,
        np.repeat(np.arange(n, dtype=np.int64), bsizes),
        None if qp.diagonal is None else np.ascontiguousarray(qp.diagonal[var_order]),
        xp,
        params,
        comp_ptr,
    )
    x = np.empty_like(xp)
    x[var_order] = xp
    return _result(qp, x, f, gap, it, conv, counts)


def _run_components(indptr, indices, data, c, block_ptr, block_of, diagonal, x, params, comp_ptr):
    """:func:`_fw_components` on a problem whose components are the block slices of
    ``comp_ptr`` (``diagonal``: see :func:`_intra`); ``x`` is solved in place. Returns the
    sums ``(iterations, converged, gap, f, counts)`` over the components."""
    nc = len(comp_ptr) - 1
    out_it = np.zeros(nc, np.int64)
    out_conv = np.zeros(nc, np.bool_)
    out_gap = np.zeros(nc)
    out_f = np.zeros(nc)
    out_counts = np.zeros((nc, _N_KINDS), np.int64)
    _fw_components(
        indptr,
        indices,
        data,
        *_intra(indptr, indices, data, block_ptr, block_of, diagonal),
        c,
        block_ptr,
        x,
        _VARIANT_CODE[params.variant],
        float(params.eps),
        int(params.max_iter),
        comp_ptr,
        out_it,
        out_conv,
        out_gap,
        out_f,
        out_counts,
    )
    return out_it.sum(), out_conv.all(), out_gap.sum(), out_f.sum(), out_counts.sum(axis=0)
