"""Quadratic terms of the BQP objective (paper 1, Eq. 9-10): sparse ``(l, l)`` CSC matrices over
the ``l = n k`` candidates.

* :func:`proximity_matrix` -- spatial proximity, Eq. 9;
* :func:`grouping_matrix` -- grouping, Eq. 10 (along the trees of
  :func:`tracker.bqp.terms.group_trees`);
* :func:`quadratic_matrix` -- their weighted sum, as the tracker builds it each frame.

Both follow the paper's normalised-Laplacian construction on a sparse similarity ``W``
(``D = diag(W 1)``, ``W_hat = D^-1/2 W D^-1/2``). For grouping, ``C_g = I - W_hat`` (Eq. 10's
Laplacian, PSD) rewards co-selecting candidates that keep the group's formation. For
proximity the paper's ``C_sp = I - D^-1/2 S D^-1/2`` would *reward* co-selecting close
candidates of two targets, the opposite of its stated purpose; we use the signless normalised
Laplacian ``C_sp = I + D^-1/2 S D^-1/2 = D^-1/2 (D + S) D^-1/2``, which is PSD as well and
penalises close co-selection. The identity is only put on candidates with at least one
neighbour (``D_ii > 0``), and with the degrees regularised, ``(D + tau I)^-1/2 (D +/- W)
(D + tau I)^-1/2`` (still PSD, so that a weak similarity between two otherwise isolated
candidates stays weak; the tracker uses tau = 1), it becomes ``D / (D + tau)``. So, unlike
the paper's identity on every candidate, it is not a constant on binary points: two targets
on one grouping edge pay 0 for keeping their formation, 1 (tau 0) or 0.5 (tau 1) for
breaking it on one side and 0 for breaking it on both, where the paper's form pays 0, 2, 2
(a departure found by an audit; the README says why it stays the default).
``BQPParams.laplacian_identity = "every"`` gives the paper's binary objective: the tracker
takes this matrix's diagonal off the linear cost.

The matrix is written by compiled kernels, one pass each, with no Python loop over targets:
the linked pairs are counted (:func:`_pair_entries`), their Gaussians evaluated (from tables
on whole pixels, :func:`_gauss_tables`, :func:`_pair_values`), the degrees summed
(:func:`_degrees`) and the canonical CSC filled (:func:`_csc_fill`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit, prange
from scipy.spatial import cKDTree

from crowdsim.checks import require_memory
from tracker.bqp.frank_wolfe import solved_apart
from tracker.threads import in_chunks

MAX_PAIR_TESTS: float = 2e10
"""Most candidate pairs :func:`quadratic_matrix` tests for a link (about a minute on two
cores): 1,000 packed targets with speed-up sampling test about 1e7, dense candidates of a
24 px template about 4e9; dense candidates of a 256 px template, 2e11 for twenty people."""
EXP_PER_THREAD: int = 65_536
"""Off whole pixels, the entries' Gaussians are numpy's ``exp`` in chunks of at least this
many entries on the tracker's threads (:func:`tracker.threads.in_chunks`; element by element,
so the values do not depend on the chunks): 2 ms of a frame on one thread at 7,800 targets.
On whole pixels they come from tables (:func:`_gauss_tables_for`)."""
TABLE_MAX_COORD: float = 2.0**24
"""Candidates on whole pixels below this magnitude make every squared distance an exact
integer, so the pairs' Gaussians come from tables (:func:`_gauss_tables`)."""
LINK_MASK_MAX_K: int = 64
"""Up to this many candidates a target (the bits of a ``uint64``), the counting pass of the
pair entries notes which candidate pairs it linked and the filling pass evaluates only those
(:func:`_pair_entries`); with more, the filling pass scans every pair again."""


@njit(cache=True)
def _pair_exponents(cand, a, i, b, j, flag, rx, ry, mode_g, inv_s, reach2_s, inv_g, reach2_g):
    """The exponents of ``(S, Gamma)`` between candidate ``i`` of target ``a`` and ``j`` of
    target ``b`` (``S = exp`` of the first, ``Gamma = exp`` of the second).

    ``-inf`` (an entry of 0) where the pair is not linked (``flag`` bit 0: proximity, bit 1:
    tree edge) or beyond the cutoff. Grouping compares ``p_a,i - p_b,j`` with ``ref = (rx,
    ry)``: its length (``mode_g`` 1, Eq. 10) or the vector itself (``mode_g`` 2). The ``exp``
    is left to numpy over all entries at once (vectorised; a scalar ``exp`` per entry was
    most of the fill pass).
    """
    dx = cand[a, i, 0] - cand[b, j, 0]
    dy = cand[a, i, 1] - cand[b, j, 1]
    s = -np.inf
    g = -np.inf
    if flag & 1:
        d2 = dx * dx + dy * dy
        if d2 <= reach2_s:
            s = -d2 * inv_s
    if flag & 2:
        if mode_g == 1:
            dev = np.sqrt(dx * dx + dy * dy) - rx
            dev2 = dev * dev
        else:
            ex = dx - rx
            ey = dy - ry
            dev2 = ex * ex + ey * ey
        if dev2 <= reach2_g:
            g = -dev2 * inv_g
    return s, g


@njit(cache=True, nogil=True, inline="always")
def _may_link(dlo, dhi, elo, ehi, flag, rx, ry, mode_g, reach2_s, reach2_g):
    """Whether some ``(dx, dy)`` with ``dx`` in ``[dlo, dhi]`` and ``dy`` in ``[elo, ehi]``
    can give an entry (:func:`_pair_exponents`: a finite ``S`` or ``Gamma`` exponent).

    The intervals bound the differences ``p_a,i - p_b,j`` of one candidate against all of the
    other target's (its candidate box), computed with the same subtractions as the entries:
    rounding is monotone, so every bound below holds for the rounded values too and
    ``False`` is exact (no entry is lost), not an approximation.
    """
    gx = max(0.0, max(dlo, -dhi))  # the smallest |dx|
    gy = max(0.0, max(elo, -ehi))
    if (flag & 1) != 0:
        if gx * gx + gy * gy <= reach2_s:
            return True
    if (flag & 2) != 0:
        if mode_g == 1:
            # |p_i - p_j| - e lies between the box's nearest and farthest distances less e
            mx = max(abs(dlo), abs(dhi))
            my = max(abs(elo), abs(ehi))
            lo = np.sqrt(gx * gx + gy * gy) - rx
            hi = np.sqrt(mx * mx + my * my) - rx
            return not ((lo > 0.0 and lo * lo > reach2_g) or (hi < 0.0 and hi * hi > reach2_g))
        ex = max(0.0, max(dlo - rx, -(dhi - rx)))
        ey = max(0.0, max(elo - ry, -(ehi - ry)))
        return ex * ex + ey * ey <= reach2_g
    return False


@njit(cache=True, nogil=True, parallel=True)
def _pair_entries(
    cand,
    box,
    pa,
    pb,
    flags,
    ref,
    mode_g,
    inv_s,
    reach2_s,
    inv_g,
    reach2_g,
    offsets,
    cand_a,
    cand_b,
    s_out,
    g_out,
    fill,
    links,
):
    """Count (``fill`` False: ``offsets[p + 1]`` = the number of linked candidate pairs of
    target pair ``p``) or write them at ``offsets[p]:offsets[p + 1]``: ``cand_a = i`` and
    ``cand_b = j`` (candidate ``i`` of ``a``, ``j`` of ``b``) in ``(i, j)`` order, and the
    exponents of ``(S, Gamma)`` (Eq. 9, 10; :func:`_pair_exponents`).

    ``links (P, k)`` uint64, when ``k <=`` :data:`LINK_MASK_MAX_K` (else empty): the count
    sets bit ``j`` of ``links[p, i]`` where ``(i, j)`` is linked, and the fill evaluates
    those pairs alone (the same calls, so the same values; at 7,800 targets the fill took
    16 ms when it evaluated every ``(i, j)`` again, 9 with the bits, the count 7.5 -> 9).

    One target pair per loop iteration, each written by one thread: the counts, and so the
    entries' layout, do not depend on the number of threads.
    """
    k = cand.shape[1]
    masked = links.shape[0] > 0
    for p in prange(pa.shape[0]):
        a = pa[p]
        b = pb[p]
        if fill:
            if offsets[p] == offsets[p + 1]:
                continue
        else:
            if masked:
                for i in range(k):
                    links[p, i] = 0
            if flags[p] == 1:
                # proximity only: skip pairs whose candidate boxes are farther apart than reach
                gx = max(0.0, max(box[a, 0] - box[b, 2], box[b, 0] - box[a, 2]))
                gy = max(0.0, max(box[a, 1] - box[b, 3], box[b, 1] - box[a, 3]))
                if gx * gx + gy * gy > reach2_s:
                    offsets[p + 1] = 0
                    continue
        m = offsets[p] if fill else 0
        rx = ref[p, 0]
        ry = ref[p, 1]
        if fill and masked:
            for i in range(k):
                row = links[p, i]
                if row == 0:
                    continue
                for j in range(k):
                    if (row >> np.uint64(j)) & np.uint64(1) == 0:
                        continue
                    s, g = _pair_exponents(
                        cand, a, i, b, j, flags[p], rx, ry, mode_g, inv_s, reach2_s, inv_g, reach2_g
                    )
                    cand_a[m] = i
                    cand_b[m] = j
                    s_out[m] = s
                    g_out[m] = g
                    m += 1
            continue
        # only the candidates of a with b's candidate box in reach are paired (skipping the
        # others' rows halved the counting pass on packed frames)
        rows = np.empty(k, np.bool_)
        for i in range(k):
            xi = cand[a, i, 0]
            yi = cand[a, i, 1]
            rows[i] = _may_link(
                xi - box[b, 2],
                xi - box[b, 0],
                yi - box[b, 3],
                yi - box[b, 1],
                flags[p],
                rx,
                ry,
                mode_g,
                reach2_s,
                reach2_g,
            )
        for i in range(k):
            if not rows[i]:
                continue
            row = np.uint64(0)
            for j in range(k):
                s, g = _pair_exponents(
                    cand,
                    a,
                    i,
                    b,
                    j,
                    flags[p],
                    rx,
                    ry,
                    mode_g,
                    inv_s,
                    reach2_s,
                    inv_g,
                    reach2_g,
                )
                if s > -np.inf or g > -np.inf:
                    if fill:
                        cand_a[m] = i
                        cand_b[m] = j
                        s_out[m] = s
                        g_out[m] = g
                    elif masked:
                        row |= np.uint64(1) << np.uint64(j)
                    m += 1
            if masked and not fill:
                links[p, i] = row
        if not fill:
            offsets[p + 1] = m


@njit(cache=True, nogil=True, parallel=True)
def _gauss_tables(flags, ref, mode_g, inv_s, reach2_s, inv_g, reach2_g, g_box, g_off, s_exp, g_exp):
    """The exponents of :func:`_pair_exponents` at every offset a pair can have when the
    candidates lie on whole pixels: ``s_exp[D]`` for the squared distances ``D = 0 ..
    floor(reach2_s)`` and, per pair ``p`` with a tree edge (``flags`` bit 1), ``g_exp[g_off[p]
    + r]`` over its box ``g_box[p] = (x0, y0, width, height)`` of :func:`_g_boxes` (row ``r``
    of ``D - x0`` for lengths, ``mode_g`` 1; of ``(dy - y0) width + dx - x0`` for offsets).

    Each exponent is computed from the same operands in the same order as
    :func:`_pair_exponents` would compute it from the candidates (``dx dx + dy dy`` is the
    exact integer ``D``), so ``exp`` of the table is the entries' values bit for bit.
    """
    for d in range(s_exp.shape[0]):
        s_exp[d] = -float(d) * inv_s
    for p in prange(flags.shape[0]):
        if flags[p] & 2 == 0:
            continue
        x0, y0, w, h = g_box[p, 0], g_box[p, 1], g_box[p, 2], g_box[p, 3]
        rx = ref[p, 0]
        ry = ref[p, 1]
        for r in range(w * h):
            if mode_g == 1:
                dev = np.sqrt(float(x0 + r)) - rx
                dev2 = dev * dev
            else:
                ex = float(x0 + r % w) - rx
                ey = float(y0 + r // w) - ry
                dev2 = ex * ex + ey * ey
            g_exp[g_off[p] + r] = -dev2 * inv_g if dev2 <= reach2_g else -np.inf


def _gauss_tables_for(
    cand: np.ndarray, flags: np.ndarray, ref: np.ndarray, mode_g: int, gauss: tuple, m: int
) -> tuple | None:
    """``(s_tab, g_box, g_off, g_tab)`` for :func:`_pair_values`: the Gaussians of
    :func:`_gauss_tables`, when the candidates lie on whole pixels (the tracker's grids) and
    the tables hold fewer values than the ``m`` entries; else ``None`` (each entry's own
    ``exp``)."""
    inv_s, reach2_s, inv_g, reach2_g = gauss
    if not (np.isfinite(reach2_s) and np.isfinite(reach2_g) and reach2_s < m):
        return None
    whole = np.abs(cand) < TABLE_MAX_COORD
    if not (whole.all() and np.array_equal(cand, np.floor(cand))):
        return None
    g_box = _g_boxes(flags, ref, mode_g, reach2_g, m)
    if g_box is None:
        return None
    g_off = np.zeros(len(flags) + 1, np.int64)
    np.cumsum(g_box[:, 2] * g_box[:, 3], out=g_off[1:])
    s_exp = np.empty(int(reach2_s) + 1)
    g_exp = np.empty(int(g_off[-1]))
    _gauss_tables(flags, ref, mode_g, inv_s, reach2_s, inv_g, reach2_g, g_box, g_off, s_exp, g_exp)
    # exp(-inf) = 0 is 4x slower than a finite exp: the offsets (a disc in a box) skip them
    g_tab = np.zeros_like(g_exp)
    np.exp(g_exp, out=g_tab, where=g_exp > -np.inf)
    return np.exp(s_exp), g_box, g_off, g_tab


def _g_boxes(
    flags: np.ndarray, ref: np.ndarray, mode_g: int, reach2_g: float, most: int
) -> np.ndarray | None:
    """``(P, 4)`` int64 ``(x0, y0, width, height)`` per pair: the whole-pixel offsets whose
    grouping exponent can be finite, with a margin of a millionth of the bound (beyond it
    ``|dev| > reach`` however the square root and the differences round); zero-sized for
    pairs without a tree edge. Lengths (``mode_g`` 1): squared distances ``D`` from ``x0``,
    one row; offsets: ``dx`` from ``x0`` and ``dy`` from ``y0``. ``None`` where the boxes
    would hold more than ``most`` offsets in all, or a reference is not finite or farther
    than any two candidates of :data:`TABLE_MAX_COORD` can be."""
    g = (flags & 2) != 0
    r = ref[g]
    if not (np.abs(r) < 2.0 * TABLE_MAX_COORD).all():  # NaN too
        return None
    reach = np.sqrt(reach2_g) * (1.0 + 1e-6) + 1e-6 * np.abs(r).max(initial=0.0)
    if mode_g == 1:
        x0 = np.floor(np.maximum(r[:, 0] - reach, 0.0) ** 2)
        width = np.ceil((r[:, 0] + reach) ** 2) - x0 + 1
        y0 = np.zeros_like(x0)
        height = np.ones_like(x0)
    else:
        x0, y0 = np.floor(r[:, 0] - reach), np.floor(r[:, 1] - reach)
        width = np.ceil(r[:, 0] + reach) - x0 + 1
        height = np.ceil(r[:, 1] + reach) - y0 + 1
    if (width * height).sum() > most:
        return None
    box = np.zeros((len(flags), 4), np.int64)
    box[g] = np.stack([x0, y0, width, height], 1)
    return box


_DE_BRUIJN = np.uint64(0x03F79D71B4CB0A89)
_BIT_INDEX = np.zeros(64, np.int64)
_BIT_INDEX[((np.uint64(1) << np.arange(64, dtype=np.uint64)) * _DE_BRUIJN) >> np.uint64(58)] = (
    np.arange(64)
)
"""``_BIT_INDEX[(b * _DE_BRUIJN) >> 58]`` is ``log2(b)`` for a single bit ``b`` of a uint64
(a de Bruijn sequence): :func:`_pair_values` visits a row's linked candidates by their bits."""


@njit(cache=True, nogil=True, parallel=True)
def _pair_values(
    cand,
    pa,
    pb,
    flags,
    mode_g,
    reach2_s,
    s_tab,
    g_box,
    g_off,
    g_tab,
    offsets,
    links,
    cand_a,
    cand_b,
    s_out,
    g_out,
):
    """The filling pass of :func:`_pair_entries` (with its ``links``) for candidates on whole
    pixels: the entries' values ``S`` and ``Gamma`` looked up in the tables of
    :func:`_gauss_tables` (their ``exp``) instead of exponents to ``exp`` one by one."""
    k = cand.shape[1]
    for p in prange(pa.shape[0]):
        if offsets[p] == offsets[p + 1]:
            continue
        a = pa[p]
        b = pb[p]
        flag = flags[p]
        x0, y0, w, h = g_box[p, 0], g_box[p, 1], g_box[p, 2], g_box[p, 3]
        m = offsets[p]
        for i in range(k):
            row = links[p, i]
            xi = cand[a, i, 0]
            yi = cand[a, i, 1]
            while row != 0:  # the set bits, lowest first, without a branch per bit
                low = row & (~row + np.uint64(1))
                row ^= low
                j = _BIT_INDEX[(low * _DE_BRUIJN) >> np.uint64(58)]
                dx = xi - cand[b, j, 0]
                dy = yi - cand[b, j, 1]
                d2 = dx * dx + dy * dy
                s = 0.0
                g = 0.0
                if flag & 1 and d2 <= reach2_s:
                    s = s_tab[int(d2)]
                if flag & 2:
                    if mode_g == 1:
                        r = int(d2) - x0
                        if 0 <= r < w:
                            g = g_tab[g_off[p] + r]
                    else:
                        cx = int(dx) - x0
                        cy = int(dy) - y0
                        if 0 <= cx < w and 0 <= cy < h:
                            g = g_tab[g_off[p] + cy * w + cx]
                cand_a[m] = i
                cand_b[m] = j
                s_out[m] = s
                g_out[m] = g
                m += 1


@njit(cache=True, nogil=True, parallel=True)
def _degrees(
    k, offsets, cand_a, cand_b, s_val, g_val, a_ptr, b_order, b_ptr, deg_s, deg_g, n_up, n_low
):
    """Per candidate: the degrees ``D_s, D_g`` and how many entries it has as the second
    (``n_up``) and the first (``n_low``) target of a pair.

    One target per loop iteration, summing its pairs in a fixed order (as first target by
    partner, then as second target by partner): the sums do not depend on the threads.
    """
    for t in prange(a_ptr.shape[0] - 1):
        base = t * k
        for p in range(a_ptr[t], a_ptr[t + 1]):  # t is the first target: rows of t
            for e in range(offsets[p], offsets[p + 1]):
                i = cand_a[e]
                deg_s[base + i] += s_val[e]
                deg_g[base + i] += g_val[e]
                n_low[base + i] += 1
        for q in range(b_ptr[t], b_ptr[t + 1]):  # t is the second target: columns of t
            p = b_order[q]
            for e in range(offsets[p], offsets[p + 1]):
                j = cand_b[e]
                deg_s[base + j] += s_val[e]
                deg_g[base + j] += g_val[e]
                n_up[base + j] += 1


@njit(cache=True, nogil=True, inline="always")
def _entry_value(w_sp, w_g, s, g, norm_s, norm_g, r, c):
    """The entry of candidates ``r`` (first target) and ``c`` (second target) of one pair:
    both triangles of :func:`_csc_fill` call this, so their operands and order are the same
    and the matrix is exactly symmetric."""
    return w_sp * s * norm_s[r] * norm_s[c] - w_g * g * norm_g[r] * norm_g[c]


@njit(cache=True, nogil=True, parallel=True)
def _csc_fill(
    k,
    pa,
    pb,
    offsets,
    cand_a,
    cand_b,
    s_val,
    g_val,
    a_ptr,
    b_order,
    b_ptr,
    w_sp,
    norm_s,
    w_g,
    norm_g,
    diag,
    n_up,
    indptr,
    indices,
    data,
):
    """The symmetric CSC ``w_sp C_sp + w_g C_g``, written one target's ``k`` columns per loop
    iteration (so no two threads write the same column).

    Column ``c`` of target ``t`` holds, in this order: the rows ``r < c`` of the pairs where
    ``t`` is the second target (partners ascending, then ``i`` ascending), the diagonal, then
    the rows of the pairs where ``t`` is the first target (partners ascending, then ``j``):
    sorted rows, no duplicates, a canonical CSC. An entry's value is computed from the same
    operands in the same order on both sides, so the matrix is exactly symmetric.
    """
    for t in prange(a_ptr.shape[0] - 1):
        base = t * k
        pos = np.empty(k, np.int64)
        for j in range(k):
            pos[j] = indptr[base + j]
        for q in range(b_ptr[t], b_ptr[t + 1]):  # rows above the diagonal
            p = b_order[q]
            abase = pa[p] * k
            for e in range(offsets[p], offsets[p + 1]):
                i = cand_a[e]
                j = cand_b[e]
                r = abase + i
                c = base + j
                indices[pos[j]] = r
                data[pos[j]] = _entry_value(w_sp, w_g, s_val[e], g_val[e], norm_s, norm_g, r, c)
                pos[j] += 1
        for j in range(k):
            if diag[base + j] != 0.0:
                indices[pos[j]] = base + j
                data[pos[j]] = diag[base + j]
                pos[j] += 1
        for p in range(a_ptr[t], a_ptr[t + 1]):  # rows below the diagonal
            bbase = pb[p] * k
            for e in range(offsets[p], offsets[p + 1]):
                i = cand_a[e]
                j = cand_b[e]
                r = base + i
                c = bbase + j
                indices[pos[i]] = c
                data[pos[i]] = _entry_value(w_sp, w_g, s_val[e], g_val[e], norm_s, norm_g, r, c)
                pos[i] += 1


@njit(cache=True, nogil=True)
def _extent(cand):
    """Per target the mean of its candidates ``(n, 2)`` and their box ``(n, 4)`` (x0 y0 x1
    y1), and the largest squared distance of a candidate from its target's mean."""
    n, k = cand.shape[:2]
    centre = np.zeros((n, 2))
    box = np.zeros((n, 4))
    spread2 = 0.0
    for t in range(n if k > 0 else 0):  # no candidates: nothing to measure
        sx = 0.0
        sy = 0.0
        x0 = x1 = cand[t, 0, 0]
        y0 = y1 = cand[t, 0, 1]
        for i in range(k):
            x = cand[t, i, 0]
            y = cand[t, i, 1]
            sx += x
            sy += y
            x0 = min(x0, x)
            x1 = max(x1, x)
            y0 = min(y0, y)
            y1 = max(y1, y)
        centre[t, 0] = sx / k
        centre[t, 1] = sy / k
        box[t, 0] = x0
        box[t, 1] = y0
        box[t, 2] = x1
        box[t, 3] = y1
        for i in range(k):
            dx = cand[t, i, 0] - centre[t, 0]
            dy = cand[t, i, 1] - centre[t, 1]
            spread2 = max(spread2, dx * dx + dy * dy)
    return centre, box, spread2


def proximity_pairs(cand: np.ndarray, reach: float) -> np.ndarray:
    """``(P, 2)`` target pairs ``a < b`` whose candidates may lie within ``reach`` px."""
    return _near_pairs(*_extent(np.ascontiguousarray(cand, np.float64))[::2], reach)


def _near_pairs(centre: np.ndarray, spread2: float, reach: float) -> np.ndarray:
    """The pairs of :func:`proximity_pairs` from the targets' candidate means and spread."""
    if centre.shape[0] < 2:
        return np.zeros((0, 2), np.int64)
    bound = reach + 2 * float(np.sqrt(spread2))
    return cKDTree(centre).query_pairs(bound, output_type="ndarray").astype(np.int64)


def _merged_pairs(n: int, pairs: np.ndarray, edges: np.ndarray, ref: np.ndarray):
    """Union of proximity pairs and tree edges as sorted ``a < b`` pairs with flags and refs.

    ``flags``: 1 proximity, 2 tree edge (3 both). ``ref[p]`` is ``(e_ab, 0)`` for lengths or
    ``p_a - p_b`` for offsets (an edge stored as ``(b, a)`` is flipped).
    """
    ref = np.asarray(ref, dtype=np.float64)
    vec = ref.ndim == 2
    ref = ref.reshape(len(edges), 2 if vec else 1)
    if not vec:
        ref = np.concatenate([ref, np.zeros_like(ref)], axis=1)
    flip = edges[:, 0] > edges[:, 1]
    e = np.where(flip[:, None], edges[:, ::-1], edges)
    if vec:
        ref = np.where(flip[:, None], -ref, ref)
    pa = np.concatenate([pairs[:, 0], e[:, 0]])
    pb = np.concatenate([pairs[:, 1], e[:, 1]])
    flag = np.concatenate([np.ones(len(pairs), np.int64), np.full(len(e), 2, np.int64)])
    r = np.concatenate([np.zeros((len(pairs), 2)), ref])
    key = pa * n + pb
    order = np.argsort(key, kind="stable")
    key, flag, r = key[order], flag[order], r[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    flags = np.bitwise_or.reduceat(flag, start)
    refs = np.add.reduceat(r, start, axis=0)  # a pair is at most once a tree edge
    ukey = key[start]
    return (
        ukey // n,
        ukey % n,
        flags.astype(np.int64),
        np.ascontiguousarray(refs),
        (2 if vec else 1),
    )


def quadratic_matrix(
    cand: np.ndarray,
    w_sp: float,
    sp_sigma: float,
    sp_cutoff: float,
    w_g: float,
    edges: np.ndarray,
    lengths: np.ndarray,
    g_sigma: float,
    g_cutoff: float,
    tau: float = 0.0,
    components: bool = False,
    split_share: float | None = None,
    diagonal: bool = False,
):
    """``w_sp C_sp + w_g C_g`` (Eq. 9-10) over candidates ``cand (n, k, 2)``, ``(l, l)`` CSC.

    ``C_sp = (D_s + tau I)^-1/2 (D_s + S) (D_s + tau I)^-1/2`` with ``S`` of Eq. 9 between
    candidates of different targets (dropped beyond ``sp_cutoff * sp_sigma`` px);
    ``C_g = (D_g + tau I)^-1/2 (D_g - Gamma) (D_g + tau I)^-1/2`` with ``Gamma`` of Eq. 10 along
    the tree ``edges (E, 2)``; ``lengths`` are the ``e_ij`` (``(E,)``, Eq. 10) or relative
    positions ``p_a - p_b`` (``(E, 2)``, see :func:`grouping_matrix`). ``tau = 0`` is the
    paper's ``I -/+ D^-1/2 W D^-1/2`` (identity only where ``D > 0``); see the module docstring.

    Compiled kernels evaluate each linked candidate pair once and write a canonical CSC
    (sorted rows, no duplicates) directly: no COO stage, no dense matrix. They run on
    numba's threads (:func:`numba.set_num_threads`), one target pair or one target per loop
    iteration with sums in a fixed order, so the matrix is the same bit for bit for any
    number of threads. Where the candidates lie on whole pixels (the tracker's search
    grids), two candidates are an integer offset apart, and the Gaussians are looked up in
    tables of the offsets each pair can have (one ``exp`` per table value, not per entry;
    the same values bit for bit).

    With ``components=True`` returns ``(Q, labels, order)``: ``labels (n,)`` int64 names the
    connected component of every block in the graph of linked target pairs (targets of two
    components share no entry of ``Q``: their sub-problems are independent). ``order`` is
    ``None``: block ``i`` is target ``i``. With ``split_share``, when the largest component
    holds less than that share of the targets (the components will be solved apart,
    :data:`tracker.bqp.frank_wolfe.SPLIT_MAX_SHARE`), ``Q`` is built with the targets grouped
    by component instead, each component's targets in their order: block ``i`` is target
    ``order[i]`` and ``labels`` are non-decreasing, so the solver's sub-problems are slices
    and need no permuted copy of ``Q``. Ranks keep their order inside a component, so every
    entry and degree is summed as in the targets' own order: the matrix is exactly ``Q``
    permuted.

    With ``diagonal=True`` the ``(l,)`` diagonal of ``Q`` (in ``Q``'s order) is returned
    last as well: the entries of ``S`` and ``Gamma`` link candidates of different targets,
    so inside a target's block ``Q`` holds its diagonal alone
    (:meth:`tracker.bqp.qp.BlockQP.from_terms` takes it).
    """
    n, k = cand.shape[:2]
    size = n * k
    cand = np.ascontiguousarray(cand, dtype=np.float64)
    reach_s = sp_cutoff * sp_sigma
    centre, box, spread2 = _extent(cand)
    pairs = _near_pairs(centre, spread2, reach_s) if w_sp > 0 else np.zeros((0, 2), np.int64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    lengths = np.asarray(lengths, dtype=np.float64)[: len(edges)]
    if w_g <= 0:
        edges = np.zeros((0, 2), np.int64)
        lengths = np.zeros(0)
    if len(pairs) == 0 and len(edges) == 0:
        empty = sp.csc_matrix((size, size))
        diag = (np.zeros(size),) if diagonal else ()
        if not components:
            return (empty, *diag) if diagonal else empty
        alone = np.arange(n, dtype=np.int64)  # every target its own component, in order
        return empty, alone, (alone if _splits(np.ones(n), split_share) else None), *diag
    pa, pb, flags, ref, mode_g = _merged_pairs(n, pairs, edges, lengths)
    tests = float(len(pa)) * k * k
    if tests > MAX_PAIR_TESTS:  # the counting pass alone would run for minutes to hours
        raise ValueError(
            f"{len(pa)} target pairs of {k} candidates each make {tests:.3g} candidate pairs "
            f"to test, more than {MAX_PAIR_TESTS:.0e}: use speed-up sampling or a smaller "
            "template"
        )
    gauss = (
        1.0 / (2.0 * sp_sigma * sp_sigma),
        reach_s**2,
        1.0 / (2.0 * g_sigma * g_sigma),
        (g_cutoff * g_sigma) ** 2,
    )
    offsets = np.zeros(len(pa) + 1, np.int64)
    none_i = np.zeros(0, np.int32)
    none_f = np.zeros(0)
    links = np.empty((len(pa) if k <= LINK_MASK_MAX_K else 0, k), np.uint64)
    pairs_geometry = (cand, box, pa, pb, flags, ref, mode_g, *gauss)
    # counts at offsets[1:]
    _pair_entries(*pairs_geometry, offsets, none_i, none_i, none_f, none_f, False, links)
    order = labels = None
    if components:
        linked = offsets[1:] > 0
        labels = _target_components(n, pa[linked], pb[linked])
        if _splits(np.bincount(labels), split_share):
            order = np.argsort(labels, kind="stable")
            rank = np.empty(n, np.int64)
            rank[order] = np.arange(n)
            pa, pb = rank[pa], rank[pb]  # still a < b: ranks keep a component's order
            by = np.argsort(pa * n + pb)  # the pairs sorted again, by (a, b)
            pa, pb, flags, ref = pa[by], pb[by], flags[by], ref[by]
            offsets[1:] = offsets[1:][by]
            links = links[by] if len(links) else links
            cand, box, labels = cand[order], box[order], labels[order]
            pairs_geometry = (cand, box, pa, pb, flags, ref, mode_g, *gauss)
    np.cumsum(offsets, out=offsets)
    m = int(offsets[-1])
    # per linked candidate pair: its two candidates and two values here, and two CSC entries
    require_memory(f"a quadratic matrix of {m} linked candidate pairs", 48.0 * m)
    cand_a = np.empty(m, np.int32)  # the pair's candidate of its first target
    cand_b = np.empty(m, np.int32)  # and of its second
    s_val = np.empty(m)
    g_val = np.empty(m)
    tables = _gauss_tables_for(cand, flags, ref, mode_g, gauss, m) if len(links) else None
    if tables is not None:  # whole pixels: the values from tables, no exp per entry
        _pair_values(
            cand,
            pa,
            pb,
            flags,
            mode_g,
            gauss[1],
            *tables,
            offsets,
            links,
            cand_a,
            cand_b,
            s_val,
            g_val,
        )
    else:
        _pair_entries(*pairs_geometry, offsets, cand_a, cand_b, s_val, g_val, True, links)

        def gaussians(lo: int, hi: int) -> None:  # numpy's exp (-inf, not linked, gives 0)
            np.exp(s_val[lo:hi], out=s_val[lo:hi])
            np.exp(g_val[lo:hi], out=g_val[lo:hi])

        in_chunks(m, gaussians, EXP_PER_THREAD)
    # pairs are sorted by (a, b): as first target a target's pairs are one run; as second
    # target a stable sort by b keeps them in order of a
    targets = np.arange(n + 1)
    a_ptr = np.searchsorted(pa, targets)
    b_order = np.argsort(pb, kind="stable")
    b_ptr = np.searchsorted(pb[b_order], targets)
    deg_s = np.zeros(size)
    deg_g = np.zeros(size)
    n_up = np.zeros(size, np.int64)
    n_low = np.zeros(size, np.int64)
    _degrees(
        k, offsets, cand_a, cand_b, s_val, g_val, a_ptr, b_order, b_ptr, deg_s, deg_g, n_up, n_low
    )
    norm_s, norm_g, diag, indptr = _normalise(
        deg_s, deg_g, tau, float(w_sp), float(w_g), n_up, n_low
    )
    # scipy keeps int32 indices where they fit (and would copy int64 ones down to int32)
    index = np.int32 if max(size, int(indptr[-1])) < np.iinfo(np.int32).max else np.int64
    indptr = indptr.astype(index)
    indices = np.empty(indptr[-1], index)
    data = np.empty(indptr[-1], np.float64)
    _csc_fill(
        k,
        pa,
        pb,
        offsets,
        cand_a,
        cand_b,
        s_val,
        g_val,
        a_ptr,
        b_order,
        b_ptr,
        float(w_sp),
        norm_s,
        float(w_g),
        norm_g,
        diag,
        n_up,
        indptr,
        indices,
        data,
    )
    out = sp.csc_matrix((data, indices, indptr), shape=(size, size))
    out.has_sorted_indices = True
    extra = (diag,) if diagonal else ()
    if components:
        return out, labels, order, *extra
    return (out, *extra) if diagonal else out


def _splits(sizes: np.ndarray, share: float | None) -> bool:
    """Whether components of these ``sizes`` are solved apart
    (:func:`tracker.bqp.frank_wolfe.solved_apart` with ``share``; ``None``: never)."""
    return share is not None and solved_apart(sizes, share)


@njit(cache=True, nogil=True)
def _target_components(n: int, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """(n,) int64 connected-component label of every target over the linked pairs ``(pa,
    pb)``, numbered in order of each component's lowest target (as
    ``scipy.sparse.csgraph.connected_components`` numbers them). Union-find with path
    halving: at 100 targets scipy's graph building and checks took 0.5 ms a frame.

    >>> _target_components(5, np.array([3, 0]), np.array([4, 2]))
    array([0, 1, 0, 2, 2])
    """
    parent = np.arange(n)
    for e in range(len(pa)):
        a, b = pa[e], pb[e]
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    labels = np.empty(n, np.int64)
    count = 0
    for t in range(n):  # a root is its component's lowest target: it comes first
        r = t
        while parent[r] != r:
            r = parent[r]
        if r == t:
            labels[t] = count
            count += 1
        else:
            labels[t] = labels[r]
    return labels


@njit(cache=True, nogil=True, parallel=True)
def _normalise(deg_s, deg_g, tau, w_sp, w_g, n_up, n_low):
    """``(D + tau)^-1/2`` of both degrees (0 where ``D = 0``), the diagonal ``w_sp D_s / (D_s +
    tau) + w_g D_g / (D_g + tau)`` and the CSC column pointers (each column's entries above
    and below the diagonal, plus the diagonal where it is not 0). One candidate per loop
    iteration, then the pointers' running sum."""
    size = deg_s.shape[0]
    norm_s = np.zeros(size)
    norm_g = np.zeros(size)
    diag = np.empty(size)
    count = np.zeros(size + 1, np.int64)
    for i in prange(size):
        ds = 0.0
        dg = 0.0
        if deg_s[i] > 0:
            norm_s[i] = 1.0 / np.sqrt(deg_s[i] + tau)
            ds = deg_s[i] / (deg_s[i] + tau)
        if deg_g[i] > 0:
            norm_g[i] = 1.0 / np.sqrt(deg_g[i] + tau)
            dg = deg_g[i] / (deg_g[i] + tau)
        diag[i] = w_sp * ds + w_g * dg
        count[i + 1] = n_up[i] + n_low[i] + (1 if diag[i] != 0.0 else 0)
    return norm_s, norm_g, diag, np.cumsum(count)


def proximity_matrix(
    cand: np.ndarray, sigma: float, cutoff: float, tau: float = 0.0
) -> sp.csc_matrix:
    """Spatial-proximity matrix ``C_sp = I + D^-1/2 S D^-1/2`` (Eq. 9, signless; see module).

    ``cand`` is ``(n, k, 2)``; ``S_ij = exp(-|p_i - p_j|^2 / 2 sigma^2)`` between candidates of
    different targets, dropped beyond ``cutoff * sigma`` px. Returns ``(l, l)`` CSC, ``l = nk``.
    """
    return quadratic_matrix(
        cand, 1.0, sigma, cutoff, 0.0, np.zeros((0, 2), np.int64), np.zeros(0), 1.0, 1.0, tau
    )


def grouping_matrix(
    cand: np.ndarray,
    edges: np.ndarray,
    lengths: np.ndarray,
    sigma: float,
    cutoff: float,
    tau: float = 0.0,
) -> sp.csc_matrix:
    """Grouping matrix ``C_g = I - D^-1/2 Gamma D^-1/2`` (Eq. 10) over candidates ``(n, k, 2)``.

    ``lengths (E,)``: ``Gamma_ij = exp(-(|p_i - p_j| - e_ij)^2 / 2 sigma^2)`` (Eq. 10), dropped
    where ``| |p_i - p_j| - e_ij | > cutoff * sigma``. ``lengths (E, 2)``: relative positions
    ``e_ij = p_a - p_b`` and ``Gamma_ij = exp(-|(p_i - p_j) - e_ij|^2 / 2 sigma^2)``, which
    keeps the formation's orientation too and is sparser (a disc, not an annulus).
    """
    return quadratic_matrix(cand, 0.0, 1.0, 1.0, 1.0, edges, lengths, sigma, cutoff, tau)
