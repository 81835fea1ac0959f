"""Dense-crowd point trackers, their solvers and metrics (SPEC §5-7).

Module map:

* :mod:`tracker.base` -- the :class:`Tracker` contract (``init``, ``step``, ``set_params``,
  ``track``) and :class:`TrackResult`;
* :mod:`tracker.registry` -- every tracker by name (``make_tracker("bqp")``);
* :mod:`tracker.runner` -- run any tracker over any sequence source, time and score it;
* :mod:`tracker.bqp` -- paper 1: the BQP tracker, its terms, the relaxed QP, Frank-Wolfe
  (plain / away / SWAP) and the interior-point baselines;
* :mod:`tracker.pnmc` -- paper 2: prominence, neighbourhood motion concurrence, flow;
* :mod:`tracker.baselines` -- independent NCC, mean-shift, ByteTrack / OC-SORT adapters;
* :mod:`tracker.appearance`, :mod:`tracker.candidates` -- shared appearance models and
  candidate grids;
* :mod:`tracker.metrics` -- the papers' accuracy curve, CLEAR MOT / IDF1 / HOTA;
* :mod:`tracker.mot_io`, :mod:`tracker.overlay` -- MOT result rows and overlay videos;
* :mod:`tracker.testing` -- the shipped contract check, scenes and synthetic QPs.

The names below are imported lazily, so ``import tracker`` stays cheap.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "BQPParams",
    "BQPTracker",
    "NCCParams",
    "NCCTracker",
    "TrackResult",
    "TRACKERS",
    "TrackRun",
    "Tracker",
    "accuracy_curve",
    "evaluate",
    "make_tracker",
    "run_tracker",
]


def __getattr__(name: str) -> Any:
    # Static imports inside the function: lazy, and visible to the import-layer test.
    if name in ("Tracker", "TrackResult"):
        from tracker import base as module
    elif name in ("make_tracker", "TRACKERS"):
        from tracker import registry as module
    elif name in ("run_tracker", "TrackRun"):
        from tracker import runner as module
    elif name == "BQPTracker":
        from tracker.bqp import tracker as module
    elif name == "BQPParams":
        from tracker.bqp import params as module
    elif name in ("NCCTracker", "NCCParams"):
        from tracker.baselines import ncc as module
    elif name in ("evaluate", "accuracy_curve"):
        from tracker import metrics as module
    else:
        raise AttributeError(f"module 'tracker' has no attribute {name!r}")
    return getattr(module, name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
