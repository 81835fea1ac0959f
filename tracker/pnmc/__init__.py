"""PNMC tracker (paper 2): prominent individuals, neighbourhood motion concurrence,
instantaneous flow and a hierarchical breadth-first update (:mod:`tracker.pnmc.tracker`)."""

from tracker.pnmc.params import PNMCParams
from tracker.pnmc.tracker import PNMCTracker

__all__ = ["PNMCParams", "PNMCTracker"]
