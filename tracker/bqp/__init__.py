"""Paper 1: the BQP tracker solved by Frank-Wolfe with SWAP steps (Dehghan & Shah).

* :mod:`tracker.bqp.tracker` -- :class:`~tracker.bqp.tracker.BQPTracker`, one binary
  quadratic program per frame;
* :mod:`tracker.bqp.params` -- :class:`~tracker.bqp.params.BQPParams`, every weight and
  threshold (Eq. 1-10);
* :mod:`tracker.bqp.terms` -- motion and neighbourhood-motion terms, coherent-motion groups;
* :mod:`tracker.bqp.quadratic` -- the proximity and grouping terms, one sparse matrix;
* :mod:`tracker.bqp.qp` -- :class:`~tracker.bqp.qp.BlockQP`, the relaxed QP over a product of
  simplices;
* :mod:`tracker.bqp.frank_wolfe` -- plain, away-step and SWAP Frank-Wolfe (numba);
* :mod:`tracker.bqp.qp_baselines` -- Clarabel and OSQP on the same QP.
"""
