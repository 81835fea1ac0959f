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

import importlib
from typing import Any

_EXPORTS = {
    "Tracker": "tracker.base",
    "TrackResult": "tracker.base",
    "make_tracker": "tracker.registry",
    "TRACKERS": "tracker.registry",
    "run_tracker": "tracker.runner",
    "TrackRun": "tracker.runner",
    "BQPTracker": "tracker.bqp.tracker",
    "BQPParams": "tracker.bqp.params",
    "NCCTracker": "tracker.baselines.ncc",
    "NCCParams": "tracker.baselines.ncc",
    "evaluate": "tracker.metrics",
    "accuracy_curve": "tracker.metrics",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'tracker' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
