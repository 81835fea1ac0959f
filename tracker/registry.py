"""Every tracker by name: one table, read by the CLI, the demo, the benchmarks and the tests.

A tracker is registered as a lazily imported ``"module:Class"`` with its parameter dataclass
and the parameter overrides that make the named variant (``bqp-ncc`` is the BQP tracker with
NCC appearance). Adding a tracker is one line in :data:`TRACKERS`; its tests then ask for its
accuracy floor on the planted crowd (``tests/tracker/accuracy_floor.json``: a few points under
what ``test_plant_and_recover_accuracy_floor`` measures), and a row in
:data:`envs.param_space.TUNABLES` makes it tunable. ``crowdsim compare --trackers NAME`` gives it
a row of its own.

>>> sorted(names())[:3]
['bqp', 'bqp-dense', 'bqp-ncc']
>>> get("kalman")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown tracker 'kalman'; valid trackers: bqp, bqp-ncc, bqp-dense, ncc...
>>> type(make_tracker("bqp-ncc").params).__name__, make_tracker("bqp-ncc").params.appearance
('BQPParams', 'ncc')
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any

from tracker.base import Tracker


def _load(target: str) -> Any:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class TrackerEntry:
    """One registered tracker.

    Attributes
    ----------
    name : str
        Registry name (``crowdsim track --tracker NAME``).
    target : str
        ``"module:Class"`` of the :class:`tracker.base.Tracker` subclass, imported on use.
    params : str
        ``"module:Class"`` of its frozen parameter dataclass.
    overrides : mapping
        Parameter values that make this variant (applied over the dataclass defaults).
    summary : str
        One line for ``--help`` and tables.
    """

    name: str
    target: str
    params: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    summary: str = ""

    def tracker_class(self) -> type[Tracker]:
        return _load(self.target)

    def params_class(self) -> type:
        return _load(self.params)

    def field_names(self) -> frozenset[str]:
        """The fields of its parameter class (what ``--set`` and overrides may name)."""
        return frozenset(f.name for f in fields(self.params_class()))

    def make_params(self, **overrides: Any) -> Any:
        """The variant's parameters, with ``overrides`` on top (unknown fields are refused)."""
        cls = self.params_class()
        valid = self.field_names()
        unknown = sorted(set(overrides) - valid)
        if unknown:
            raise ValueError(
                f"tracker {self.name!r} has no parameter(s) {', '.join(unknown)}; "
                f"valid: {', '.join(sorted(valid))}"
            )
        return cls(**{**self.overrides, **overrides})

    def create(self, params: Any = None, **overrides: Any) -> Tracker:
        """A new tracker; ``params`` (an instance of :meth:`params_class`, or a mapping of its
        fields, validated like overrides) and/or overrides.

        Anything else is refused naming its type: a tracker built around a dict or another
        tracker's parameters would run unvalidated until something deep inside it failed.
        """
        cls = self.params_class()
        if params is None:
            params = self.make_params(**overrides)
        elif isinstance(params, Mapping):
            params = self.make_params(**{**params, **overrides})
        elif not isinstance(params, cls):
            raise ValueError(
                f"tracker {self.name!r} takes params as a {cls.__name__} or a mapping of its "
                f"fields, got {type(params).__name__}"
            )
        elif overrides:
            self.make_params(**overrides)  # unknown fields are refused by name
            params = replace(params, **overrides)
        trk = self.tracker_class()(params)
        trk.name = self.name  # a variant's own name (bqp-ncc), in reports and messages
        return trk


def _entry(name: str, target: str, params: str, summary: str, **overrides: Any) -> TrackerEntry:
    return TrackerEntry(name, target, params, MappingProxyType(overrides), summary)


_BQP = ("tracker.bqp.tracker:BQPTracker", "tracker.bqp.params:BQPParams")
_NCC = ("tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams")

TRACKERS: Mapping[str, TrackerEntry] = MappingProxyType(
    {
        e.name: e
        for e in (
            _entry(
                "bqp", *_BQP, "BQP / Frank-Wolfe SWAP, KCF appearance, speed-up sampling (paper 1)"
            ),
            _entry(
                "bqp-ncc",
                *_BQP,
                "BQP / Frank-Wolfe SWAP with NCC template appearance",
                appearance="ncc",
            ),
            _entry(
                "bqp-dense",
                *_BQP,
                "BQP with dense candidates (no speed-up sampling)",
                speedup=False,
            ),
            _entry("ncc", *_NCC, "independent NCC template tracker (baseline of both papers)"),
            _entry(
                "pnmc",
                "tracker.pnmc.tracker:PNMCTracker",
                "tracker.pnmc.params:PNMCParams",
                "prominence + neighbourhood motion concurrence, hierarchical update (paper 2)",
            ),
            _entry(
                "meanshift",
                "tracker.baselines.meanshift:MeanShiftTracker",
                "tracker.baselines.meanshift:MeanShiftParams",
                "OpenCV mean-shift on colour histograms (paper 2's MS)",
            ),
            _entry(
                "bytetrack",
                "tracker.baselines.detection:ByteTrackTracker",
                "tracker.baselines.detection:ByteTrackParams",
                "ByteTrack on a detection feed (simulated head detections by default)",
            ),
            _entry(
                "ocsort",
                "tracker.baselines.detection:OCSORTTracker",
                "tracker.baselines.detection:OCSORTParams",
                "OC-SORT on a detection feed (simulated head detections by default)",
            ),
        )
    }
)
"""Registry name -> :class:`TrackerEntry`, in the order tables list them."""


def names() -> tuple[str, ...]:
    """Registered tracker names."""
    return tuple(TRACKERS)


def get(name: str) -> TrackerEntry:
    """The entry named ``name``; ``ValueError`` listing the valid names otherwise."""
    try:
        return TRACKERS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown tracker {name!r}; valid trackers: {', '.join(TRACKERS)}"
        ) from None


def make_tracker(tracker: str | Tracker, params: Any = None, **overrides: Any) -> Tracker:
    """Resolve ``tracker`` (a registry name, or a ready :class:`Tracker` passed through).

    >>> make_tracker("ncc", search_factor=3.0).params.search_factor
    3.0
    """
    if isinstance(tracker, Tracker):
        if params is not None or overrides:
            raise ValueError("pass params only with a tracker name, not with a tracker object")
        return tracker
    return get(tracker).create(params, **overrides)
