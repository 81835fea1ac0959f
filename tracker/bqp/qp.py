"""The relaxed per-frame problem of the BQP tracker: a convex QP over a product of simplices.

Per frame the tracker picks one candidate location per target (paper Eq. 1-3). Relaxing the
binary choice to its convex hull gives one probability simplex per target ("block")::

    min_x  c . x + x^T Q x     s.t.  x >= 0,  sum_{i in block b} x_i = 1  for every block b

with ``c = c_a + zeta c_m + eta c_nm`` (linear terms) and ``Q = C_sp + C_g`` (the two
normalised-Laplacian quadratic terms, Eq. 9-10), which is positive semi-definite.

:class:`BlockQP` is only the container: it validates shapes, symmetry and the block layout,
evaluates the objective and converts per-block choices to one-hot vertices. The solver lives in
:mod:`tracker.bqp.frank_wolfe`, the reference solvers in :mod:`tracker.bqp.qp_baselines`.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from numba import njit

from crowdsim.checks import whole_numbers

SYMMETRY_RTOL: float = 1e-9
"""Relative tolerance of the symmetry check of ``Q`` (see :func:`_check_csc`)."""

_NPZ_KEYS = ("c", "Q_data", "Q_indices", "Q_indptr", "block_ptr")


@njit(cache=True)
def _check_csc(indptr, indices, data, rtol):
    """``(all finite, looks symmetric)`` for a CSC matrix, in one sequential O(nnz) pass.

    Compares ``Q v`` with ``Q^T v`` for a fixed, irregular positive probe vector ``v``
    (``(Q - Q^T) v = 0`` for a non-symmetric ``Q`` would need an exact cancellation), row by
    row against ``rtol * (|Q| v + |Q|^T v)``. Forming ``Q^T`` instead costs several times
    more; it is only done to word the error once this test fails.
    """
    n = indptr.shape[0] - 1
    v = np.empty(n)
    for j in range(n):
        t = (j + 1) * 0.6180339887498949
        v[j] = 0.5 + (t - np.floor(t))
    qv = np.zeros(n)
    qtv = np.zeros(n)
    mag = np.zeros(n)
    for j in range(n):
        vj = v[j]
        acc = 0.0
        amag = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            d = data[p]
            if not np.isfinite(d):
                return False, False
            r = indices[p]
            qv[r] += d * vj
            mag[r] += abs(d) * vj
            acc += d * v[r]
            amag += abs(d) * v[r]
        qtv[j] = acc
        mag[j] += amag
    for r in range(n):
        if abs(qv[r] - qtv[r]) > rtol * mag[r]:
            return True, False
    return True, True


def _checked_layout(c: Any, block_ptr: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``c`` as finite float64 ``(l,)`` and ``block_ptr`` as an int64 block layout of its
    ``l`` variables, with the block sizes; a ``ValueError`` naming the field and the value
    otherwise. The O(l) checks of :class:`BlockQP` and :meth:`BlockQP.from_terms`."""
    c = np.asarray(c)
    if c.ndim != 1:
        raise ValueError(f"BlockQP.c must be 1-D (l,), got shape {c.shape}")
    if not np.issubdtype(c.dtype, np.number) or np.iscomplexobj(c):
        raise ValueError(f"BlockQP.c must be real numbers, got dtype {c.dtype}")
    c = np.ascontiguousarray(c, dtype=np.float64)
    if not np.all(np.isfinite(c)):
        bad = int(np.flatnonzero(~np.isfinite(c))[0])
        raise ValueError(f"BlockQP.c must be finite; c[{bad}] = {c[bad]}")
    l = c.shape[0]

    bp = np.asarray(block_ptr)
    if bp.ndim != 1 or bp.shape[0] < 1:
        raise ValueError(f"BlockQP.block_ptr must be 1-D (n+1,), got shape {bp.shape}")
    if not np.issubdtype(bp.dtype, np.integer):
        if np.issubdtype(bp.dtype, np.floating) and whole_numbers(bp):
            bp = bp.astype(np.int64)
        else:
            raise ValueError(f"BlockQP.block_ptr must be integers, got dtype {bp.dtype}")
    bp = np.ascontiguousarray(bp, dtype=np.int64)
    if bp[0] != 0:
        raise ValueError(f"BlockQP.block_ptr[0] must be 0, got {bp[0]}")
    if bp[-1] != l:
        raise ValueError(f"BlockQP.block_ptr[-1] must equal len(c) = {l}, got {bp[-1]}")
    sizes = np.diff(bp)
    if np.any(sizes <= 0):
        b = int(np.flatnonzero(sizes <= 0)[0])
        raise ValueError(
            f"BlockQP.block_ptr must be strictly increasing (every block non-empty); "
            f"block {b} has size {sizes[b]}"
        )
    return c, bp, sizes


@dataclass
class BlockQP:
    """``min_x c.x + x^T Q x`` over the product of simplices, one simplex per target (block).

    Attributes
    ----------
    c : (l,) float64
        Linear costs, one per candidate (appearance + motion terms, Eq. 1).
    Q : (l, l) scipy.sparse.csc_matrix, float64
        Symmetric quadratic term (``C_sp + C_g``). Positive semi-definiteness is the
        caller's guarantee (it is not checked: that would need a factorisation); symmetry,
        shape and finiteness are checked in O(nnz). Stored canonical (sorted indices, no
        duplicates); a ``Q`` that already is canonical float64 CSC is kept without a copy.
    block_ptr : (n + 1,) int64
        Block ``b`` (target ``b``) owns variables ``block_ptr[b]:block_ptr[b + 1]``.
        ``block_ptr[0] == 0``, ``block_ptr[-1] == l`` and every block is non-empty.
        ``n = 0`` (no targets, ``block_ptr = [0]``, ``l = 0``) is allowed.

    Raises
    ------
    ValueError
        Naming the field (``c``, ``Q`` or ``block_ptr``) and the bad value.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> qp = BlockQP(np.array([1.0, 0.0, 2.0]), sp.identity(3, format="csc"),
    ...              np.array([0, 2, 3]))
    >>> qp.n_blocks, qp.n_vars
    (2, 3)
    >>> qp.vertex(np.array([1, 0]))
    array([0., 1., 1.])
    >>> qp.objective(qp.vertex(np.array([1, 0])))
    4.0
    """

    c: np.ndarray
    Q: sp.csc_matrix
    block_ptr: np.ndarray
    block_of: np.ndarray = field(init=False, repr=False)
    """(l,) int64: the block owning each variable (derived)."""
    diagonal: np.ndarray | None = field(init=False, default=None, repr=False)
    """(l,) float64 ``Q``'s diagonal, when it is ``Q``'s only entries inside a block (set by
    :meth:`from_terms` when its caller knows it); ``None``: not known."""

    def __post_init__(self) -> None:
        c, bp, sizes = _checked_layout(self.c, self.block_ptr)
        l = c.shape[0]

        if not sp.issparse(self.Q):
            raise ValueError(
                f"BlockQP.Q must be a scipy.sparse matrix (dense l x l is never used), "
                f"got {type(self.Q).__name__}"
            )
        if self.Q.shape != (l, l):
            raise ValueError(f"BlockQP.Q must have shape ({l}, {l}), got {self.Q.shape}")
        if np.iscomplexobj(self.Q.data) or not np.issubdtype(self.Q.dtype, np.number):
            raise ValueError(f"BlockQP.Q must be real, got dtype {self.Q.dtype}")
        # No copy when Q is already canonical float64 CSC (the per-frame fast path): the
        # BlockQP then shares Q's arrays, so the caller must not mutate Q afterwards.
        Q = self.Q if sp.isspmatrix_csc(self.Q) else sp.csc_matrix(self.Q)
        if Q.dtype != np.float64:
            Q = Q.astype(np.float64)
        if not Q.has_canonical_format:
            Q = Q.copy()
            Q.sum_duplicates()  # also sorts the row indices of every column
        finite, symmetric = _check_csc(Q.indptr, Q.indices, Q.data, SYMMETRY_RTOL)
        if not finite:
            raise ValueError("BlockQP.Q must be finite; it holds NaN or inf entries")
        if not symmetric:  # confirm entry-wise, and word the error
            diff = abs(Q - Q.T).tocoo()
            i = int(np.argmax(diff.data)) if diff.nnz else 0
            if diff.nnz == 0 or diff.data[i] <= SYMMETRY_RTOL * float(abs(Q.data).max()):
                symmetric = True
        if not symmetric:
            raise ValueError(
                f"BlockQP.Q must be symmetric; max |Q - Q^T| = {diff.data[i]:.3g} at "
                f"({diff.row[i]}, {diff.col[i]}): Q[{diff.row[i]}, {diff.col[i]}] = "
                f"{Q[diff.row[i], diff.col[i]]:.6g}, Q[{diff.col[i]}, {diff.row[i]}] = "
                f"{Q[diff.col[i], diff.row[i]]:.6g}"
            )

        self.c = c
        self.Q = Q
        self.block_ptr = bp
        self.block_of = np.repeat(np.arange(bp.shape[0] - 1, dtype=np.int64), sizes)

    @classmethod
    def from_terms(
        cls,
        c: np.ndarray,
        Q: sp.csc_matrix,
        block_ptr: np.ndarray,
        diagonal: np.ndarray | None = None,
    ) -> BlockQP:
        """The per-frame problem from :func:`tracker.bqp.quadratic.quadratic_matrix`'s ``Q``.

        That ``Q`` is canonical float64 CSC, finite and exactly symmetric by construction
        (both triangles are written from the same operands), so the O(nnz) checks of the
        constructor are left out: at 1,000 packed targets they took 3 ms of a frame. ``c``
        must still be finite and ``block_ptr`` a valid block layout (both O(l), checked).

        ``diagonal`` is ``Q``'s diagonal as ``quadratic_matrix(..., diagonal=True)`` returns
        it: that ``Q`` links only candidates of different targets, so inside a block it holds
        its diagonal alone, and the solver takes the blocks' parts of ``Q`` from it
        (:attr:`diagonal`) instead of searching every column.
        """
        c, bp, sizes = _checked_layout(c, block_ptr)
        l = c.shape[0]
        if not (sp.isspmatrix_csc(Q) and Q.dtype == np.float64 and Q.shape == (l, l)):
            raise ValueError(f"BlockQP.Q must be ({l}, {l}) float64 CSC from quadratic_matrix")
        if diagonal is not None:
            diagonal = np.asarray(diagonal)
            if diagonal.shape != (l,) or diagonal.dtype != np.float64:
                raise ValueError(
                    f"BlockQP.diagonal must be ({l},) float64, got shape {diagonal.shape} "
                    f"dtype {diagonal.dtype}"
                )
        qp = object.__new__(cls)
        qp.c, qp.Q, qp.block_ptr, qp.diagonal = c, Q, bp, diagonal
        qp.block_of = np.repeat(np.arange(len(sizes), dtype=np.int64), sizes)
        return qp

    # ------------------------------------------------------------------ shape
    @property
    def n_blocks(self) -> int:
        """Number of blocks (targets) ``n``."""
        return int(self.block_ptr.shape[0] - 1)

    @property
    def n_vars(self) -> int:
        """Number of variables (candidates over all targets) ``l``."""
        return int(self.c.shape[0])

    @property
    def block_sizes(self) -> np.ndarray:
        """(n,) int64: number of candidates per target."""
        return np.diff(self.block_ptr)

    # ------------------------------------------------------------ evaluation
    def objective(self, x: np.ndarray) -> float:
        """``c.x + x^T Q x`` for ``x`` of shape (l,) (feasibility not checked)."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.n_vars,):
            raise ValueError(f"x must have shape ({self.n_vars},), got {x.shape}")
        return float(self.c @ x + x @ (self.Q @ x))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """(l,) gradient ``c + 2 Q x``."""
        x = np.asarray(x, dtype=np.float64)
        return self.c + 2.0 * (self.Q @ x)

    def vertex(self, choice: np.ndarray) -> np.ndarray:
        """One-hot (l,) vertex from per-block local indices ``choice`` (n,) int."""
        choice = np.asarray(choice)
        if choice.shape != (self.n_blocks,):
            raise ValueError(f"choice must have shape ({self.n_blocks},), got {choice.shape}")
        if not np.issubdtype(choice.dtype, np.integer):
            raise ValueError(f"choice must be integers, got dtype {choice.dtype}")
        sizes = self.block_sizes
        bad = (choice < 0) | (choice >= sizes)
        if np.any(bad):
            b = int(np.flatnonzero(bad)[0])
            raise ValueError(f"choice[{b}] = {choice[b]} is outside block {b} of size {sizes[b]}")
        x = np.zeros(self.n_vars)
        x[self.block_ptr[:-1] + choice] = 1.0
        return x

    def block_sums(self, x: np.ndarray) -> np.ndarray:
        """(n,) sum of ``x`` within each block."""
        x = np.asarray(x, dtype=np.float64)
        if self.n_blocks == 0:
            return np.zeros(0)
        return np.add.reduceat(x, self.block_ptr[:-1])

    def check_feasible(self, x: np.ndarray, name: str = "x", atol: float = 1e-8) -> np.ndarray:
        """Validate ``x`` is in the product of simplices; return it as a float64 copy.

        Entries in ``[-atol, 0)`` are clipped to 0 and each block is renormalised to sum 1.
        """
        x = np.array(x, dtype=np.float64, copy=True)
        if x.shape != (self.n_vars,):
            raise ValueError(f"{name} must have shape ({self.n_vars},), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be finite")
        if np.any(x < -atol):
            i = int(np.argmin(x))
            raise ValueError(f"{name} must be >= 0 (infeasible); {name}[{i}] = {x[i]:.6g}")
        np.maximum(x, 0.0, out=x)
        sums = self.block_sums(x)
        tol = atol * np.maximum(1.0, self.block_sizes)
        if np.any(np.abs(sums - 1.0) > tol):
            b = int(np.argmax(np.abs(sums - 1.0)))
            raise ValueError(
                f"{name} must sum to 1 in every block (infeasible); block {b} sums to {sums[b]:.6g}"
            )
        if self.n_blocks:
            x /= np.repeat(sums, self.block_sizes)
        return x

    # -------------------------------------------------------------- save/load
    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The ``.npz`` fields: ``c, Q_data, Q_indices, Q_indptr, block_ptr``."""
        return {
            f"{prefix}c": self.c,
            f"{prefix}Q_data": self.Q.data,
            f"{prefix}Q_indices": self.Q.indices,
            f"{prefix}Q_indptr": self.Q.indptr,
            f"{prefix}block_ptr": self.block_ptr,
        }

    @classmethod
    def from_arrays(cls, arrays: dict | np.lib.npyio.NpzFile, prefix: str = "") -> BlockQP:
        missing = [k for k in _NPZ_KEYS if f"{prefix}{k}" not in arrays]
        if missing:
            raise ValueError(f"QP file lacks field(s) {', '.join(prefix + k for k in missing)}")
        c = np.asarray(arrays[f"{prefix}c"])
        l = c.shape[0] if c.ndim == 1 else -1
        try:
            Q = sp.csc_matrix(
                (
                    arrays[f"{prefix}Q_data"],
                    arrays[f"{prefix}Q_indices"],
                    arrays[f"{prefix}Q_indptr"],
                ),
                shape=(l, l),
            )
        except (ValueError, TypeError) as exc:
            raise ValueError(f"QP file field {prefix}Q_* is corrupt: {exc}") from exc
        return cls(c, Q, np.asarray(arrays[f"{prefix}block_ptr"]))

    def save(self, path: str | os.PathLike) -> None:
        """Write one problem to ``path`` (``.npz``; see :meth:`to_arrays`)."""
        save_many(path, [self])

    @classmethod
    def load(cls, path: str | os.PathLike) -> BlockQP:
        """Read the first (usually only) problem of a file written by :meth:`save`."""
        qps = load_many(path)
        if not qps:
            raise ValueError(f"{path}: holds no QP")
        return qps[0]


def save_many(path: str | os.PathLike, qps: list[BlockQP]) -> None:
    """Write several problems to one ``.npz``.

    A single problem is stored under the plain keys ``c, Q_data, Q_indices, Q_indptr,
    block_ptr``; several under ``p0/c, p0/Q_data, ...``, ``p1/...`` and ``count``. The file is
    written atomically, at ``path`` exactly (numpy would add ``.npz`` to a name without it).
    """
    from crowdsim.atomic import atomic_path

    if len(qps) == 1:
        arrays = qps[0].to_arrays()
    else:
        arrays = {"count": np.array(len(qps))}
        for i, qp in enumerate(qps):
            arrays.update(qp.to_arrays(prefix=f"p{i}/"))
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def load_many(path: str | os.PathLike) -> list[BlockQP]:
    """Read every problem of a file written by :func:`save_many` or :meth:`BlockQP.save`."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: no such QP file")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable .npz QP file ({exc})") from exc
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: not an .npz QP file (holds a single array)")
    try:
        with z:
            if "count" in z.files:
                return [BlockQP.from_arrays(z, prefix=f"p{i}/") for i in range(int(z["count"]))]
            return [BlockQP.from_arrays(z)]
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: corrupt .npz QP file ({exc})") from exc
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
