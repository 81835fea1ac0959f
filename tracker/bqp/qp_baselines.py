"""Reference solvers for the relaxed BQP: Clarabel (interior point) and OSQP (ADMM).

They solve the same :class:`tracker.bqp.qp.BlockQP` as :mod:`tracker.bqp.frank_wolfe`,
standing in for the paper's ILOG CPLEX (Sec. 7.4, Fig. 12). Both take the problem in the form::

    min 1/2 x^T P x + q^T x   with  P = 2 Q  (upper triangle),  q = c
    Clarabel:  A x + s = b,  s in {0}^n x R_+^l,  A = [B; -I], b = [1; 0]
    OSQP:      1 <= B x <= 1,  0 <= x <= inf

where ``B`` (n, l) sums each block. Neither package is a core dependency: they are imported
lazily, and a missing one raises :class:`crowdsim.optional.DependencyNotInstalled`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tracker.bqp.qp import BlockQP


@dataclass
class QPSolution:
    """Output of a reference solver.

    Attributes
    ----------
    x : (l,) float64
        Solution, clipped to ``>= 0`` and renormalised per block (solver round-off only).
    objective : float
        ``c.x + x^T Q x`` at ``x`` (recomputed, so comparable with :mod:`tracker.bqp.frank_wolfe`).
    status : str
        The solver's status string.
    iterations : int
        Solver iterations.
    solve_time : float
        Seconds spent in the solver's ``solve`` call only (setup excluded), as reported
        by the solver when it reports one.
    """

    x: np.ndarray
    objective: float
    status: str
    iterations: int
    solve_time: float


def block_sum_matrix(qp: BlockQP) -> sp.csc_matrix:
    """(n, l) sparse matrix ``B`` with ``(B x)_b = sum of x over block b``."""
    l = qp.n_vars
    return sp.csc_matrix(
        (np.ones(l), qp.block_of, np.arange(l + 1, dtype=np.int64)), shape=(qp.n_blocks, l)
    )


def _finish(qp: BlockQP, x: np.ndarray, status: str, iterations: int, t: float) -> QPSolution:
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    if qp.n_blocks:
        sums = qp.block_sums(x)
        sums[sums <= 0] = 1.0
        x = x / np.repeat(sums, qp.block_sizes)
    return QPSolution(
        x=x, objective=qp.objective(x), status=status, iterations=iterations, solve_time=t
    )


def solve_clarabel(qp: BlockQP, tol: float = 1e-8, verbose: bool = False) -> QPSolution:
    """Solve ``qp`` with Clarabel's interior-point method (gap tolerances ``tol``)."""
    from crowdsim.optional import require

    clarabel = require("clarabel", "bench", "the Clarabel reference QP solver")
    l, n = qp.n_vars, qp.n_blocks
    if n == 0:
        return QPSolution(np.zeros(0), 0.0, "Solved", 0, 0.0)
    P = sp.triu(2.0 * qp.Q, format="csc")
    A = sp.vstack([block_sum_matrix(qp), -sp.identity(l, format="csc")], format="csc")
    b = np.concatenate([np.ones(n), np.zeros(l)])
    settings = clarabel.DefaultSettings()
    settings.verbose = verbose
    settings.tol_gap_abs = tol
    settings.tol_gap_rel = tol
    solver = clarabel.DefaultSolver(
        P, qp.c, A, b, [clarabel.ZeroConeT(n), clarabel.NonnegativeConeT(l)], settings
    )
    sol = solver.solve()
    return _finish(
        qp, np.asarray(sol.x), str(sol.status), int(sol.iterations), float(sol.solve_time)
    )


def solve_osqp(
    qp: BlockQP, tol: float = 1e-6, verbose: bool = False, max_iter: int = 20_000
) -> QPSolution:
    """Solve ``qp`` with OSQP (first-order ADMM; absolute/relative tolerances ``tol``)."""
    from crowdsim.optional import require

    osqp = require("osqp", "bench", "the OSQP reference QP solver")
    l, n = qp.n_vars, qp.n_blocks
    if n == 0:
        return QPSolution(np.zeros(0), 0.0, "solved", 0, 0.0)
    P = sp.triu(2.0 * qp.Q, format="csc")
    A = sp.vstack([block_sum_matrix(qp), sp.identity(l, format="csc")], format="csc")
    lo = np.concatenate([np.ones(n), np.zeros(l)])
    hi = np.concatenate([np.ones(n), np.full(l, np.inf)])
    prob = osqp.OSQP()
    prob.setup(
        P,
        qp.c,
        A,
        lo,
        hi,
        eps_abs=tol,
        eps_rel=tol,
        verbose=verbose,
        max_iter=max_iter,
        polishing=True,
    )
    res = prob.solve(raise_error=False)
    return _finish(
        qp, np.asarray(res.x), str(res.info.status), int(res.info.iter), float(res.info.solve_time)
    )


SOLVERS = {"clarabel": solve_clarabel, "osqp": solve_osqp}
"""Reference solver name -> function ``(qp) -> QPSolution``."""
